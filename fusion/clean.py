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
from fusion.merge import subset
from fusion.train.init import points_in_masks
from fusion.train.trainer import scene_scale


class Reason(IntEnum):
    """Why a splat was removed (0 = kept)."""

    KEPT = 0
    OUTSIDE_MASKS = 1
    LOW_OPACITY = 2
    EXTREME_SCALE = 3
    ISOLATED = 4


@dataclass(frozen=True)
class CleanOptions:
    """Options of :func:`clean_splats` (see the module docstring); a check is off when its value is None.

    Defaults were chosen on data_synth ``tabletop`` (24 views, 320×240, 1000 steps, 29.9 k splats): stricter ones
    (σ > 0.05 × scene scale or > 20 median spacings; DBSCAN eps 5 spacings, clusters < 5) removed 59 % of the
    splats and cost 7.5 dB of held-out PSNR inside the masks — large flat splats on textureless, glass and mirror
    regions and sparse splats are legitimate there. The defaults remove 11 % for 0.1 dB.
    """

    mask_dilation_px: int = 2
    min_opacity: float | None = 0.02
    max_scale_scene: float | None = 0.2
    max_scale_spacing: float | None = None
    cluster_eps_spacing: float | None = 50.0
    min_cluster_size: int = 3

    def __post_init__(self) -> None:
        if self.mask_dilation_px < 0 or self.min_cluster_size < 1:
            raise ConfigError("mask_dilation_px must be >= 0 and min_cluster_size >= 1")
        for name in ("max_scale_scene", "max_scale_spacing", "cluster_eps_spacing"):
            v = getattr(self, name)
            if v is not None and not v > 0:
                raise ConfigError(f"{name} must be > 0 or None, got {v}")


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


def _median_spacing(points: np.ndarray) -> float:
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
    spacing = _median_spacing(splats.means)
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
