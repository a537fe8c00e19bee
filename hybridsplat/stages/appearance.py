"""Stage ``appearance``: the survey layer's appearance refined for the viewer product (splats/survey.ply).

The MVS Gaussians of the survey layer (export/mvs_gaussians.ply less the points that need splats) get their colour
(SH), opacity, scales and rotations fitted to every pixel of the training photos, the fill (splats/cleaned.ply) and
background (splats/background.ply) layers frozen beside them, positions frozen bit for bit
(:mod:`fusion.appearance`). splats/survey.ply holds one Gaussian per converted MVS Gaussian, in the same order (the
points that need splats unrefined); ``merge`` builds the viewer product from it, while the survey products keep
the converted attributes.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from fusion.appearance import AppearanceOptions
from hybridsplat.stages import sizes
from hybridsplat.stages.base import Stage, StageContext

if TYPE_CHECKING:
    import numpy as np

    from core.gaussians import GaussianSet
    from hybridsplat.layout import ProjectLayout


class AppearanceStage(Stage):
    name = "appearance"
    Options = AppearanceOptions
    title = "survey-layer appearance"
    uses_seed = True

    def inputs(self, ctx: StageContext) -> list[Path]:
        layout, ws = ctx.layout, ctx.layout.dense_workspace
        optional = [layout.cleaned_splats, layout.background_splats, layout.classified_points]
        return [layout.mvs_gaussians, *(p for p in optional if p.is_file()), ws.sparse, ws.images]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.survey_splats]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout_names)}

    def needs(self, ctx: StageContext) -> str | None:
        opts: AppearanceOptions = ctx.options(self)
        return None if opts.enabled else "off ([appearance] enabled = false): the survey layer keeps its converted look"

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of splats/survey.ply: the converted MVS Gaussians (export/mvs_gaussians.ply's count and fields) at
        the training SH degree, an origin sidecar and the log (64 KiB)."""
        opts: AppearanceOptions = ctx.options(self)
        mvs = sizes.ply_vertices(ctx.layout.mvs_gaussians)
        degree = max(mvs.sh_degree, opts.training.sh_degree)
        return sizes.gaussian_ply_bytes(mvs.count, degree, len(mvs.extras)) + sizes.SIDECAR_BYTES + sizes.LOG_BYTES

    def run(self, ctx: StageContext) -> dict[str, Any]:
        import numpy as np

        from core.io.gaussian_ply import write_gaussian_ply
        from hybridsplat import project_io

        layout = ctx.layout
        cameras, images = project_io.read_training_photos(layout, set(ctx.source.holdout_names))
        mvs, needs, context = survey_layer_inputs(layout, cameras.origin)
        survey = np.flatnonzero(~needs)
        if len(survey) == 0:
            write_gaussian_ply(layout.survey_splats, mvs)
            return {"gaussians": 0, "reason": "every MVS point needs splats: the survey layer is empty"}
        from fusion.appearance import refine_survey_appearance  # torch: after the inputs are read

        def progress(info: Any) -> None:
            ctx.progress(f"loss {info.loss:.4f}, PSNR {info.holdout_psnr:.2f} dB (held-back pixels)", info.step,
                         info.iterations)  # fmt: skip

        opts: AppearanceOptions = ctx.options(self)
        result = refine_survey_appearance(cameras, images, mvs.subset(survey), context, opts, ctx.config.seed,
                                          progress)  # fmt: skip
        out = mvs.with_sh_degree(result.gaussians.sh_degree)
        refined = result.gaussians
        out.log_scales[survey], out.quats[survey] = refined.log_scales, refined.quats
        out.logit_opacities[survey], out.sh_dc[survey] = refined.logit_opacities, refined.sh_dc
        out.sh_rest[survey] = refined.sh_rest
        write_gaussian_ply(layout.survey_splats, out)
        return {**result.counts, "unrefined_needs_splats": int(needs.sum())}

    def summary(self, counts: dict[str, Any]) -> str:
        if not counts.get("gaussians"):
            return f"survey layer not refined: {counts.get('reason', 'nothing to refine')}"
        first, last = counts.get("holdout_psnr_db_first"), counts.get("holdout_psnr_db")
        psnr = f", held-back PSNR {first:.2f} -> {last:.2f} dB" if first is not None and last is not None else ""
        return (
            f"{counts['gaussians']} survey Gaussians refined (positions frozen), {counts['iterations']} steps, "
            f"SH {counts['sh_degree']}{psnr}"
        )


def survey_layer_inputs(
    layout: ProjectLayout, origin: np.ndarray
) -> tuple[GaussianSet, np.ndarray, GaussianSet | None]:
    """What the stage refines and beside what: the converted MVS Gaussians (export/mvs_gaussians.ply), which of them
    need splats ((N,) bool; none without classified points) and the frozen context (the fill and background layers
    that exist and are not empty, at ``origin``; None without any)."""
    import numpy as np

    from core.gaussians import GaussianSet
    from core.io.gaussian_ply import read_gaussian_ply
    from hybridsplat import project_io

    mvs = read_gaussian_ply(layout.mvs_gaussians)
    needs = (project_io.needs_splats_per_gaussian(layout, mvs) if layout.classified_points.is_file()
             else np.zeros(len(mvs), bool))  # fmt: skip
    layers = [read_gaussian_ply(p) for p in (layout.cleaned_splats, layout.background_splats) if p.is_file()]
    layers = [g for g in layers if len(g)]
    context = GaussianSet.concatenate([g.with_origin(origin) for g in layers]) if layers else None
    return mvs, needs, context
