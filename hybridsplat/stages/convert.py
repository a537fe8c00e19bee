"""Stage ``convert``: the dense MVS points become Gaussians (export/mvs_gaussians.ply), see fusion.convert; with
``memory_limit_mb`` the fused cloud is converted in chunks with bounded memory (fusion.convert_stream), same file."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fusion.convert_options import DEFAULT_MODE, ConvertMode, ConvertOptions
from hybridsplat.stages import sizes
from hybridsplat.stages.base import MEMORY_LIMIT_HELP, CliOption, Stage, StageContext

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


class ConvertStage(Stage):
    name = "convert"
    Options = ConvertStageOptions
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

    def run(self, ctx: StageContext) -> dict[str, Any]:
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
        return {
            "gaussians": len(result.gaussians),
            "mean_nn_spacing_m": result.stats.mean_nn_spacing,
            "median_spacing_m": result.stats.median_spacing,
            "warnings": [" ".join(str(w.message).split()) for w in caught],
        }

    def summary(self, counts: dict[str, Any]) -> str:
        text = f"{counts['gaussians']} Gaussians, median spacing {counts['median_spacing_m']:.3g} m"
        if counts.get("memory_limit_mb") is not None:
            text += f", streamed in {counts['cells']} cells (peak {counts['peak_rss_mb']:.0f} MiB)"
        return text


def _run_streamed(ctx: StageContext, opts: ConvertStageOptions) -> dict[str, Any]:
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
    return {
        "gaussians": result.num_points,
        "mean_nn_spacing_m": result.stats.mean_nn_spacing,
        "median_spacing_m": result.stats.median_spacing,
        "warnings": [" ".join(str(w.message).split()) for w in caught],
        "memory_limit_mb": opts.memory_limit_mb,
        "peak_rss_mb": memory.peak_mb,
        "cells": result.cells,
        "fallback_points": result.fallback_points,
    }
