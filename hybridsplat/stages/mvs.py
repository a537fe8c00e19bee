"""Stage ``mvs``: depth and normal maps per photo, fused by COLMAP into the dense cloud (PROJECT/dense).

Held-out photos are undistorted with the others (for evaluation) but never used for depth or fusion.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import ConfigError
from core.io.json_io import write_json_atomic
from hybridsplat.stages.base import Stage, StageContext, model_origin
from recon.mvs import FusionOptions, MvsBackend, MvsOptions


@dataclass(frozen=True)
class MvsStageOptions:
    """Options of the ``mvs`` stage.

    backend: auto (COLMAP PatchMatch on CUDA, else our CPU MVS) | cpu | colmap.
    max_image_size: longer side of the dense images in pixels; -1 = full resolution. The default keeps a CPU run
        of a few dozen photos in minutes (a 6-megapixel photo at full size takes over an hour per view on 2 cores).
    threads: CPU threads of the cpu backend (0 = all).
    min_num_pixels: fusion keeps a point seen consistently by at least this many views.
    """

    backend: str = "auto"
    max_image_size: int = 1000
    threads: int = 0
    min_num_pixels: int = 3

    def __post_init__(self) -> None:
        try:
            MvsBackend(self.backend)
        except ValueError as err:
            raise ConfigError(f"backend must be auto, cpu or colmap, got {self.backend!r}") from err
        if self.max_image_size == 0 or self.max_image_size < -1:
            raise ConfigError(f"max_image_size must be -1 (full size) or a positive size, got {self.max_image_size}")


class MvsStage(Stage):
    name = "mvs"
    Options = MvsStageOptions
    title = "dense depth maps and fusion"

    def inputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.sparse, ctx.source.image_dir]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.dense, ctx.layout.record(self.name)]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout_names)}

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from core.io.origin import write_origin
        from recon.mvs import run_mvs

        opts: MvsStageOptions = ctx.options(self)
        layout = ctx.layout
        options = MvsOptions(
            backend=MvsBackend(opts.backend),
            max_image_size=opts.max_image_size,
            num_threads=opts.threads or None,
            fusion=FusionOptions(min_num_pixels=opts.min_num_pixels),
            held_out=frozenset(ctx.source.holdout_names),
        )
        report = run_mvs(layout.sparse, ctx.source.image_dir, layout.dense, options, ctx.progress)
        origin = model_origin(ctx)
        if np.any(origin != 0):  # the model is in a local frame: fused.ply (float32) gets the offset sidecar
            write_origin(layout.fused_ply, origin, ctx.config.input.crs)
        write_json_atomic(layout.record(self.name), {"report": report, "options": options})
        return {
            "backend": report.backend,
            "views": report.num_views,
            "held_out": len(ctx.source.holdout_names),
            "image_size": max(max(s) for s in report.image_sizes) if report.image_sizes else 0,
            "points": report.num_points,
            "seconds_per_view": report.seconds_per_view,
        }

    def summary(self, counts: dict[str, Any]) -> str:
        return (
            f"{counts['backend']}: {counts['views']} views at {counts['image_size']} px, "
            f"{counts['seconds_per_view']:.1f} s/view, {counts['points']} fused points"
        )
