"""Stage ``convert``: the dense MVS points become Gaussians (export/mvs_gaussians.ply), see fusion.convert."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fusion.convert_options import DEFAULT_MODE, ConvertMode, ConvertOptions
from hybridsplat.stages import sizes
from hybridsplat.stages.base import CliOption, Stage, StageContext


@dataclass(frozen=True)
class ConvertStageOptions:
    """Options of the ``convert`` stage: the conversion ``mode`` (:class:`fusion.convert.ConvertMode`: ``adaptive``,
    the default everywhere, or ``paper``, Eq. 1-4 exactly) and its parameters (:class:`fusion.convert.ConvertOptions`,
    ``[convert.conversion]``)."""

    mode: ConvertMode = DEFAULT_MODE
    conversion: ConvertOptions = field(default_factory=ConvertOptions)


class ConvertStage(Stage):
    name = "convert"
    Options = ConvertStageOptions
    title = "MVS points to Gaussians"
    run_options = (CliOption("mode", "--convert-mode", help="MVS-to-Gaussian conversion: adaptive | paper."),)

    def inputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.fused_ply, ctx.layout.fused_vis]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.mvs_gaussians]

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of export/mvs_gaussians.ply: one SH-degree-0 Gaussian per fused point with the fused cloud's extra
        fields and ``source`` appended (4 bytes a property), its origin sidecar, and the log (64 KiB)."""
        fused = sizes.ply_vertices(ctx.layout.fused_ply)
        gaussians = sizes.gaussian_ply_bytes(fused.count, 0, len(fused.extras) + 1)
        return gaussians + sizes.SIDECAR_BYTES + sizes.LOG_BYTES

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from core.io.gaussian_ply import write_gaussian_ply
        from fusion.convert import convert_points
        from recon.workspace import read_fused

        opts: ConvertStageOptions = ctx.options(self)
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
        return f"{counts['gaussians']} Gaussians, median spacing {counts['median_spacing_m']:.3g} m"
