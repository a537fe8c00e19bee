"""Stage ``convert``: the dense MVS points become Gaussians (export/mvs_gaussians.ply), see fusion.convert; with
``memory_limit_mb`` the fused cloud is converted in chunks with bounded memory (fusion.convert_stream), same file."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

from fusion.convert_options import DEFAULT_MODE, ConvertMode, ConvertOptions
from hybridsplat.stages import sizes
from hybridsplat.stages.base import MEMORY_LIMIT_HELP, CliOption, Stage, StageContext, StageResult, omitted_if_none

STREAM_TEMP_BYTES = 56
"""Temporary bytes a point of the streamed conversion takes in export/ (cells and halos 32, results 24)."""


@dataclass(frozen=True)
class ConvertStageOptions:
    """Options of the ``convert`` stage: the conversion ``mode`` (:class:`fusion.convert.ConvertMode`: ``adaptive``,
    the default everywhere, or ``paper``, Eq. 1-4 exactly) and its parameters (:class:`fusion.convert.ConvertOptions`,
    ``[convert.conversion]``). ``memory_limit_mb`` (MiB): None converts the fused cloud in memory; a number converts
    it in chunks within about that peak memory (:func:`fusion.convert_stream.convert_stream`, the same file; at least
    :data:`fusion.convert_stream.BASE_MB` + :data:`fusion.convert_stream.MIN_WORK_MB`, else a :class:`ConfigError`)."""

    mode: ConvertMode = DEFAULT_MODE
    conversion: ConvertOptions = field(default_factory=ConvertOptions)
    memory_limit_mb: float | None = None

    def __post_init__(self) -> None:
        if self.memory_limit_mb is not None:
            from fusion.convert_stream import plan_memory

            plan_memory(self.memory_limit_mb, self.conversion.k_neighbors)  # a ConfigError naming the value


@dataclass(frozen=True)
class ConvertResult(StageResult):
    """What the convert stage made: ``gaussians`` (one per fused point), the mean nearest-neighbour and the median
    spacing of the points (m) and the conversion's ``warnings`` (one line each). Streamed (``memory_limit_mb``,
    MiB): its peak resident memory (MiB), the ``cells`` it ran in and the points converted by the fallback."""

    gaussians: int = 0
    mean_nn_spacing_m: float = 0.0
    median_spacing_m: float = 0.0
    warnings: tuple[str, ...] = ()
    memory_limit_mb: float | None = omitted_if_none()
    peak_rss_mb: float | None = omitted_if_none()
    cells: int | None = omitted_if_none()
    fallback_points: int | None = omitted_if_none()


class ConvertStage(Stage):
    name = "convert"
    Options = ConvertStageOptions
    Result = ConvertResult
    title = "MVS points to Gaussians"
    run_options = (
        CliOption("mode", "--convert-mode", help="MVS-to-Gaussian conversion: adaptive | paper."),
        CliOption(
            "memory_limit_mb",
            "--memory-limit",
            help=MEMORY_LIMIT_HELP,
        ),
    )

    def inputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.fused_ply, ctx.layout.fused_vis]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.mvs_gaussians]

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of export/mvs_gaussians.ply: one SH-degree-0 Gaussian per fused point with the fused cloud's extra
        fields and ``source`` appended (4 bytes a property), its origin sidecar, and the log (64 KiB); with a memory
        limit also the streamed conversion's temporary files (:data:`STREAM_TEMP_BYTES` a point)."""
        fused = sizes.ply_vertices(ctx.layout.fused_ply)
        gaussians = sizes.gaussian_ply_bytes(fused.count, 0, len(fused.extras) + 1)
        streamed = STREAM_TEMP_BYTES * fused.count if ctx.options(self).memory_limit_mb is not None else 0
        return gaussians + streamed + sizes.SIDECAR_BYTES + sizes.LOG_BYTES

    def run(self, ctx: StageContext) -> ConvertResult:
        opts: ConvertStageOptions = ctx.options(self)
        if opts.memory_limit_mb is not None:
            return _run_streamed(ctx, opts)
        from core.io.gaussian_ply import write_gaussian_ply
        from fusion.convert import convert_points
        from recon.workspace import read_fused

        cloud = read_fused(ctx.layout.dense)
        ctx.progress("points", 0, len(cloud))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = convert_points(cloud, opts.mode, opts.conversion)
        write_gaussian_ply(ctx.layout.mvs_gaussians, result.gaussians, extra_fields=True)
        ctx.progress("points", len(cloud), len(cloud))
        return ConvertResult(
            gaussians=len(result.gaussians),
            mean_nn_spacing_m=result.stats.mean_nn_spacing,
            median_spacing_m=result.stats.median_spacing,
            warnings=_lines(caught),
        )

    def summary(self, result: ConvertResult) -> str:
        text = f"{result.gaussians} Gaussians, median spacing {result.median_spacing_m:.3g} m"
        if result.memory_limit_mb is not None:
            text += f", streamed in {result.cells} cells (peak {result.peak_rss_mb or 0:.0f} MiB)"
        return text


def _lines(caught: list[warnings.WarningMessage]) -> tuple[str, ...]:
    """The warnings' messages, one line each."""
    return tuple(" ".join(str(w.message).split()) for w in caught)


def _run_streamed(ctx: StageContext, opts: ConvertStageOptions) -> ConvertResult:
    """The fused cloud converted chunk by chunk (:func:`fusion.convert_stream.convert_stream`) into the same
    export/mvs_gaussians.ply as the in-memory path; temporary cell files in export/."""
    from fusion.convert_stream import StreamOptions, convert_stream
    from hybridsplat.manifest import PeakMemory
    from recon.workspace import fused_source

    source = fused_source(ctx.layout.dense)
    ctx.layout.mvs_gaussians.parent.mkdir(parents=True, exist_ok=True)
    stream = StreamOptions(memory_limit_mb=opts.memory_limit_mb, work_dir=ctx.layout.mvs_gaussians.parent)
    ctx.progress("points", 0, 1)
    # the stage's own peak (sampled resident memory), not ru_maxrss, which keeps the earlier stages' peaks
    with PeakMemory() as memory, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = convert_stream(
            source, opts.mode, opts.conversion, stream, ply_path=ctx.layout.mvs_gaussians, extra_fields=True
        )
    ctx.progress("points", result.num_points, result.num_points)
    return ConvertResult(
        gaussians=result.num_points,
        mean_nn_spacing_m=result.stats.mean_nn_spacing,
        median_spacing_m=result.stats.median_spacing,
        warnings=_lines(caught),
        memory_limit_mb=opts.memory_limit_mb,
        peak_rss_mb=memory.peak_mb,
        cells=result.cells,
        fallback_points=result.fallback_points,
    )
