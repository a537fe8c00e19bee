"""Stage ``baseline``: the whole-scene 3DGS baseline (splats/baseline.ply), the product the hybrid is compared with.

Plain 3D Gaussian Splatting as the reference paper compares against: the same trainer, renderer, resolution and
Gaussian cap as the ``train`` stage, but with mask = whole image, no frozen MVS context, and one initial Gaussian
per SfM point. It trains on the same photos (held-out photos excluded). Off unless asked for (``run --baseline``;
the demo turns it on): a survey does not need it, a comparison does.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from core.errors import ConfigError
from hybridsplat.stages.base import Stage, StageContext, read_project_model


@dataclass(frozen=True)
class BaselineStageOptions:
    """Options of the ``baseline`` stage.

    enabled: train the baseline at all (off by default: it costs a whole-scene training).
    iterations: maximum steps (early stop on 5 % held-back pixels, as in ``train``).
    downscale, max_image_size: as the ``train`` stage's (same defaults, so both train at the same resolution).
    cap: hard Gaussian budget (the ``train`` stage's hard cap by default: "same Gaussian cap").
    sh_degree: highest SH degree.
    refine_start / refine_until: densification window, as the ``train`` stage's (same defaults). On the demo
        tabletop (seed 1) 1000 steps reached 19.99 dB held-out masked PSNR (23.82 whole image) with densification
        from step 100 to 500, against 17.81 (20.81) when it ran from step 500 to the last step.
    checkpoints: steps (< iterations) after which the splats are also written to splats/baseline_checkpoints/,
        with the seconds the stage had taken by then (counts ``checkpoints``): points of one run's time against
        error curve, which the eval stage measures as products ``baseline_<step>``. A checkpoint is the state of
        the longer run at that step (learning rates and densification scheduled for ``iterations`` steps), not
        what a run of that many steps would give.
    """

    enabled: bool = False
    iterations: int = 2000
    downscale: int = 1
    max_image_size: int = 640
    cap: int = 60_000
    sh_degree: int = 3
    refine_start: int = 100
    refine_until: float = 0.5
    checkpoints: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.downscale < 1 or self.cap < 1 or self.max_image_size < 0:
            raise ConfigError("baseline: iterations, downscale and cap must be >= 1, max_image_size >= 0")
        if any(not 1 <= int(s) < self.iterations for s in self.checkpoints):
            raise ConfigError(f"baseline: checkpoints must be steps from 1 to iterations - 1 ({self.iterations - 1}), "
                              f"got {list(self.checkpoints)}")  # fmt: skip
        if self.refine_start < 0 or not 0.0 < self.refine_until <= 1.0:
            raise ConfigError("baseline: need refine_start >= 0 and 0 < refine_until <= 1")


class BaselineStage(Stage):
    name = "baseline"
    Options = BaselineStageOptions
    title = "whole-scene 3DGS baseline"

    def inputs(self, ctx: StageContext) -> list[Path]:
        ws = ctx.layout.dense_workspace
        return [ctx.layout.sparse, ws.sparse, ws.images]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.baseline_splats, ctx.layout.baseline_checkpoints_dir]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout_names)}

    def needs(self, ctx: StageContext) -> str | None:
        if not ctx.options(self).enabled:
            return "not requested (run --baseline, or [baseline] enabled = true): only needed for comparison"
        return None

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from core.io.gaussian_ply import write_gaussian_ply
        from core.io.images import read_image
        from fusion.train import DefaultStrategy, TrainOptions, train_splats
        from fusion.train.init import sfm_seeds
        from hybridsplat.stages.train import training_downscale

        t0 = time.perf_counter()
        opts: BaselineStageOptions = ctx.options(self)
        layout = ctx.layout
        ws = layout.dense_workspace
        cameras, _ = read_project_model(ctx, ws.sparse)
        _, sfm = read_project_model(ctx, layout.sparse)
        held_out = set(ctx.source.holdout_names)
        images = {v.name: read_image(ws.images / v.name) for v in cameras if v.name not in held_out}
        init = sfm_seeds(sfm.world_positions - cameras.origin, sfm.colors if len(sfm) else None, cameras.origin)
        downscale = training_downscale(cameras, opts.downscale, opts.max_image_size)
        train_opts = TrainOptions(iterations=opts.iterations, downscale=downscale, seed=ctx.config.seed,
                                  sh_degree=opts.sh_degree, refine_until=opts.refine_until,
                                  snapshot_iterations=tuple(int(s) for s in opts.checkpoints),
                                  strategy=DefaultStrategy(cap=opts.cap, refine_start=opts.refine_start))  # fmt: skip

        def progress(info) -> None:
            ctx.progress(
                f"loss {info.loss:.4f} PSNR {info.holdout_psnr:.2f} dB, {info.gaussians} splats",
                info.step,
                info.iterations,
            )

        setup = time.perf_counter() - t0
        result = train_splats(cameras, images, None, init, None, train_opts, progress)
        write_gaussian_ply(layout.baseline_splats, result.splats)
        # Written even when empty: a recorded output that does not exist would make the stage never up to date.
        layout.baseline_checkpoints_dir.mkdir(parents=True, exist_ok=True)
        for step, snap in sorted(result.snapshots.items()):
            write_gaussian_ply(layout.baseline_checkpoints_dir / f"baseline_{step:06d}.ply", snap)
        return {
            "splats": len(result.splats),
            "initial": result.initial_gaussians,
            "downscale": downscale,
            "cap": opts.cap,
            "iterations": result.iterations,
            "stopped_early": result.stopped_early,
            "holdout_psnr_db": result.final_holdout_psnr,
            "views_used": result.views_used,
            "resolution": list(result.resolution),
            "seconds_training": result.seconds,
            # (step, seconds since the start, PSNR on the held-back pixels) per evaluation window
            "history": [[c.step, round(c.seconds, 3), round(c.holdout_psnr, 3)] for c in result.history],
            # step -> seconds of the stage until that checkpoint (the setup before the training included)
            "checkpoints": {str(s): round(setup + t, 3) for s, t in sorted(result.snapshot_seconds.items())},
        }

    def summary(self, counts: dict[str, Any]) -> str:
        return (
            f"{counts['splats']} splats after {counts['iterations']} steps, "
            f"PSNR {counts['holdout_psnr_db']:.2f} dB on held-back pixels"
        )
