"""Image texture: how much the photos' grey levels vary in a window around the point's projections.

Multi-view stereo matches windows of the photos: where a window holds texture (a rough gravel roof, printed
text, bricks), a fused point is a measurement, even when few views fused it or it lies off the neighbours' plane;
where it holds almost none (matte paint, a sky mirrored in glass or chrome), a fused point is a guess. The 3D
neighbourhood's colour spread (``color_variance``) sees texture at the cloud's spacing, usually several pixels;
this group reads it at the photos' own resolution, in a window of the size the CPU MVS matches
(:data:`TEXTURE_RADIUS_PX`, ``recon.mvs_cpu_options`` ``window_radius``). Per view, once (OpenCV box filters over
the grey photo, mean of RGB / 255): the window's standard deviation and the smaller eigenvalue of the window's
structure tensor (mean of the outer products of the 3 × 3 Sobel gradients / 8: two-dimensional texture, which
an edge alone does not have). Per point, over the views that fused it (``PointCloud.visibility``; held-out photos
never take part), at the nearest pixel of its projection:

``texture_std_views`` (1)
    mean over the fusing views of the window's grey standard deviation (0–1 grey scale); neutral (no fusing
    view): 0.
``texture_corner_views`` (1/px)
    mean over the fusing views of sqrt(λ_min) of the window's structure tensor (grey / 255 per pixel, the
    Shi–Tomasi corner strength); neutral: 0.
``texture_log_spread`` (1)
    standard deviation over the fusing views of ln(window std + :data:`TEXTURE_EPS`): the same surface seen with
    unlike texture from different views (a reflection that moves, a pane showing what lies behind it), 0 for a
    matte textured or a uniform surface; neutral (fewer than 2 fusing views): 0.

Hand-written because no library maps a window statistic back to the points of a fused cloud; the per-view maps
are OpenCV filters, cached per view like :mod:`classify.features.image_boundaries` (two float16 maps, 4 bytes per
pixel).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from classify.features.fusing import fusing_chunks
from classify.features.multiview import MultiViewOptions, ViewData

IMAGE_TEXTURE_NAMES = ("texture_std_views", "texture_corner_views", "texture_log_spread")
TEXTURE_RADIUS_PX = 3
"""Window radius (pixels): the (2r+1)² window of the CPU MVS's NCC (``MvsOptions`` ``window_radius``)."""
TEXTURE_EPS = 0.004
"""Added to a window's grey std (0–1 scale) before its log: about one grey level of 255, the photos' noise floor."""


def texture_maps(photo: np.ndarray, radius: int = TEXTURE_RADIUS_PX) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel of a photo (H, W, 3) or (H, W) uint8: the grey standard deviation (0–1 scale) and sqrt of the
    smaller eigenvalue of the structure tensor (grey / 255 per pixel) over the (2r+1)² window centred there (borders
    reflected, OpenCV's default), both (H, W) float16, ≥ 0."""
    import cv2

    img = np.asarray(photo)
    # float64 throughout: E[x²] − E[x]² of float32 window sums leaves ~1e-4 of std on a uniform photo.
    grey = (img.astype(np.float64).mean(axis=2) if img.ndim == 3 else img.astype(np.float64)) / 255.0
    size = (2 * radius + 1, 2 * radius + 1)

    def window_mean(a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, cv2.CV_64F, size, normalize=True)

    mean = window_mean(grey)
    var = np.maximum(window_mean(grey * grey) - mean * mean, 0.0)
    var[var < 1e-12] = 0.0  # rounding of the window sums on a uniform window
    gx = cv2.Sobel(grey, cv2.CV_64F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(grey, cv2.CV_64F, 0, 1, ksize=3) / 8.0
    a, b, c = window_mean(gx * gx), window_mean(gx * gy), window_mean(gy * gy)
    lam_min = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b)
    return np.sqrt(var).astype(np.float16), np.sqrt(np.maximum(lam_min, 0.0)).astype(np.float16)


def image_texture_features(
    positions: np.ndarray,
    visibility: list[np.ndarray] | None,
    views: ViewData,
    options: MultiViewOptions = MultiViewOptions(),
) -> dict[str, np.ndarray]:
    """The features of :data:`IMAGE_TEXTURE_NAMES`, each (N,) float32 and finite, for points (N, 3) float64 (metres,
    the cameras' local frame).

    visibility: per point, the image ids that fused it (None: the frustum views whose depth map agrees).
    options: chunking, the maps' cache size and the fallback depth tolerance.
    """
    pts = np.asarray(positions, dtype=np.float64)
    n = len(pts)

    @lru_cache(maxsize=max(1, options.cache_images))
    def maps(name: str) -> tuple[np.ndarray, np.ndarray]:
        return texture_maps(views.image(name))

    std_sum, corner_sum, log_sum, log_sq, count = (np.zeros(n) for _ in range(5))
    for sl, samples in fusing_chunks(pts, visibility, views, options.chunk_size, options.depth_tolerance):
        for s in samples:
            std_map, corner_map = maps(s.view.name)
            std = s.sample(std_map).astype(np.float64)
            log_std = np.log(std + TEXTURE_EPS)
            idx = s.idx + sl.start
            std_sum[idx] += std
            corner_sum[idx] += s.sample(corner_map)
            log_sum[idx] += log_std
            log_sq[idx] += log_std * log_std
            count[idx] += 1
    safe = np.maximum(count, 1)
    log_mean = log_sum / safe
    log_var = np.maximum(log_sq / safe - log_mean * log_mean, 0.0)
    return {
        "texture_std_views": np.where(count > 0, std_sum / safe, 0.0).astype(np.float32),
        "texture_corner_views": np.where(count > 0, corner_sum / safe, 0.0).astype(np.float32),
        "texture_log_spread": np.where(count >= 2, np.sqrt(log_var), 0.0).astype(np.float32),
    }
