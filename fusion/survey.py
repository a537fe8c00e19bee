"""The hybrid's products from MVS Gaussians and cleaned splats: the viewer set (every Gaussian, a ``source`` and a
``surface`` field each) and the survey point product (only Gaussians whose geometry is trustworthy).

The point product keeps the trusted MVS points, and only those splats and ``needs_splats`` MVS points that pass
:func:`fusion.clean.select_survey_points` (splats opaque, thin along the normal and not large; both seen inside the
region mask from several training views, not seen outside it unoccluded, and near the silhouette rim of some view,
which rejects the virtual images of reflections and refractions that MVS and splats place inside mirrors and
glass), plus the ``needs_splats`` MVS points of the classes that leave MVS incomplete rather than wrong
(:attr:`MergeOptions.needs_mvs_classes`). ``surface`` is 1 for the MVS Gaussians and for the splats whose centres
pass :func:`fusion.clean.surface_splat_options`; the mesh builds its geometry from ``surface = 1`` only.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from core.cameras import Cameras
from core.gaussians import GaussianSet
from fusion.merge_options import MergeOptions


@dataclass
class ViewTests:
    """What the view tests of :func:`fusion.clean.select_survey_points` need: the cameras, the masks (name → (H, W)
    bool), the trusted MVS points (M, 3) in the cameras' local frame and their median spacing (metres)."""

    cameras: Cameras
    masks: Mapping[str, np.ndarray]
    trusted: np.ndarray
    spacing: float


@dataclass
class HybridProducts:
    """The viewer set (``gaussians``, with ``source`` and ``surface`` fields), the survey points (a Gaussian set
    whose centres are the points) and what was kept and why (counts for the stage record)."""

    gaussians: GaussianSet
    points: GaussianSet
    stats: Any
    counts: dict[str, Any]


def view_tests(
    cameras: Cameras, masks: Mapping[str, np.ndarray], mvs: GaussianSet, needs: np.ndarray, splats: GaussianSet
) -> ViewTests:
    """The inputs of the view tests: trusted points are the MVS Gaussians that need no splats; their spacing, else
    (no trusted surface) the splats' own, else 1 m."""
    from fusion.clean import median_nn_spacing

    trusted = mvs.subset(~needs).with_origin(cameras.origin).means if (~needs).any() else np.zeros((0, 3))
    spacing = median_nn_spacing(trusted)
    if not spacing > 0:
        spacing = median_nn_spacing(splats.means)
    return ViewTests(cameras, masks, trusted, spacing if spacing > 0 else 1.0)


def surface_field(merged: GaussianSet, views: ViewTests, test: bool) -> tuple[np.ndarray, Any]:
    """(N,) uint8 ``surface`` per merged Gaussian (1 for MVS Gaussians; for splats the verdict of
    :func:`fusion.clean.surface_splat_options`, or 1 when ``test`` is off) and the splats' selection (None: off)."""
    from fusion.clean import select_survey_points, surface_splat_options
    from fusion.convert import Source
    from fusion.merge import subset

    out = np.ones(len(merged), np.uint8)
    if not test:
        return out, None
    is_splat = np.asarray(merged.fields["source"]) == Source.SPLAT
    sel = select_survey_points(subset(merged, is_splat), views.cameras, views.masks, views.trusted, views.spacing,
                               surface_splat_options())  # fmt: skip
    out[is_splat] = sel.keep
    return out, sel


def survey_selections(
    views: ViewTests, mvs: GaussianSet, needs: np.ndarray, splats: GaussianSet, opts: MergeOptions
) -> tuple[Any, Any]:
    """Which cleaned splats and which ``needs_splats`` MVS points go into the point product (selections of
    :func:`fusion.clean.select_survey_points`; the second is None when ``needs_mvs`` is off)."""
    from fusion.clean import select_survey_points

    cameras, masks, trusted, spacing = views.cameras, views.masks, views.trusted, views.spacing
    sel_splats = select_survey_points(splats, cameras, masks, trusted, spacing, opts.points)
    sel_mvs = None
    if opts.needs_mvs and not opts.keep_needs_splats and needs.any():
        rule = replace(opts.points, shape_checks=False, max_rim_spacing=opts.needs_mvs_max_rim_spacing)
        sel_mvs = select_survey_points(mvs.subset(needs), cameras, masks, trusted, spacing, rule)
    return sel_splats, sel_mvs


def kept_classes(
    needs: np.ndarray, predicted: np.ndarray | None, codes: Mapping[str, int], opts: MergeOptions
) -> dict[str, np.ndarray]:
    """Per class name of ``needs_mvs_classes`` present in ``codes`` (the project's needs-splats classes): (N,) bool,
    its ``needs_splats`` MVS points (``predicted``: class code per MVS Gaussian). Empty when ``keep_needs_splats``
    keeps them all anyway."""
    if opts.keep_needs_splats or not opts.needs_mvs_classes or not needs.any() or predicted is None:
        return {}
    wanted = [n for n in opts.needs_mvs_classes if n in codes]
    return {name: needs & (predicted == codes[name]) for name in wanted}


def hybrid_products(
    mvs: GaussianSet,
    splats: GaussianSet,
    needs: np.ndarray,
    views: ViewTests,
    opts: MergeOptions,
    predicted: np.ndarray | None = None,
    class_codes: Mapping[str, int] | None = None,
) -> HybridProducts:
    """The hybrid's viewer set and survey points from the MVS Gaussians, the cleaned splats and ``needs`` (N,) bool
    per MVS Gaussian; ``predicted`` / ``class_codes`` choose the ``needs_mvs_classes`` points (see the module)."""
    from fusion.merge import merge_hybrid, subset

    result = merge_hybrid(mvs, splats, needs, keep_needs_splats=opts.keep_needs_splats)
    surface, sel_surface = surface_field(result.gaussians, views, opts.surface_test)
    result.gaussians.fields["surface"] = surface
    sel_splats, sel_mvs = survey_selections(views, mvs, needs, splats, opts)
    needs_left_out = needs.copy()
    if sel_mvs is not None:
        needs_left_out[np.flatnonzero(needs)[sel_mvs.keep]] = False
    by_class = kept_classes(needs, predicted, class_codes or {}, opts)
    for kept in by_class.values():
        needs_left_out[kept] = False
    points = merge_hybrid(mvs, subset(splats, sel_splats.keep), needs_left_out,
                          keep_needs_splats=opts.keep_needs_splats).gaussians  # fmt: skip
    counts: dict[str, Any] = {"point_splats": vars(sel_splats.counts)}
    if sel_surface is not None:
        counts["surface_splats"] = vars(sel_surface.counts)
    if sel_mvs is not None:
        counts["point_needs_mvs"] = vars(sel_mvs.counts)
    counts["point_needs_mvs_classes"] = {name: int(kept.sum()) for name, kept in by_class.items()}
    return HybridProducts(result.gaussians, points, result.stats, counts)
