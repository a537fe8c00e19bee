"""Stage ``background``: the background layer, what the photos see beyond the survey region (splats/background.ply).

Trained behind the frozen survey (MVS) and fill (cleaned splats) Gaussians on the training photos' background
pixels, at reduced resolution (:mod:`fusion.background`); ``merge`` adds it to the viewer product with
``source`` = ``Source.BACKGROUND``. A scene whose photos see nothing beyond the survey region gets an empty layer,
and the stage says why.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fusion.background import BackgroundOptions
from hybridsplat.stages import sizes
from hybridsplat.stages.base import Stage, StageContext


class BackgroundStage(Stage):
    name = "background"
    Options = BackgroundOptions
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

    def run(self, ctx: StageContext) -> dict[str, Any]:
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
            return {"gaussians": 0, "reason": result}
        write_gaussian_ply(layout.background_splats, result.gaussians)
        return result.counts

    def summary(self, counts: dict[str, Any]) -> str:
        if not counts.get("gaussians"):
            return f"no background layer: {counts.get('reason', 'nothing to train')}"
        chosen = " (chosen by the photos' agreement)" if counts.get("shell_decided") else ""
        unseen = counts.get("unseen_gaussians", 0)
        unseen_text = f" ({unseen} extrapolated to directions no photo shows)" if unseen else ""
        return (
            f"{counts['gaussians']} Gaussians on a {counts['shell_radius_m']:.3g} m shell{chosen}{unseen_text}, "
            f"{100 * counts['share']:.1f} % of the pixels, {counts['iterations']} steps"
        )


def _empty(origin: Any) -> Any:
    import numpy as np

    from core.gaussians import GaussianSet

    return GaussianSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3)),
                       np.zeros((0, 0, 3)), origin=origin)  # fmt: skip
