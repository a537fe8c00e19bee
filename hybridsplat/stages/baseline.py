"""Stage ``baseline``: the whole-scene 3DGS baseline (splats/baseline.ply), the product the hybrid is compared with.

Plain 3D Gaussian Splatting as the reference paper compares against: the same trainer, renderer, resolution and
Gaussian cap as the ``train`` stage, but with mask = whole image, no frozen MVS context, and one initial Gaussian
per SfM point. It trains on the same photos (held-out photos excluded). Off unless asked for (``run --baseline``;
the demo turns it on): a survey does not need it, a comparison does.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fusion.train.masked import WholeSceneOptions
from hybridsplat.project_io import sparse_model
from hybridsplat.stages import sizes
from hybridsplat.stages.base import CliOption, Stage, StageContext, StageResult


@dataclass(frozen=True)
class BaselineResult(StageResult):
    """What the baseline stage made: ``splats`` Gaussians from ``initial`` SfM points after ``iterations`` steps
    (``stopped_early``: by the early stop, else its whole budget) within ``cap``, at photo ``downscale`` and
    ``resolution`` (W, H px), their PSNR on held-back pixels (dB; NaN without an evaluation), the views used, the
    training's seconds; ``history``: (step, seconds since the start, PSNR on the held-back pixels in dB) per
    evaluation window; ``checkpoints``: step → seconds of the stage until that checkpoint (the setup before the
    training included)."""

    splats: int = 0
    initial: int = 0
    downscale: int = 1
    cap: int = 0
    iterations: int = 0
    stopped_early: bool = False
    holdout_psnr_db: float = math.nan
    views_used: int = 0
    resolution: tuple[int, ...] = ()
    seconds_training: float = 0.0
    history: tuple[tuple[int, float, float], ...] = ()
    checkpoints: dict[str, float] = field(default_factory=dict)


class BaselineStage(Stage):
    name = "baseline"
    Options = WholeSceneOptions
    Result = BaselineResult
    title = "whole-scene 3DGS baseline"
    uses_seed = True
    run_options = (
        CliOption("enabled", "--baseline", value=True,
                  help="Also train the whole-scene 3DGS baseline and compare with it in the report."),
    )  # fmt: skip

    def inputs(self, ctx: StageContext) -> list[Path]:
        ws = ctx.layout.dense_workspace
        return [sparse_model(ctx.layout), ws.sparse, ws.images]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.baseline_splats, ctx.layout.baseline_checkpoints_dir]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout_names)}

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of splats/baseline.ply and its checkpoints (one per ``checkpoints`` step), each with at most the
        strategy's ``cap`` Gaussians, or, when the run is too short for the strategy to densify, at most the SfM
        points it starts from; at the training SH degree, with origin sidecars, and the log (64 KiB)."""
        opts: WholeSceneOptions = ctx.options(self)
        training = opts.training
        count = training.strategy.cap
        points = sizes.model_count(sparse_model(ctx.layout), "points3D")
        if points and not sizes.can_densify(training.strategy, training.iterations):
            count = min(count, points)
        files = 1 + sizes.snapshot_count(opts.checkpoints, training.iterations)
        return files * (sizes.gaussian_ply_bytes(count, training.sh_degree) + sizes.SIDECAR_BYTES) + sizes.LOG_BYTES

    def needs(self, ctx: StageContext) -> str | None:
        if not ctx.options(self).enabled:
            return "not requested (run --baseline, or [baseline] enabled = true): only needed for comparison"
        return None

    def run(self, ctx: StageContext) -> BaselineResult:
        from core.io.gaussian_ply import write_gaussian_ply
        from core.io.images import read_image
        from fusion.train.masked import train_whole_scene
        from hybridsplat.project_io import read_project_model

        t0 = time.perf_counter()
        opts: WholeSceneOptions = ctx.options(self)
        layout = ctx.layout
        ws = layout.dense_workspace
        cameras, _ = read_project_model(layout, ws.sparse)
        _, sfm = read_project_model(layout, sparse_model(layout))
        held_out = set(ctx.source.holdout_names)
        images = {v.name: read_image(ws.images / v.name) for v in cameras if v.name not in held_out}
        sfm_points = (sfm.world_positions - cameras.origin, sfm.colors if len(sfm) else None)

        def progress(info) -> None:
            ctx.progress(f"loss {info.loss:.4f} PSNR {info.holdout_psnr:.2f} dB, {info.gaussians} splats",
                         info.step, info.iterations)  # fmt: skip

        setup = time.perf_counter() - t0
        result, downscale = train_whole_scene(cameras, images, sfm_points, opts, ctx.config.seed, progress)
        write_gaussian_ply(layout.baseline_splats, result.splats)
        # Written even when empty: a recorded output that does not exist would make the stage never up to date.
        layout.baseline_checkpoints_dir.mkdir(parents=True, exist_ok=True)
        for step, snap in sorted(result.snapshots.items()):
            write_gaussian_ply(layout.baseline_checkpoints_dir / f"baseline_{step:06d}.ply", snap)
        return BaselineResult(
            splats=len(result.splats),
            initial=result.initial_gaussians,
            downscale=downscale,
            cap=opts.training.strategy.cap,
            iterations=result.iterations,
            stopped_early=result.stopped_early,
            holdout_psnr_db=result.final_holdout_psnr,
            views_used=result.views_used,
            resolution=result.resolution,
            seconds_training=result.seconds,
            history=tuple((c.step, round(c.seconds, 3), round(c.holdout_psnr, 3)) for c in result.history),
            checkpoints={str(s): round(setup + t, 3) for s, t in sorted(result.snapshot_seconds.items())},
        )

    def summary(self, result: BaselineResult) -> str:
        return (
            f"{result.splats} splats after {result.iterations} steps, "
            f"PSNR {result.holdout_psnr_db:.2f} dB on held-back pixels"
        )
