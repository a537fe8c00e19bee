"""Stage ``mvs``: depth and normal maps per photo, fused by COLMAP into the dense cloud (PROJECT/dense).

Held-out photos are undistorted with the others (for evaluation) but never used for depth or fusion.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from core.io.json_io import write_json_atomic
from hybridsplat.project_io import model_origin
from hybridsplat.stages.base import CliOption, Stage, StageContext
from recon.mvs import MvsOptions


class MvsStage(Stage):
    name = "mvs"
    Options = MvsOptions
    title = "dense depth maps and fusion"
    command = "mvs"
    command_help = "Depth + normal maps per photo, fused by COLMAP into PROJECT/dense/fused.ply (+ .vis)."
    command_options = (
        CliOption("backend", help="auto | cpu | colmap (PatchMatch, needs CUDA)."),
        CliOption("max_image_size", help="Longer side of the dense images, px (-1: full size)."),
        CliOption("num_threads", "--threads", help="CPU threads of the cpu backend (none: all)."),
        CliOption("fusion.min_num_pixels", help="Fusion: minimum number of agreeing views."),
    )
    run_options = (
        CliOption("backend", "--mvs-backend", help="auto | cpu | colmap (COLMAP PatchMatch needs CUDA)."),
        CliOption("max_image_size", help="Longer side of the dense images, px (-1: full size)."),
    )

    def inputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.sparse, ctx.source.image_dir]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.dense, ctx.layout.record(self.name)]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout_names)}

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from core.io.origin import write_origin
        from recon.mvs import run_mvs

        layout = ctx.layout
        options = replace(ctx.options(self), held_out=frozenset(ctx.source.holdout_names))
        report = run_mvs(layout.sparse, ctx.source.image_dir, layout.dense, options, ctx.progress)
        origin = model_origin(layout)
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
