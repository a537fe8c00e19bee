"""Appearance refinement of the survey layer: the MVS Gaussians fitted to the photos with their positions frozen.

The adaptive conversion (:mod:`fusion.convert`) gives each MVS point a fixed surfel: DC colour from the point, σ from
the local spacing, opacity from its number of views. This refinement fits, on the whole of every training photo,
their colour (spherical harmonics up to ``training.sh_degree``), opacity, scales and rotations, with the fill and
background layers frozen beside them, so that the survey layer looks as good in a viewer as plain 3DGS while it
stays the MVS geometry:

- positions never change: the trainer's means learning rate is 0 and the result carries the input's float64 means
  (bit for bit, not their float32 training-frame copies);
- no Gaussian is added, removed or moved (the strategy never refines), so row *i* of the result is MVS point *i*;
- every σ stays at most ``max_scale_spacings`` × the point's local spacing (the median distance to its
  ``spacing_neighbours`` nearest MVS points, as the conversion measures it) or its converted σ if larger (a
  projection after every step), so a survey Gaussian still stands for its point and never grows over a hole;
- no survey Gaussian is made invisible: α is kept at least :data:`MIN_OPACITY` (above the 1/255 under which the
  exporters drop a Gaussian), so the viewer product keeps one Gaussian per survey point.

With ``refine_context`` the fill and background layers are refined in the same fit: positions frozen as well (row
*i* of a refined layer is row *i* of the layer as trained), σ unbounded, and α never below the lesser of
:data:`MIN_OPACITY` and its α as trained, so the refinement drops no fill splat the survey points and the mesh read.

The survey products (points, LAS, C2C, the mesh, measurement) keep the converted attributes: only the viewer product
(``export/merged.ply``) takes the refined ones. ``.splat`` files hold DC colour only: they get the refined DC colour,
opacity, scales and rotations, not the higher SH bands.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from core.cameras import Cameras
from core.constraints import Constrained, Constraints, Interval
from core.errors import ConfigError
from core.gaussians import GaussianSet
from fusion.train.options import TrainOptions
from fusion.train.strategy import DefaultStrategy

#: the least α of a refined survey Gaussian (twice the exporters' threshold of 1/255)
MIN_OPACITY = 2.0 / 255.0


def _appearance_training() -> TrainOptions:
    return TrainOptions(
        iterations=2000,
        sh_degree=3,
        sh_degree_interval=100,
        lr_means=0.0,
        min_iterations=400,
        patience=2,
        strategy=DefaultStrategy(refine_start=0, refine_stop=0, reset_every=0),
    )


@dataclass(frozen=True)
class AppearanceOptions(Constrained):
    """Options of :func:`refine_survey_appearance` (the ``appearance`` stage's options).

    enabled: refine the survey layer's appearance for the viewer product. refine_context: refine the fill and
    background layers beside it in the same fit (colour, opacity, scales and rotations; their positions frozen too,
    their σ unbounded), instead of keeping them frozen as trained. max_image_size: longer side of the
    training photos (px; 0 = full size). max_scale_spacings: the largest σ of a survey Gaussian, in multiples of
    its point's local spacing (never below its converted σ). spacing_neighbours: neighbours of that spacing.
    max_passes: the step budget in passes over the training photos: at most ``max_passes`` × photos steps, never
    more than ``training.iterations`` (0: no cap). training: the trainer's options (positions frozen: ``lr_means``
    must be 0; the strategy must not refine; its cap is raised to the survey layer's count).

    How the defaults were set (never on a scored view): the fill's resolution (640 px); a bound of one spacing
    (2.5 × the conversion's σ of 0.4 spacings: neighbouring surfels overlap, none covers a hole; set before any
    measurement); the conversion's 8 neighbours; SH degree 3 and the step budget by the PSNR on the trainer's
    held-back training pixels (demo scene, docs/experiments/2026-11-27-survey-appearance.md): degree 3 above degree 1,
    still rising at 1000 steps, so up to 2000 steps ended by the trainer's early stop on those pixels. That stop
    waits 2 windows without a gain of 0.05 dB (the trainer waits 3), chosen on the held-back pixels and on held-back
    training views of the demo and the fountain (docs/experiments/2026-11-28-appearance-budget.md). ``refine_context``
    on by the held-out views of four tuning layouts (random-object 0, random-aerial 0–2; seeds no figure is scored
    on): whole-image PSNR and LPIPS better on all four (docs/experiments/2026-11-28-joint-refinement.md).
    ``max_passes`` (84) is that 2 000-step budget per photo of the demo it was chosen on (24 photos: 83 passes), so a
    scene with fewer photos does not fit each photo more often (checked on a held-back training photo of the
    fountain: docs/experiments/2026-11-29-time-to-quality.md).
    """

    enabled: bool = True
    refine_context: bool = True
    max_image_size: int = 640
    max_scale_spacings: float = 1.0
    spacing_neighbours: int = 8
    max_passes: float = 84.0
    training: TrainOptions = field(default_factory=_appearance_training)

    constraints: ClassVar[Constraints] = {
        "max_image_size": Interval(int, 0, None),
        "max_scale_spacings": Interval(float, 0, math.inf, closed="right"),
        "spacing_neighbours": Interval(int, 1, 64),
        "max_passes": Interval(float, 0, math.inf),
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.training.lr_means != 0.0:
            lr = self.training.lr_means
            raise ConfigError(f"the survey layer's positions are frozen: training.lr_means must be 0, got {lr}")
        strategy = self.training.strategy
        if not isinstance(strategy, DefaultStrategy) or strategy.refine_start < strategy.refine_stop:
            raise ConfigError(
                "the survey layer keeps one Gaussian per MVS point: training.strategy must be a "
                "DefaultStrategy that never refines (refine_stop <= refine_start)"
            )


def step_budget(options: AppearanceOptions, photos: int) -> int:
    """The fit's steps for ``photos`` training photos: ``training.iterations``, at most ``max_passes`` passes over
    the photos (at least one step)."""
    if options.max_passes == 0:
        return options.training.iterations
    return max(1, min(options.training.iterations, math.ceil(options.max_passes * photos)))


def scale_bounds(means: np.ndarray, log_scales: np.ndarray, multiple: float, neighbours: int) -> np.ndarray:
    """(N,) the largest σ (metres) each Gaussian may reach: ``multiple`` × its point's local spacing (median
    distance to the ``neighbours`` nearest other points, duplicates ignored, as :mod:`fusion.convert` measures it)
    and never below its current largest σ. A point without a distinct neighbour keeps its current σ as bound."""
    from core.knn.search import knn_grid_summary

    current = np.exp(np.asarray(log_scales, np.float64).max(axis=1)) if len(means) else np.zeros(0)
    if len(means) < 2:
        return current
    _, spacing = knn_grid_summary(np.asarray(means, np.float64), min(neighbours, len(means) - 1))
    return np.maximum(multiple * spacing, current)


@dataclass
class AppearanceResult:
    """The survey Gaussians with refined appearance (same rows, origin and float64 means as the input; SH at the
    training degree), the context refined beside them (``refine_context``; same rows, origin, float64 means and
    fields as the input context; None when it stayed frozen or there was none), the trainer's result and counts."""

    gaussians: GaussianSet
    training: Any
    counts: dict[str, Any]
    context: GaussianSet | None = None


def refine_survey_appearance(
    cameras: Cameras,
    images: Mapping[str, np.ndarray],
    survey: GaussianSet,
    context: GaussianSet | None,
    options: AppearanceOptions,
    seed: int,
    progress: Callable[[Any], None] | None = None,
    *,
    masks: Mapping[str, np.ndarray] | None = None,
    fixed: GaussianSet | None = None,
) -> AppearanceResult:
    """Fit the appearance of ``survey`` (the MVS Gaussians of the survey layer, any origin) to ``images`` (name →
    (H, W, 3) photo at its camera's size; the training photos only) beside ``context`` (the fill and background
    layers), on every pixel: the context frozen, or with ``options.refine_context`` refined in the same fit (its
    positions frozen as well, its σ unbounded, its α free). Positions are returned bit for bit.

    masks: name → (H, W) bool, the pixels fitted (None: every pixel; a tile's fit, :mod:`hybridsplat.tile_appearance`,
    fits the pixels its own Gaussians cover). fixed: Gaussians rendered beside the others and kept frozen whatever
    ``refine_context`` says (a tile's view of the background layer)."""
    from fusion.train.masked import training_downscale
    from fusion.train.trainer import train_splats

    if len(survey) == 0:
        raise ConfigError("no survey Gaussians: nothing to refine")
    joint = options.refine_context and context is not None and len(context) > 0
    bounds = scale_bounds(survey.means, survey.log_scales, options.max_scale_spacings, options.spacing_neighbours)
    init, frozen = survey, context
    if joint:
        assert context is not None
        init, frozen = GaussianSet.concatenate([survey, context]), None
        bounds = np.r_[bounds, np.full(len(context), np.inf)]
    if fixed is not None and len(fixed):
        fixed = fixed.with_origin(survey.origin)
        frozen = fixed if frozen is None else GaussianSet.concatenate([frozen.with_origin(survey.origin), fixed])
    downscale = training_downscale(cameras, options.training.downscale, options.max_image_size)
    strategy = replace(options.training.strategy, cap=max(options.training.strategy.cap, len(init)))
    steps = step_budget(options, sum(1 for view in cameras if view.name in images))
    train_opts = replace(options.training, iterations=steps, downscale=downscale, seed=seed, strategy=strategy)
    result = train_splats(cameras, images, masks, init, frozen, train_opts, progress, max_scales=bounds)
    trained = result.splats.with_origin(survey.origin)
    n = len(survey)
    least = np.float32(np.log(MIN_OPACITY / (1.0 - MIN_OPACITY)))
    opacities = np.maximum(trained.logit_opacities[:n], least)
    refined = GaussianSet(survey.means.copy(), trained.log_scales[:n], trained.quats[:n], opacities,
                          trained.sh_dc[:n], trained.sh_rest[:n], survey.origin.copy(),
                          fields=dict(survey.fields))  # fmt: skip
    refined_context = None
    if joint:
        assert context is not None  # no Gaussian is made invisible that was not: the survey points know it
        refined_context = with_attributes(context, trained.subset(np.arange(n, len(trained))))
        floor = np.minimum(context.logit_opacities.astype(np.float32), least)
        refined_context.logit_opacities = np.maximum(refined_context.logit_opacities, floor)
    at_bound = np.exp(refined.log_scales.astype(np.float64).max(axis=1)) >= bounds[:n] * (1 - 1e-5)
    history = result.history
    counts = {
        "gaussians": len(refined),
        "iterations": result.iterations,
        "step_budget": steps,
        "downscale": downscale,
        "resolution": list(result.resolution),
        "sh_degree": train_opts.sh_degree,
        "at_scale_bound": int(at_bound.sum()),
        "at_least_opacity": int((trained.logit_opacities[:n] < least).sum()),
        "holdout_psnr_db_first": history[0].holdout_psnr if history else None,
        "holdout_psnr_db": history[-1].holdout_psnr if history else None,
        "context_gaussians": len(context) if context is not None else 0,
        "context_refined": len(refined_context) if refined_context is not None else 0,
        "seconds_training": result.seconds,
    }
    return AppearanceResult(refined, result, counts, refined_context)


def assign_attributes(out: GaussianSet, rows: np.ndarray, refined: GaussianSet) -> None:
    """``out``'s ``rows`` (in place) take ``refined``'s scales, rotations, opacities and SH (the same SH degree);
    positions, origin and fields untouched."""
    out.log_scales[rows], out.quats[rows] = refined.log_scales, refined.quats
    out.logit_opacities[rows], out.sh_dc[rows] = refined.logit_opacities, refined.sh_dc
    out.sh_rest[rows] = refined.sh_rest


def with_attributes(base: GaussianSet, trained: GaussianSet) -> GaussianSet:
    """``base`` (positions, origin and fields kept bit for bit) with the scales, rotations, opacities and SH of
    ``trained`` (the same rows, any origin)."""
    return GaussianSet(base.means.copy(), trained.log_scales, trained.quats, trained.logit_opacities, trained.sh_dc,
                       trained.sh_rest, base.origin.copy(), fields=dict(base.fields))  # fmt: skip


def with_converted_survey(
    merged: GaussianSet,
    converted: GaussianSet,
    source_path: Any = None,
    *,
    fill: GaussianSet | None = None,
    background: GaussianSet | None = None,
) -> GaussianSet:
    """``merged`` (a set with a ``source`` field, e.g. export/merged.ply) with its survey rows (``Source.MVS``) given
    back the attributes of the converted MVS Gaussian at the same position (``converted``: export/mvs_gaussians.ply),
    and, when given, its fill rows (``Source.SPLAT``) those of ``fill`` (splats/cleaned.ply) and its background rows
    (``Source.BACKGROUND``) those of ``background`` (splats/background.ply): the layers as before the appearance
    stage, in ``converted``'s origin. The refinement never moves a Gaussian, so positions identify the rows (each
    reference is brought to that origin as the merge brings it); where several Gaussians share one position (a
    clone that moved with its parent), the k-th such row of ``merged`` takes the k-th of the reference, in file
    order (the merge keeps each layer's order). What the survey products (the mesh, the controls that measure MVS)
    read instead of the refined appearance. Raises :class:`DataError` (naming ``source_path``) when a row matches no
    Gaussian of its reference."""
    from core.errors import DataError
    from fusion.convert_options import Source

    if "source" not in merged.fields:
        raise DataError("the merged Gaussians have no 'source' field: the survey layer cannot be told apart",
                        source_path)  # fmt: skip
    if not np.array_equal(merged.origin, converted.origin):
        # A file re-based on reading (a far background beyond the readers' local range): the same points, exactly,
        # when both origins are whole metres (what choose_origin gives); any other difference fails by position.
        merged = merged.with_origin(converted.origin)
    out = merged.subset(np.arange(len(merged)))
    references = {Source.MVS: ("converted MVS Gaussian", converted), Source.SPLAT: ("fill splat", fill),
                  Source.BACKGROUND: ("background Gaussian", background)}  # fmt: skip
    for source, (what, reference) in references.items():
        rows = np.flatnonzero(np.asarray(merged.fields["source"]) == source)
        if reference is None or len(rows) == 0:
            continue
        _restore_rows(out, rows, reference.with_origin(merged.origin), what, source_path)
    return out


def _restore_rows(out: GaussianSet, rows: np.ndarray, reference: GaussianSet, what: str, source_path: Any) -> None:
    """Gives ``out``'s ``rows`` (in place) the attributes of the ``reference`` Gaussian at the same position."""
    from core.errors import DataError

    keys = _position_keys(reference.means)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    wanted = _position_keys(out.means[rows])
    first = np.searchsorted(sorted_keys, wanted, side="left")
    count = np.searchsorted(sorted_keys, wanted, side="right") - first
    found = count > 0
    if not found.all():
        raise DataError(f"{int((~found).sum())} Gaussians of the merged product lie where no {what} does: the "
                        f"layer changed since the merge", source_path)  # fmt: skip
    at = first + np.minimum(_rank_among_equal(wanted), count - 1)
    index = order[at]
    source = reference.with_sh_degree(out.sh_degree)
    out.log_scales[rows] = source.log_scales[index]
    out.quats[rows] = source.quats[index]
    out.logit_opacities[rows] = source.logit_opacities[index]
    out.sh_dc[rows] = source.sh_dc[index]
    out.sh_rest[rows] = source.sh_rest[index]  # type: ignore[index]


def _rank_among_equal(keys: np.ndarray) -> np.ndarray:
    """(N,) int64: how many earlier entries of ``keys`` (N,) equal each one (0 for the first of its value)."""
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    rank = np.empty(len(keys), dtype=np.int64)
    rank[order] = np.arange(len(keys)) - np.searchsorted(sorted_keys, sorted_keys, side="left")
    return rank


def _position_keys(means: np.ndarray) -> np.ndarray:
    """One sortable key per row of (N, 3) float64 positions: their exact bytes."""
    return np.ascontiguousarray(means, dtype=np.float64).view(np.dtype((np.void, 24))).reshape(-1)
