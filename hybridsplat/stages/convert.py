"""Stage ``convert``: the dense MVS points become Gaussians (export/mvs_gaussians.ply), see fusion.convert."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from core.errors import ConfigError
from fusion.convert import DEFAULT_MODE, ConvertMode
from hybridsplat.stages.base import Stage, StageContext


@dataclass(frozen=True)
class ConvertStageOptions:
    """Options of the ``convert`` stage.

    mode: ``adaptive`` (per-point spacing from k neighbours, surfels along the MVS normal, opacity from the
        number of views; the default everywhere, ``hybridsplat convert`` included) or ``paper`` (Eq. 1-4 exactly).
    """

    mode: str = DEFAULT_MODE.value

    def __post_init__(self) -> None:
        try:
            ConvertMode(self.mode)
        except ValueError as err:
            raise ConfigError(
                f"mode must be one of {', '.join(m.value for m in ConvertMode)}, got {self.mode!r}"
            ) from err


class ConvertStage(Stage):
    name = "convert"
    Options = ConvertStageOptions
    title = "MVS points to Gaussians"

    def inputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.fused_ply, ctx.layout.fused_vis]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.mvs_gaussians]

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from core.io.gaussian_ply import write_gaussian_ply
        from fusion.convert import convert_points
        from recon.workspace import read_fused

        opts: ConvertStageOptions = ctx.options(self)
        cloud = read_fused(ctx.layout.dense)
        ctx.progress("points", 0, len(cloud))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = convert_points(cloud, ConvertMode(opts.mode))
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
