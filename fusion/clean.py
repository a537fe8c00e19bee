"""Cleaning trained splats: floaters, out-of-region and degenerate splats removed, with counts and reasons.

A splat is removed for the first of these reasons that applies (:class:`Reason` codes, in this order):

1. ``OUTSIDE_MASKS``: its centre projects (in front of the camera, inside the image) into no mask pixel of any
   view — after growing each mask by ``mask_dilation_px`` so that splats on a region's border stay;
2. ``LOW_OPACITY``: α below ``min_opacity``;
3. ``EXTREME_SCALE``: largest σ above ``max_scale_scene`` × scene scale, or above ``max_scale_spacing`` × the
   median nearest-neighbour spacing of the splats' centres;
4. ``ISOLATED``: in a DBSCAN cluster (scikit-learn) of fewer than ``min_cluster_size`` splats, or DBSCAN noise,
   with eps = ``cluster_eps_spacing`` × the median nearest-neighbour spacing.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import IntEnum

import cv2
import numpy as np
from scipy.spatial import cKDTree
from sklearn.cluster import DBSCAN

from core.cameras import Cameras
from core.errors import ConfigError
from core.gaussians import GaussianSet
from fusion.clean_options import CleanOptions, SurveyPointOptions, surface_splat_options  # noqa: F401 (re-exported)
from fusion.mask_projection import project_to_pixels
from fusion.merge import subset
from fusion.train.init import points_in_masks, zbuffer_depth
from fusion.train.trainer import scene_scale


class Reason(IntEnum):
    """Why a splat was removed (0 = kept)."""

    KEPT = 0
    OUTSIDE_MASKS = 1
    LOW_OPACITY = 2
    EXTREME_SCALE = 3
    ISOLATED = 4


@dataclass(frozen=True)
class CleanCounts:
    """How many splats went in, were removed for each reason, and stayed."""

    input: int
    outside_masks: int
    low_opacity: int
    extreme_scale: int
    isolated: int
    kept: int


@dataclass
class CleanResult:
    """The kept splats, the counts, and the per-input-splat :class:`Reason` codes (N,) uint8."""

    splats: GaussianSet
    counts: CleanCounts
    reasons: np.ndarray


def median_nn_spacing(points: np.ndarray) -> float:
    """Median distance (metres) from each of the (N, 3) points to its nearest other point; 0 for fewer than two."""
    if len(points) < 2:
        return 0.0
    d, _ = cKDTree(points).query(points, k=2)
    return float(np.median(d[:, 1]))


def clean_splats(
    splats: GaussianSet,
    cameras: Cameras | None = None,
    masks: Mapping[str, np.ndarray] | None = None,
    options: CleanOptions | None = None,
) -> CleanResult:
    """Remove floaters and degenerate splats (``splats`` in the frame of ``cameras``' origin or any other: they
    are moved to the cameras' origin for the mask test). Without cameras and masks the mask test is skipped; without
    at least two cameras the scene scale is the splats' extent."""
    opts = options or CleanOptions()
    n = len(splats)
    reasons = np.zeros(n, np.uint8)
    if n == 0:
        return CleanResult(splats, CleanCounts(0, 0, 0, 0, 0, 0), reasons)

    def mark(cond: np.ndarray, reason: Reason) -> None:
        reasons[(reasons == 0) & cond] = reason

    local = splats.with_origin(cameras.origin).means if cameras is not None else splats.means
    if cameras is not None and masks is not None:
        kernel = np.ones((2 * opts.mask_dilation_px + 1,) * 2, np.uint8)
        grown = {k: cv2.dilate(np.asarray(m, np.uint8), kernel) > 0 for k, m in masks.items()}
        mark(~points_in_masks(cameras, grown, local), Reason.OUTSIDE_MASKS)
    if opts.min_opacity is not None:
        mark(splats.opacities < opts.min_opacity, Reason.LOW_OPACITY)
    sigma = splats.scales.astype(np.float64).max(axis=1)
    spacing = median_nn_spacing(splats.means)
    if opts.max_scale_scene is not None:
        if cameras is not None and len(cameras) > 1:
            scale = scene_scale(cameras)
        else:  # no camera spread to measure: the splats' own extent
            scale = float(np.ptp(splats.means, axis=0).max())
        mark(sigma > opts.max_scale_scene * scale, Reason.EXTREME_SCALE)
    if opts.max_scale_spacing is not None and spacing > 0:
        mark(sigma > opts.max_scale_spacing * spacing, Reason.EXTREME_SCALE)
    if opts.cluster_eps_spacing is not None and spacing > 0:
        alive = np.flatnonzero(reasons == 0)
        if len(alive):
            labels = DBSCAN(eps=opts.cluster_eps_spacing * spacing, min_samples=1).fit(splats.means[alive]).labels_
            sizes = np.bincount(labels)
            small = sizes[labels] < opts.min_cluster_size
            isolated = np.zeros(n, bool)
            isolated[alive[small]] = True
            mark(isolated, Reason.ISOLATED)
    counts = CleanCounts(
        n,
        int((reasons == Reason.OUTSIDE_MASKS).sum()),
        int((reasons == Reason.LOW_OPACITY).sum()),
        int((reasons == Reason.EXTREME_SCALE).sum()),
        int((reasons == Reason.ISOLATED).sum()),
        int((reasons == 0).sum()),
    )
    return CleanResult(subset(splats, reasons == 0), counts, reasons)


# -- which splats become survey points ----------------------------------------------------------------------------
class PointReason(IntEnum):
    """Why a (cleaned) splat's centre is left out of the point product (0 = kept), first reason that applies."""

    KEPT = 0
    LOW_OPACITY = 1
    THICK = 2
    LARGE = 3
    FEW_VIEWS = 4
    OFF_MASKS = 5
    INTERIOR = 6
    BEHIND = 7


@dataclass(frozen=True)
class SurveyPointCounts:
    """How many splats were considered, left out of the point product for each reason, and kept."""

    input: int
    low_opacity: int
    thick: int
    large: int
    few_views: int
    off_masks: int
    interior: int
    behind: int
    kept: int


@dataclass
class SurveyPointSelection:
    """keep: (N,) bool per splat; reasons: (N,) uint8 :class:`PointReason`; views_inside / views_outside: (N,)
    int32 counts of unoccluded views where the centre lands inside / outside the mask."""

    keep: np.ndarray
    reasons: np.ndarray
    views_inside: np.ndarray
    views_outside: np.ndarray
    counts: SurveyPointCounts


def closed_zbuffer(cameras: Cameras, view, points: np.ndarray, radius: int = 1) -> np.ndarray:
    """(H, W) z-buffer of ``points`` (local frame) in ``view`` with its holes between samples closed: each pixel takes
    the nearest depth within ``radius`` px (grey erosion of the depth, empty pixels as +inf); inf where none."""
    depth = zbuffer_depth(cameras, view, points)
    depth = np.where(depth > 0, depth, np.inf).astype(np.float32)
    if radius > 0:
        depth = cv2.erode(depth, np.ones((2 * radius + 1,) * 2, np.uint8), borderType=cv2.BORDER_REPLICATE)
    return depth


def hole_filled_depth(depth: np.ndarray) -> np.ndarray:
    """(H, W) float32 depth with its empty pixels (not finite or <= 0) filled by linear interpolation between the
    pixels that border them (scipy's Delaunay-based ``LinearNDInterpolator``; exact for a plane), and the nearest
    border pixel's depth outside their convex hull; all inf when no pixel has a depth. What the trusted surface
    would be across an MVS hole if it continued smoothly. (OpenCV's ``inpaint`` takes float32 images but returned
    values off by a metre on a plane 2 m away in our check.)"""
    from scipy.interpolate import LinearNDInterpolator
    from threadpoolctl import threadpool_limits

    depth = np.asarray(depth, dtype=np.float32)
    holes = ~(np.isfinite(depth) & (depth > 0))
    if holes.all():
        return np.full(depth.shape, np.inf, np.float32)
    if not holes.any():
        return depth.copy()
    border = ~holes & cv2.dilate(holes.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    sites = np.argwhere(border).astype(np.float64)
    values = depth[border].astype(np.float64)
    targets = np.argwhere(holes).astype(np.float64)
    filled = np.full(len(targets), np.nan)
    if len(sites) >= 3 and np.linalg.matrix_rank(sites - sites[0]) == 2:
        # one BLAS thread: qhull solves a 2 × 2 system per triangle; OpenBLAS's threads on such calls only spin, and
        # beside a second process they starve each other (bench/bench_hole_fill_contention.py)
        with threadpool_limits(limits=1, user_api="blas"):
            filled = LinearNDInterpolator(sites, values)(targets)
    outside = ~np.isfinite(filled)
    if outside.any():
        filled[outside] = values[cKDTree(sites).query(targets[outside])[1]]
    out = depth.copy()
    out[holes] = filled
    return out


@dataclass
class MaskViews:
    """Per point (N,): views where it lands inside / outside the mask unoccluded (int32), its smallest distance
    to a mask edge over the views where it lands inside (metres at its depth: px × z / f; inf when none), and of
    the inside views those where it lies behind the hole-filled trusted depth by more than the margin (int32; zeros
    when not asked for)."""

    inside: np.ndarray
    outside: np.ndarray
    rim_m: np.ndarray
    behind: np.ndarray


def mask_views(
    cameras: Cameras, masks: Mapping[str, np.ndarray], points: np.ndarray, trusted: np.ndarray | None,
    occlusion_tolerance: float = 0.02, behind_margin: float | None = None,
) -> MaskViews:  # fmt: skip
    """Per point (N, 3, local frame): the views where it lands inside / outside the view's mask, counting only views
    where it is in front of the camera, inside the image and not behind the ``trusted`` points' closed z-buffer by
    more than ``occlusion_tolerance`` of its depth, and its distance to the nearest mask edge (a point of a convex
    surface lies on the silhouette rim of the views that graze it). With ``behind_margin`` (metres) and trusted
    points, also the inside views where it lies behind :func:`hole_filled_depth` of the trusted closed z-buffer by
    more than the margin. Views without a mask entry are not counted."""
    inside = np.zeros(len(points), np.int32)
    outside = np.zeros(len(points), np.int32)
    behind = np.zeros(len(points), np.int32)
    rim = np.full(len(points), np.inf)
    has_trusted = trusted is not None and len(trusted) > 0
    for view in cameras:
        mask = masks.get(view.name)
        if mask is None:
            continue
        h, w = mask.shape
        px = project_to_pixels(cameras, view, points, w, h)
        row, col, z, ok = px.row, px.col, px.z, px.ok.copy()
        if has_trusted:
            zb = closed_zbuffer(cameras, view, trusted)
            front = np.zeros(len(points), bool)
            front[ok] = z[ok] <= zb[row[ok], col[ok]] * (1.0 + occlusion_tolerance)
            ok &= front
        hit = np.zeros(len(points), bool)
        hit[ok] = mask[row[ok], col[ok]]
        inside += hit
        outside += ok & ~hit
        if behind_margin is not None and has_trusted and hit.any():
            filled = hole_filled_depth(zb)
            behind[hit] += z[hit] > filled[row[hit], col[hit]] + behind_margin
        if hit.any():
            # distance (px) of each mask pixel's centre to the nearest outside pixel's centre, minus half a pixel
            padded = np.pad(mask.astype(np.uint8), 1)  # the image border is an edge too
            edge_px = cv2.distanceTransform(padded, cv2.DIST_L2, 5)[1:-1, 1:-1] - 0.5
            f = float(np.mean(cameras.camera_of(view).focal))
            rim[hit] = np.minimum(rim[hit], edge_px[row[hit], col[hit]] * z[hit] / f)
    return MaskViews(inside, outside, rim, behind)


def select_survey_points(
    splats: GaussianSet,
    cameras: Cameras,
    masks: Mapping[str, np.ndarray],
    trusted: np.ndarray | None,
    spacing: float,
    options: SurveyPointOptions | None = None,
) -> SurveyPointSelection:
    """Which splats' centres are trustworthy survey points (see :class:`SurveyPointOptions`).

    splats: any origin (moved to the cameras' origin for the view tests); masks: image name → (H, W) bool at the
    camera's size (the training masks); trusted: (M, 3) trusted MVS points in the cameras' local frame (occlusion
    test; None: no occlusion test); spacing: trusted MVS point spacing, metres (> 0).
    """
    opts = options or SurveyPointOptions()
    if not spacing > 0:
        raise ConfigError(f"spacing must be a positive distance in metres, got {spacing}")
    n = len(splats)
    reasons = np.zeros(n, np.uint8)
    if n == 0:
        z = np.zeros(0, np.int32)
        return SurveyPointSelection(np.zeros(0, bool), reasons, z, z, SurveyPointCounts(0, 0, 0, 0, 0, 0, 0, 0, 0))

    def mark(cond: np.ndarray, reason: PointReason) -> None:
        reasons[(reasons == 0) & cond] = reason

    sigma = splats.scales.astype(np.float64)
    if opts.shape_checks and opts.min_opacity is not None:
        mark(splats.opacities < opts.min_opacity, PointReason.LOW_OPACITY)
    if opts.shape_checks and opts.max_thickness_spacing is not None:
        mark(sigma.min(axis=1) > opts.max_thickness_spacing * spacing, PointReason.THICK)
    if opts.shape_checks and opts.max_extent_spacing is not None:
        mark(sigma.max(axis=1) > opts.max_extent_spacing * spacing, PointReason.LARGE)
    local = splats.with_origin(cameras.origin).means
    margin = opts.behind_margin_spacing * spacing if opts.max_behind_share is not None else None
    mv = mask_views(cameras, masks, local, trusted, opts.occlusion_tolerance, margin)
    inside, outside = mv.inside, mv.outside
    mark(inside < opts.min_views, PointReason.FEW_VIEWS)
    if opts.min_mask_share is not None:
        share = inside / np.maximum(inside + outside, 1)
        mark(share < opts.min_mask_share, PointReason.OFF_MASKS)
    if opts.max_rim_spacing is not None:
        mark(mv.rim_m > opts.max_rim_spacing * spacing, PointReason.INTERIOR)
    if opts.max_behind_share is not None:
        mark(mv.behind > opts.max_behind_share * np.maximum(inside, 1), PointReason.BEHIND)
    counts = SurveyPointCounts(
        n, *(int((reasons == r).sum()) for r in list(PointReason)[1:]), int((reasons == 0).sum())
    )
    return SurveyPointSelection(reasons == 0, reasons, inside, outside, counts)
