"""Stage ``background``: the background layer, what the photos see beyond the survey region (splats/background.ply).

Trained behind the frozen survey (MVS) and fill (cleaned splats) Gaussians on the training photos' background
pixels, at reduced resolution (:mod:`fusion.background`); ``merge`` adds it to the viewer product with
``source`` = ``Source.BACKGROUND``. A scene whose photos see nothing beyond the survey region gets an empty layer,
and the stage says why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fusion.background import BackgroundOptions
from hybridsplat.records import TypedRecord
from hybridsplat.stages import sizes
from hybridsplat.stages.base import Stage, StageContext, StageResult, omitted_if_none


@dataclass(frozen=True)
class ShellScore(TypedRecord):
    """How much the photos disagree about a candidate shell radius (mean colour disagreement over ``pairs`` of
    photos seeing the same direction)."""

    disagreement: float = math.nan
    pairs: int = 0


@dataclass(frozen=True)
class BackgroundResult(StageResult):
    """What the background stage made (the counts of :func:`fusion.background.train_background`): the ``share`` of
    the training photos' pixels beyond the survey region (0..1), the ``seeds`` and trained ``gaussians``, the photo
    ``downscale``, the shell's radius (m; ``shell_multiple`` of the region's radius, ``shell_decided``: chosen by
    the photos' agreement) and each candidate's score (``shell_scores``, by multiple), the region's radius (m), the
    Gaussians extrapolated to directions no photo shows (``unseen_gaussians``), the training's steps, whether it
    stopped early and its PSNR on held-back pixels (dB). ``reason``: why there is no background layer, when
    there is none."""

    share: float = 0.0
    seeds: int = 0
    gaussians: int = 0
    downscale: int = 1
    shell_radius_m: float = 0.0
    shell_multiple: float = 0.0
    shell_decided: bool = False
    shell_scores: dict[str, ShellScore] = field(default_factory=dict)
    region_radius_m: float = 0.0
    unseen_gaussians: int = 0
    iterations: int = 0
    stopped_early: bool = False
    holdout_psnr_db: float | None = None
    reason: str | None = omitted_if_none()


class BackgroundStage(Stage):
    name = "background"
    Options = BackgroundOptions
    Result = BackgroundResult
    title = "background layer"
    uses_seed = True

    def inputs(self, ctx: StageContext) -> list[Path]:
        layout, ws = ctx.layout, ctx.layout.dense_workspace
        fill = [layout.cleaned_splats] if layout.cleaned_splats.is_file() else []
        return [layout.mvs_gaussians, *fill, ws.sparse, ws.images]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.background_splats]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout_names)}

    def needs(self, ctx: StageContext) -> str | None:
        opts: BackgroundOptions = ctx.options(self)
        return None if opts.enabled else "off ([background] enabled = false): the viewer product has no background"

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of splats/background.ply: at most the strategy's cap (and twice ``max_seeds``) Gaussians at the
        training SH degree, an origin sidecar and the log (64 KiB)."""
        opts: BackgroundOptions = ctx.options(self)
        cap = max(getattr(opts.training.strategy, "cap", 0), 2 * opts.max_seeds)
        return sizes.gaussian_ply_bytes(cap, opts.training.sh_degree) + sizes.SIDECAR_BYTES + sizes.LOG_BYTES

    def run(self, ctx: StageContext) -> BackgroundResult:
        from core.gaussians import GaussianSet
        from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply
        from hybridsplat import project_io

        layout = ctx.layout
        cameras, images = project_io.read_training_photos(layout, set(ctx.source.holdout_names))
        layers = [read_gaussian_ply(layout.mvs_gaussians)]
        if layout.cleaned_splats.is_file():
            layers.append(read_gaussian_ply(layout.cleaned_splats))
        foreground = GaussianSet.concatenate([g.with_origin(cameras.origin) for g in layers])
        from fusion.background import train_background  # torch: after the inputs are read

        def progress(info: Any) -> None:
            ctx.progress(f"loss {info.loss:.4f}, {info.gaussians} Gaussians", info.step, info.iterations)

        result = train_background(cameras, images, foreground, ctx.options(self), ctx.config.seed, progress)
        if isinstance(result, str):
            write_gaussian_ply(layout.background_splats, _empty(cameras.origin))
            return BackgroundResult(reason=result)
        write_gaussian_ply(layout.background_splats, result.gaussians)
        return BackgroundResult(**result.counts)

    def summary(self, result: BackgroundResult) -> str:
        if not result.gaussians:
            return f"no background layer: {result.reason or 'nothing to train'}"
        chosen = " (chosen by the photos' agreement)" if result.shell_decided else ""
        unseen = result.unseen_gaussians
        unseen_text = f" ({unseen} extrapolated to directions no photo shows)" if unseen else ""
        return (
            f"{result.gaussians} Gaussians on a {result.shell_radius_m:.3g} m shell{chosen}{unseen_text}, "
            f"{100 * result.share:.1f} % of the pixels, {result.iterations} steps"
        )


def _empty(origin: Any) -> Any:
    import numpy as np

    from core.gaussians import GaussianSet

    return GaussianSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3)),
                       np.zeros((0, 0, 3)), origin=origin)  # fmt: skip
