"""Stage ``appearance``: the survey layer's appearance refined for the viewer product (splats/survey.ply).

The MVS Gaussians of the survey layer (export/mvs_gaussians.ply less the points that need splats) get their colour
(SH), opacity, scales and rotations fitted to every pixel of the training photos, the fill (splats/cleaned.ply) and
background (splats/background.ply) layers frozen beside them, positions frozen bit for bit
(:mod:`fusion.appearance`). splats/survey.ply holds one Gaussian per converted MVS Gaussian, in the same order (the
points that need splats unrefined); ``merge`` builds the viewer product from it, while the survey products keep
the converted attributes. With ``refine_context`` (the default) the fill and background layers are refined in the
same fit, positions frozen too: splats/fill_refined.ply and splats/background_refined.ply, row for row with
splats/cleaned.ply and splats/background.ply, for the viewer product only (the survey points and the mesh read the
layers as trained). On a tiled project the fit runs tile by tile (:mod:`hybridsplat.tile_appearance`; the background
layer is then kept as trained).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fusion.appearance import AppearanceOptions, assign_attributes
from hybridsplat.records import TypedRecord
from hybridsplat.stages import sizes
from hybridsplat.stages.base import Stage, StageContext, StageResult, omitted_if_none

if TYPE_CHECKING:
    import numpy as np

    from core.gaussians import GaussianSet
    from hybridsplat.layout import ProjectLayout


@dataclass(frozen=True)
class TileAppearanceRecord(TypedRecord):
    """One tile's fit (:func:`hybridsplat.tile_appearance.run_tile_appearance`): its peak memory (MB), its survey and
    fill Gaussians and training photos, the share of their pixels it fitted (0..1), its steps, its PSNR on
    held-back pixels (dB; None without an evaluation), its seconds, whether its files were up to date
    (``cached``: not fitted again) and, as a Ray task, the resources Ray gave it."""

    tile: str = ""
    peak_mb: float = 0.0
    survey_gaussians: int = 0
    fill_gaussians: int = 0
    photos: int = 0
    covered_share: float = 0.0
    iterations: int = 0
    holdout_psnr_db: float | None = None
    seconds: float = 0.0
    cached: bool = False
    resources: dict[str, float] | None = omitted_if_none()


@dataclass(frozen=True)
class AppearanceResult(StageResult):
    """What the appearance stage made: ``gaussians`` survey Gaussians refined in ``iterations`` steps (tiled: the
    most a tile took) at SH degree ``sh_degree``, ``context_refined`` fill and background Gaussians refined beside
    them, and the ``unrefined_needs_splats`` MVS Gaussians left as converted (the points that need splats).

    Untiled (the counts of :func:`fusion.appearance.refine_survey_appearance`): the step budget, the photo
    downscale and training resolution (W, H px), the Gaussians at the σ bound and at the least opacity, the PSNR on
    held-back pixels at the first and last evaluation (dB), the context Gaussians and the training's seconds.
    Tiled (:mod:`hybridsplat.tile_appearance`): ``background_refined`` (False: the background stays as trained),
    the survey and fill Gaussians no tile refined, the ``tiles`` fitted, each tile's record and the peak memory
    with the Ray workers (MB). ``reason``: why nothing was refined, when nothing was."""

    gaussians: int = 0
    iterations: int = 0
    step_budget: int | None = omitted_if_none()
    downscale: int | None = omitted_if_none()
    resolution: tuple[int, ...] | None = omitted_if_none()
    sh_degree: int = 0
    at_scale_bound: int | None = omitted_if_none()
    at_least_opacity: int | None = omitted_if_none()
    holdout_psnr_db_first: float | None = omitted_if_none()
    holdout_psnr_db: float | None = omitted_if_none()
    context_gaussians: int | None = omitted_if_none()
    context_refined: int = 0
    seconds_training: float | None = omitted_if_none()
    background_refined: bool | None = omitted_if_none()
    unrefined_needs_splats: int = 0
    survey_unrefined: int | None = omitted_if_none()
    fill_unrefined: int | None = omitted_if_none()
    tiles: int | None = omitted_if_none()
    per_tile: tuple[TileAppearanceRecord, ...] | None = omitted_if_none()
    peak_mb_with_workers: float | None = omitted_if_none()
    reason: str | None = omitted_if_none()


class AppearanceStage(Stage):
    name = "appearance"
    Options = AppearanceOptions
    Result = AppearanceResult
    title = "survey-layer appearance"
    uses_seed = True

    def inputs(self, ctx: StageContext) -> list[Path]:
        from hybridsplat.stages.tiles import tiling_on

        layout, ws = ctx.layout, ctx.layout.dense_workspace
        optional = [*layer_files(ctx), layout.classified_points]
        plan = [layout.tile_plan] if tiling_on(ctx) else []  # tiled: refined tile by tile, as the plan cuts it
        return [layout.mvs_gaussians, *(p for p in optional if p.is_file()), ws.sparse, ws.images, *plan]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.survey_splats, *(refined for _, refined in self._refined_layers(ctx))]

    def _refined_layers(self, ctx: StageContext) -> list[tuple[Path, Path]]:
        """(layer as trained, its refined copy) for the fill and background layers that exist, with
        ``refine_context``; none without."""
        if not ctx.options(self).refine_context:
            return []
        refined = ctx.layout.refined_layers()
        return [(base, refined[base]) for base in layer_files(ctx)]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout_names)}

    def needs(self, ctx: StageContext) -> str | None:
        opts: AppearanceOptions = ctx.options(self)
        return None if opts.enabled else "off ([appearance] enabled = false): the survey layer keeps its converted look"

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of splats/survey.ply: the converted MVS Gaussians (export/mvs_gaussians.ply's count and fields) at
        the training SH degree, an origin sidecar and the log (64 KiB); with tiles, also each tile's inputs and
        refined copies of the survey and fill Gaussians in its bounds (counted as the whole layers three times:
        two files each, overlaps held twice)."""
        from hybridsplat.stages.tiles import tiling_on

        opts: AppearanceOptions = ctx.options(self)
        total = sizes.SIDECAR_BYTES + sizes.LOG_BYTES
        tiled = tiling_on(ctx)
        for path in [ctx.layout.mvs_gaussians, *(base for base, _ in self._refined_layers(ctx))]:
            layer = sizes.ply_vertices(path)
            degree = max(layer.sh_degree, opts.training.sh_degree)
            one = sizes.gaussian_ply_bytes(layer.count, degree, len(layer.extras)) + sizes.SIDECAR_BYTES
            total += one * (4 if tiled and path != ctx.layout.background_splats else 1)
        return total

    def run(self, ctx: StageContext) -> AppearanceResult:
        import numpy as np

        from core.io.gaussian_ply import write_gaussian_ply
        from hybridsplat import project_io
        from hybridsplat.stages.tiles import tiling_on

        layout = ctx.layout
        mvs, needs, layers = survey_layer_inputs(layout, layer_files(ctx))
        survey = np.flatnonzero(~needs)
        if len(survey) == 0:
            write_gaussian_ply(layout.survey_splats, mvs)
            for base, refined in self._refined_layers(ctx):
                write_gaussian_ply(refined, layers[base])
            return AppearanceResult(reason="every MVS point needs splats: the survey layer is empty")
        if tiling_on(ctx):  # each tile reads its own photos
            return self._run_tiled(ctx, mvs, survey, layers)
        cameras, images = project_io.read_training_photos(layout, set(ctx.source.holdout_names))
        from fusion.appearance import refine_survey_appearance  # torch: after the inputs are read

        def progress(info: Any) -> None:
            ctx.progress(f"loss {info.loss:.4f}, PSNR {info.holdout_psnr:.2f} dB (held-back pixels)", info.step,
                         info.iterations)  # fmt: skip

        opts: AppearanceOptions = ctx.options(self)
        context = context_of(layers, cameras.origin)
        result = refine_survey_appearance(cameras, images, mvs.subset(survey), context, opts, ctx.config.seed,
                                          progress)  # fmt: skip
        out = mvs.with_sh_degree(result.gaussians.sh_degree)
        assign_attributes(out, survey, result.gaussians)
        write_gaussian_ply(layout.survey_splats, out)
        _write_refined_layers(self._refined_layers(ctx), layers, result.context)
        return AppearanceResult(**result.counts, unrefined_needs_splats=int(needs.sum()))

    def _run_tiled(
        self, ctx: StageContext, mvs: GaussianSet, survey: np.ndarray, layers: dict[Path, GaussianSet]
    ) -> AppearanceResult:
        """The tiled project's fit (:mod:`hybridsplat.tile_appearance`): the survey rows and the fill refined tile by
        tile, the background layer kept as trained (its refined copy is the layer itself)."""
        from core.io.gaussian_ply import write_gaussian_ply
        from hybridsplat.tile_appearance import run_tiled_appearance

        layout, opts = ctx.layout, ctx.options(self)
        fill = layers.get(layout.cleaned_splats)
        background = layers.get(layout.background_splats)
        with_background = background is not None and len(background) > 0
        stitched = run_tiled_appearance(ctx, mvs.subset(survey), fill, with_background, opts)
        out = mvs.with_sh_degree(stitched.survey.sh_degree)
        assign_attributes(out, survey, stitched.survey)
        write_gaussian_ply(layout.survey_splats, out)
        for base, refined in self._refined_layers(ctx):
            write_gaussian_ply(refined, stitched.fill if base == layout.cleaned_splats else layers[base])
        return AppearanceResult(
            gaussians=len(survey),
            iterations=stitched.iterations,
            sh_degree=stitched.survey.sh_degree,
            context_refined=len(fill) if fill is not None and self._refined_layers(ctx) else 0,
            background_refined=False,
            unrefined_needs_splats=int(len(mvs) - len(survey)),
            survey_unrefined=stitched.survey_unrefined,
            fill_unrefined=stitched.fill_unrefined,
            tiles=len(stitched.per_tile),
            per_tile=stitched.per_tile,
            peak_mb_with_workers=stitched.peak_mb_with_workers,
        )

    def summary(self, result: AppearanceResult) -> str:
        if not result.gaussians:
            return f"survey layer not refined: {result.reason or 'nothing to refine'}"
        first, last = result.holdout_psnr_db_first, result.holdout_psnr_db
        psnr = f", held-back PSNR {first:.2f} -> {last:.2f} dB" if first is not None and last is not None else ""
        context = result.context_refined
        beside = f" with {context} fill and background Gaussians" if context else ""
        if result.tiles:
            beside = f" with {context} fill Gaussians" if context else ""
            where = f" in {result.tiles} tiles (background as trained), up to {result.iterations} steps a tile"
            return f"{result.gaussians} survey Gaussians refined{beside}{where}, SH {result.sh_degree}"
        return (
            f"{result.gaussians} survey Gaussians refined{beside} (positions frozen), {result.iterations} "
            f"steps, SH {result.sh_degree}{psnr}"
        )


def layer_files(ctx: StageContext) -> list[Path]:
    """The layers the survey layer is refined beside: splats/cleaned.ply when it exists and splats/background.ply
    when it exists and the background stage is on (a stage turned off leaves its file behind, unread)."""
    from fusion.background import BackgroundOptions

    layout = ctx.layout
    background = ctx.config.options("background", BackgroundOptions).enabled and layout.background_splats.is_file()
    return [layout.cleaned_splats] * layout.cleaned_splats.is_file() + [layout.background_splats] * background


def survey_layer_inputs(
    layout: ProjectLayout, layers: list[Path]
) -> tuple[GaussianSet, np.ndarray, dict[Path, GaussianSet]]:
    """What the stage refines and beside what: the converted MVS Gaussians (export/mvs_gaussians.ply), which of them
    need splats ((N,) bool; none without classified points) and the ``layers`` (file → set as read, in order)."""
    import numpy as np

    from core.io.gaussian_ply import read_gaussian_ply
    from hybridsplat import project_io

    mvs = read_gaussian_ply(layout.mvs_gaussians)
    needs = (project_io.needs_splats_per_gaussian(layout, mvs) if layout.classified_points.is_file()
             else np.zeros(len(mvs), bool))  # fmt: skip
    return mvs, needs, {p: read_gaussian_ply(p) for p in layers}


def context_of(layers: dict[Path, GaussianSet], origin: np.ndarray) -> GaussianSet | None:
    """The non-empty ``layers`` concatenated in order at ``origin`` (the context the survey layer is refined
    beside); None without any."""
    from core.gaussians import GaussianSet

    visible = [g for g in layers.values() if len(g)]
    return GaussianSet.concatenate([g.with_origin(origin) for g in visible]) if visible else None


def _write_refined_layers(
    pairs: list[tuple[Path, Path]], layers: dict[Path, GaussianSet], refined: GaussianSet | None
) -> None:
    """Writes each refined copy of ``pairs`` (layer file → its refined file): the layer's rows of ``refined`` (the
    non-empty ``layers`` concatenated in order, as refined beside the survey layer) on the layer's own positions,
    origin and fields; an empty layer as it is."""
    import numpy as np

    from core.io.gaussian_ply import write_gaussian_ply
    from fusion.appearance import with_attributes

    start = 0
    for base, path in pairs:
        layer = layers[base]
        if len(layer) and refined is not None:
            rows = refined.subset(np.arange(start, start + len(layer)))
            layer, start = with_attributes(layer, rows), start + len(layer)
        write_gaussian_ply(path, layer)
