"""Stage ``mvs``: depth and normal maps per photo, fused by COLMAP into the dense cloud (PROJECT/dense).

Held-out photos are undistorted with the others (for evaluation) but never used for depth or fusion, on every
backend: they get no depth or normal map, are no other photo's source (their pixels are never read for depth) and are
not in ``dense/stereo/fusion.cfg`` (COLMAP PatchMatch runs the explicit ``dense/stereo/patch-match.cfg`` that
:mod:`recon.mvs` writes).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from core.io.json_io import write_json_atomic
from hybridsplat.disk_space import tree_bytes
from hybridsplat.project_io import model_origin, sparse_model
from hybridsplat.stages import sizes
from hybridsplat.stages.base import CliOption, Stage, StageContext, StageResult
from recon.mvs import MvsOptions


@dataclass(frozen=True)
class MvsResult(StageResult):
    """What the mvs stage made: the ``backend`` that ran (cpu | colmap), depth maps of ``views`` photos (the
    ``held_out`` ones aside), the longer side of the dense images (``image_size``, px), ``points`` fused points and
    the seconds a view took (``seconds_per_view``)."""

    backend: str = ""
    views: int = 0
    held_out: int = 0
    image_size: int = 0
    points: int = 0
    seconds_per_view: float = 0.0


class MvsStage(Stage):
    name = "mvs"
    Options = MvsOptions
    Result = MvsResult
    title = "dense depth maps and fusion"
    command = "mvs"
    command_help = "Depth + normal maps per photo, fused by COLMAP into PROJECT/dense/fused.ply (+ .vis)."
    command_options = (
        CliOption("backend", help="auto | cpu | colmap (PatchMatch, needs CUDA)."),
        CliOption("max_image_size", help="Longer side of the dense images, px (-1: full size)."),
        CliOption("cpu.quality", "--mvs-quality", help="CPU MVS effort: fast | balanced | high (hypotheses a pixel)."),
        CliOption("num_threads", "--threads", help="CPU threads of the cpu backend (none: all)."),
        CliOption("fusion.min_num_pixels", help="Fusion: minimum number of agreeing views."),
    )
    run_options = (
        CliOption("backend", "--mvs-backend", help="auto | cpu | colmap (COLMAP PatchMatch needs CUDA)."),
        CliOption("max_image_size", help="Longer side of the dense images, px (-1: full size)."),
        CliOption("cpu.quality", "--mvs-quality", help="CPU MVS effort: fast | balanced | high (hypotheses a pixel)."),
    )

    def inputs(self, ctx: StageContext) -> list[Path]:
        return [sparse_model(ctx.layout), ctx.source.image_dir]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.dense, ctx.layout.record(self.name)]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout_names)}

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of the dense workspace, the record and COLMAP's log, for n registered photos of W × H px (the
        largest camera, +10 % a side for undistortion, capped at ``max_image_size``): per photo its undistorted RGB
        PNG and 32·W·H bytes of photometric and geometric depth (4 bytes a pixel) and normal (12) maps (counted for
        held-out photos too, which get none: a small over-estimate); a fused point per ``fusion.min_num_pixels``
        pixels of the fused photos, 27 bytes in fused.ply and 4 in fused.ply.vis, plus 4 bytes a fused pixel in the
        .vis; a copy of the sparse model (+256 bytes a photo); the configuration 4 KiB + 1 KiB a photo; the record
        64 KiB + 256 bytes a photo; the log 64 KiB + 8 KiB a photo."""
        opts: MvsOptions = ctx.options(self)
        n = sizes.model_count(sparse_model(ctx.layout), "images") or len(ctx.source.spec.image_names)
        width, height = dense_size(sparse_model(ctx.layout), opts.max_image_size)
        photos = n * (sizes.png_bytes(width, height, 3) + 2 * (4 + 12) * width * height + 4 * 64)
        fused_pixels = max(n - len(ctx.source.holdout_names), 0) * width * height
        points = -(-fused_pixels // max(opts.fusion.min_num_pixels, 1))
        fused = 2 * sizes.PLY_HEADER_BYTES + (27 + 4) * points + 4 * fused_pixels + sizes.SIDECAR_BYTES
        model = tree_bytes([sparse_model(ctx.layout)]) + 256 * n
        text = 4 * sizes.KIB + sizes.JSON_BYTES + sizes.LOG_BYTES + (1 + 8) * sizes.KIB * n + 256 * n
        return photos + fused + model + text

    def run(self, ctx: StageContext) -> MvsResult:
        from core.io.origin import write_origin
        from recon.mvs import run_mvs

        layout = ctx.layout
        options = replace(ctx.options(self), held_out=frozenset(ctx.source.holdout_names))
        report = run_mvs(sparse_model(layout), ctx.source.image_dir, layout.dense, options, ctx.progress)
        origin = model_origin(layout)
        if np.any(origin != 0):  # the model is in a local frame: fused.ply (float32) gets the offset sidecar
            write_origin(layout.fused_ply, origin, ctx.config.input.crs)
        write_json_atomic(layout.record(self.name), {"report": report, "options": options})
        return MvsResult(
            backend=report.backend,
            views=report.num_views,
            held_out=len(ctx.source.holdout_names),
            image_size=max(max(s) for s in report.image_sizes) if report.image_sizes else 0,
            points=report.num_points,
            seconds_per_view=report.seconds_per_view,
        )

    def summary(self, result: MvsResult) -> str:
        return (
            f"{result.backend}: {result.views} views at {result.image_size} px, "
            f"{result.seconds_per_view:.1f} s/view, {result.points} fused points"
        )


def dense_size(sparse: Path, max_image_size: int) -> tuple[int, int]:
    """(width, height) in pixels bounding the undistorted photos: the largest camera of ``sparse`` with 10 % more a
    side (undistortion of a distorted camera may enlarge it), capped at ``max_image_size`` (-1: no cap)."""
    cameras = sizes.camera_sizes(sparse)
    if not cameras:  # no model: the stage fails before it writes a map
        return 0, 0
    width, height = sizes.largest(cameras)
    return sizes.capped_size((-(-width * 11 // 10), -(-height * 11 // 10)), max_image_size)
