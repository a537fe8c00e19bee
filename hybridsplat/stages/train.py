"""Stage ``train``: new splats trained inside the region masks next to the frozen MVS Gaussians (splats/trained.ply
and splats/snapshots/), see :func:`fusion.train.masked.train_in_masks`.

Reads the undistorted photos and model of the dense workspace (held-out photos excluded), the classified cloud
(``needs_splats`` per MVS point), the training masks, the MVS Gaussians (export/mvs_gaussians.ply, one per fused
point) and the SfM points. Skipped when the scene has no classification or no mask pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fusion.train.masked import MaskedTrainingOptions
from fusion.train.strategy import RefineCounts
from hybridsplat.project_io import sparse_model
from hybridsplat.records import TypedRecord
from hybridsplat.stages import sizes
from hybridsplat.stages.base import CliOption, Stage, StageContext, StageResult, omitted_if_none


@dataclass(frozen=True)
class TrainSeeds(TypedRecord):
    """Where the initial splats came from: MVS points that need splats, SfM points in the masks, points along mask
    pixels' rays, and of those the rays without a depth to place them at."""

    mvs: int = 0
    sfm: int = 0
    rays: int = 0
    rays_without_depth: int = 0


@dataclass(frozen=True)
class TrainResult(StageResult):
    """What the train stage made: ``trained`` splats after ``iterations`` steps (``stopped_early``: by the early
    stop, else its whole budget), their masked PSNR on the held-back pixels (dB; NaN without an evaluation), at
    photo ``downscale`` and ``resolution`` (W, H px) within ``cap`` splats; the views used and those without a
    mask pixel, the mask pixels, the frozen MVS ``context_gaussians`` and how many were culled, the ``seeds``,
    the strategy's ``refine`` counts (summed over the run), the training's seconds and the neighbours' splats
    frozen beside a tile (``neighbour_context``). ``reason``: why nothing was trained, when nothing was."""

    trained: int = 0
    downscale: int = 1
    cap: int = 0
    iterations: int = 0
    stopped_early: bool = False
    holdout_psnr_db: float = math.nan
    views_used: int = 0
    views_without_mask: int = 0
    mask_pixels: int = 0
    context_gaussians: int = 0
    context_culled: int = 0
    seeds: TrainSeeds = field(default_factory=TrainSeeds)
    refine: RefineCounts = field(default_factory=RefineCounts)
    resolution: tuple[int, ...] = ()
    seconds_training: float = 0.0
    neighbour_context: int = 0
    reason: str | None = omitted_if_none()


class TrainStage(Stage):
    name = "train"
    Options = MaskedTrainingOptions
    Result = TrainResult
    title = "masked splat training"
    uses_seed = True
    command = "train"
    command_help = ("Train new splats inside the masks with the trusted MVS Gaussians frozen as context (a progress "
                    "bar shows masked loss, masked PSNR and the splat count).")  # fmt: skip
    command_options = (
        CliOption("training.iterations", help="Maximum training steps (early stop on hold-out pixels)."),
        CliOption("training.downscale", help="Integer downscale of photos and masks for training (at least)."),
        CliOption("training.strategy.cap", "--cap", help="Hard budget of trained splats."),
    )
    run_options = (
        CliOption("training.iterations", "--train-iterations",
                  help="Most splat-training steps (default: the train stage's; it stops early on a plateau)."),
    )  # fmt: skip

    def inputs(self, ctx: StageContext) -> list[Path]:
        ws = ctx.layout.dense_workspace
        layout = ctx.layout
        context = [layout.neighbour_splats] if layout.neighbour_splats.is_file() else []  # a tile's, see tile_context
        return [layout.classified_points, layout.masks_dir, layout.record("masks"), layout.mvs_gaussians, ws.sparse,
                ws.images, *context]  # fmt: skip

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.trained_splats, ctx.layout.snapshots_dir]

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of splats/trained.ply and its snapshots (one per ``snapshot_iterations`` step within the run),
        each at most the run's Gaussian budget at the training SH degree (:func:`_training_budget`), with origin
        sidecars, and the log (64 KiB)."""
        opts: MaskedTrainingOptions = ctx.options(self)
        files = 1 + sizes.snapshot_count(opts.snapshot_iterations, opts.training.iterations)
        budget = _training_budget(ctx.layout.dense_workspace.sparse, opts)
        splats = sizes.gaussian_ply_bytes(budget, opts.training.sh_degree)
        return files * (splats + sizes.SIDECAR_BYTES) + sizes.LOG_BYTES

    def needs(self, ctx: StageContext) -> str | None:
        from hybridsplat.project_io import has_region_masks, read_masks_record

        if not ctx.layout.classified_points.is_file():
            return "no classified cloud (classify/points.ply): no region to train splats in"
        if not has_region_masks(ctx.layout):
            return "no region masks (classify/masks): nothing needs splats"
        record = read_masks_record(ctx.layout)
        if record is not None and not record.training_needed:
            return "every region mask is empty: no non-collaborative region or hole needs splats"
        return None

    def run(self, ctx: StageContext) -> TrainResult:
        from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply
        from core.io.images import read_image
        from hybridsplat import project_io

        opts: MaskedTrainingOptions = ctx.options(self)
        layout = ctx.layout
        ws = layout.dense_workspace
        cameras, _ = project_io.read_project_model(layout, ws.sparse)
        _, sfm = project_io.read_project_model(layout, sparse_model(layout))
        held_out = set(ctx.source.holdout_names) if ctx.source is not None else set()
        masks = project_io.read_region_masks(layout, cameras, training=True)
        masks = {k: m for k, m in masks.items() if k not in held_out}  # never train on those
        if not any(m.any() for m in masks.values()):
            return TrainResult(reason="masks are empty")
        images = {v.name: read_image(ws.images / v.name) for v in cameras if v.name in masks}
        mvs = read_gaussian_ply(layout.mvs_gaussians).with_origin(cameras.origin)
        neighbours = None  # a tile of a tiled run: its neighbours' splats in the overlap, frozen
        if layout.neighbour_splats.is_file():
            neighbours = read_gaussian_ply(layout.neighbour_splats).with_origin(cameras.origin)
        needs = project_io.needs_splats_per_gaussian(layout, mvs)
        sfm_points = (sfm.world_positions - cameras.origin, sfm.colors) if len(sfm) else None
        # torch from here on: the inputs above have been read and checked
        from fusion.train.masked import train_in_masks

        def progress(info) -> None:
            ctx.progress(f"loss {info.loss:.4f} masked PSNR {info.holdout_psnr:.2f} dB, {info.gaussians} splats",
                         info.step, info.iterations)  # fmt: skip

        result, seeds, used = train_in_masks(cameras, images, masks, mvs, needs, sfm_points, opts, ctx.config.seed,
                                             progress, neighbours=neighbours)  # fmt: skip
        write_gaussian_ply(layout.trained_splats, result.splats)
        layout.snapshots_dir.mkdir(parents=True, exist_ok=True)
        for step, snap in sorted(result.snapshots.items()):
            write_gaussian_ply(layout.snapshots_dir / f"splats_{step:06d}.ply", snap)
        return _result(result, seeds, used, neighbours=len(neighbours or ()))

    def summary(self, result: TrainResult) -> str:
        if not result.trained:
            return "no splats trained"
        return f"{result.trained} splats after {result.iterations} steps, masked PSNR {result.holdout_psnr_db:.2f} dB"


def _training_budget(model: Path, opts: MaskedTrainingOptions) -> int:
    """The most Gaussians masked training may hold (:func:`fusion.train.masked.train_in_masks`): the strategy's
    ``cap``, and at most ``splats_per_mask_pixel`` × the mask pixels at the training downscale (at least 1000),
    the mask pixels bounded by every pixel of the photos of the dense ``model`` (the largest camera's each)."""
    cameras = sizes.camera_sizes(model)
    cap = opts.training.strategy.cap
    if not cameras:
        return cap
    width, height = sizes.largest(cameras)
    longest = max(max(c) for c in cameras)
    limit = opts.max_image_size
    downscale = max(opts.training.downscale, -(-longest // limit) if limit else 1)
    pixels = sizes.model_count(model, "images") * width * height / downscale**2
    return min(cap, max(1000, round(opts.splats_per_mask_pixel * pixels)))


def _result(result: Any, seeds: Any, used: dict[str, Any], neighbours: int) -> TrainResult:
    """The train stage's result: what was trained, at which resolution and budget, and from which seeds."""
    return TrainResult(
        trained=len(result.splats),
        downscale=used["downscale"],
        cap=used["cap"],
        iterations=result.iterations,
        stopped_early=result.stopped_early,
        holdout_psnr_db=result.final_holdout_psnr,
        views_used=result.views_used,
        views_without_mask=result.views_without_mask,
        mask_pixels=result.mask_pixels,
        context_gaussians=result.context_total,
        context_culled=result.context_culled,
        seeds=TrainSeeds(seeds.from_mvs, seeds.from_sfm, seeds.from_rays, seeds.rays_without_depth),
        refine=result.refine,
        resolution=result.resolution,
        seconds_training=result.seconds,
        neighbour_context=neighbours,
    )
