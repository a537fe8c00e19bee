"""Image boundaries: edges of the photos, back-projected to the points that fall on or near them.

A material boundary (glass in a frame, a chrome trim on paint, a thin wire against the sky) is a sharp line in
the photos but falls inside one 3D neighbourhood of k points, which blurs it. Per view, once: the grey photo
(mean of RGB, / 255), its Sobel gradient magnitude and the Euclidean distance transform of its Canny edges
(OpenCV). Per point, over the views that fused it (``PointCloud.visibility``; held-out photos never take part),
at the nearest pixel of its projection:

``edge_strength_views`` (1/px)
    mean Sobel gradient magnitude (3 × 3 Sobel / 8: grey levels / 255 per pixel, the slope of a ramp, half the
    height of a step next to it); neutral (no fusing view): 0.
``edge_distance_px`` (px)
    mean distance to the nearest Canny edge pixel (thresholds :data:`CANNY_LOW` / :data:`CANNY_HIGH` on the 3 × 3
    Sobel of the 8-bit grey photo, L2 gradient), capped at :data:`EDGE_CAP_PX`; neutral (no fusing view): the cap.
``edge_distance_spacing`` (1: point spacings)
    the same distance per view converted to metres at the point's depth (px × z / f, the footprint on a
    fronto-parallel plane), averaged, divided by the cloud's point spacing: below 1, the boundary is closer than
    the 3D neighbourhood can resolve. Capped at :data:`EDGE_CAP_SPACING`; neutral (no fusing view): the cap.

The per-view maps are computed once per view and call (a small LRU cache of ``options.cache_images`` views, maps
stored as float16: 4 bytes per pixel); work is chunked over points (outer) and views (inner).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from classify.features.fusing import fusing_chunks
from classify.features.multiview import MultiViewOptions, ViewData
from core.errors import DataError

IMAGE_BOUNDARY_NAMES = ("edge_strength_views", "edge_distance_px", "edge_distance_spacing")
CANNY_LOW = 40.0  # hysteresis thresholds on the 3 × 3 Sobel of the 8-bit grey photo (a step of h levels gives 4 h)
CANNY_HIGH = 120.0
EDGE_CAP_PX = 32.0
EDGE_CAP_SPACING = 32.0


def edge_maps(photo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient magnitude (H, W) float16 (grey / 255 per pixel) and distance to the nearest Canny edge pixel
    (H, W) float16 (pixels, capped at :data:`EDGE_CAP_PX`) of a photo (H, W, 3) or (H, W) uint8."""
    import cv2

    img = np.asarray(photo)
    grey = img.astype(np.float32).mean(axis=2) if img.ndim == 3 else img.astype(np.float32)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    strength = np.sqrt(gx * gx + gy * gy) / (8.0 * 255.0)
    grey8 = np.clip(np.rint(grey), 0, 255).astype(np.uint8)
    edges = cv2.Canny(grey8, CANNY_LOW, CANNY_HIGH, apertureSize=3, L2gradient=True)
    if edges.any():
        dist = cv2.distanceTransform(np.where(edges > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        dist = np.minimum(dist, EDGE_CAP_PX)
    else:
        dist = np.full(grey.shape, EDGE_CAP_PX, dtype=np.float32)
    return strength.astype(np.float16), dist.astype(np.float16)


def image_boundary_features(
    positions: np.ndarray,
    visibility: list[np.ndarray] | None,
    views: ViewData,
    spacing: float,
    options: MultiViewOptions = MultiViewOptions(),
) -> dict[str, np.ndarray]:
    """The features of :data:`IMAGE_BOUNDARY_NAMES`, each (N,) float32 and finite, for points (N, 3) float64
    (metres, the cameras' local frame).

    visibility: per point, the image ids that fused it (None: the frustum views whose depth map agrees).
    spacing: the cloud's median point spacing (metres, > 0). options: chunking and the maps' cache size.
    """
    pts = np.asarray(positions, dtype=np.float64)
    n = len(pts)
    if not spacing > 0 or not np.isfinite(spacing):
        raise DataError(f"image-boundary features need a positive point spacing, got {spacing}")

    @lru_cache(maxsize=max(1, options.cache_images))
    def maps(name: str) -> tuple[np.ndarray, np.ndarray]:
        return edge_maps(views.image(name))

    strength_sum, dist_sum, metric_sum, count = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    for sl, samples in fusing_chunks(pts, visibility, views, options.chunk_size, options.depth_tolerance):
        for s in samples:
            strength, dist = maps(s.view.name)
            sx, sy = strength.shape[1] / s.camera.width, strength.shape[0] / s.camera.height  # map px per camera px
            d_px = s.sample(dist).astype(np.float64)
            idx = s.idx + sl.start
            strength_sum[idx] += s.sample(strength)
            dist_sum[idx] += d_px
            fx, fy = s.camera.focal
            metric_sum[idx] += np.minimum(
                d_px / (0.5 * (sx + sy)) * s.z / (0.5 * (fx + fy)) / spacing, EDGE_CAP_SPACING
            )
            count[idx] += 1
    has = count > 0
    safe = np.maximum(count, 1)
    return {
        "edge_strength_views": np.where(has, strength_sum / safe, 0.0).astype(np.float32),
        "edge_distance_px": np.where(has, dist_sum / safe, EDGE_CAP_PX).astype(np.float32),
        "edge_distance_spacing": np.where(has, metric_sum / safe, EDGE_CAP_SPACING).astype(np.float32),
    }
