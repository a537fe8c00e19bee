"""Initial splats inside the regions to train (before any optimisation).

Three sources of seeds (all in the cameras' local frame, metres):

1. MVS points flagged ``needs_splats`` (their geometry is unreliable, but they sit near the surface);
2. SfM points whose projection falls inside a mask in at least ``min_sfm_views`` views (in front of the camera);
3. ray samples: for a seeded subset of each view's mask pixels, a point on the pixel's ray at the depth
   interpolated from the surrounding trusted MVS depth (the z-buffered projection of the ``needs_splats = 0``
   points, in a band around the mask), so that holes without any MVS point still get seeds. The interpolation is a
   normalised convolution (:func:`fill_depth`): the Gaussian-weighted mean of nearby band depths, with the window
   widened until it reaches some.

Colours: each seed's own colour (MVS / SfM point colour; the photo's pixel for ray samples). Scales: isotropic,
the mean distance to the ``k_scale`` nearest seeds-or-frozen points (3DGS's initialisation), clamped. Opacity:
``initial_opacity``. Seeds closer than ``min_spacing`` to an earlier seed are dropped, and the total is capped
(seeded subsample).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from core.cameras import Cameras
from core.errors import DataError
from core.gaussians import SH_C0, GaussianSet, logit
from fusion.mask_projection import project_to_pixels
from fusion.train.options import InitOptions  # noqa: F401 (re-exported)


@dataclass
class InitResult:
    """The seeds as a degree-0 :class:`GaussianSet` (cameras' frame) and how many came from each source."""

    gaussians: GaussianSet
    from_mvs: int
    from_sfm: int
    from_rays: int
    rays_without_depth: int
    dropped_close: int
    dropped_cap: int


def points_in_masks(
    cameras: Cameras, masks: Mapping[str, np.ndarray], points: np.ndarray, min_views: int = 1
) -> np.ndarray:
    """(N,) bool: the local-frame points (N, 3) that project in front of the camera into a mask pixel in at least
    ``min_views`` views (masks: image name → (H, W) bool at the camera's size)."""
    hits = np.zeros(len(points), np.int32)
    for view in cameras:
        mask = masks.get(view.name)
        if mask is None or not mask.any():
            continue
        h, w = mask.shape
        hits += project_to_pixels(cameras, view, points, w, h).lookup(mask)
    return hits >= min_views


def zbuffer_depth(cameras: Cameras, view, points: np.ndarray) -> np.ndarray:
    """(H, W) float64 z-depth of the nearest of ``points`` (N, 3, local frame) per pixel; 0 where none projects."""
    cam = cameras.camera_of(view)
    px = project_to_pixels(cameras, view, points, cam.width, cam.height)
    ok = px.ok
    depth = np.full(cam.height * cam.width, np.inf)
    np.minimum.at(depth, px.row[ok] * cam.width + px.col[ok], px.z[ok])
    depth[~np.isfinite(depth)] = 0.0
    return depth.reshape(cam.height, cam.width)


def fill_depth(depth: np.ndarray, valid: np.ndarray, sigmas: tuple[float, ...] = (2, 4, 8, 16, 32, 64)) -> np.ndarray:
    """(H, W) depth interpolated everywhere from the ``valid`` pixels by normalised convolution: per pixel, the
    Gaussian-weighted mean of the valid depths at the smallest σ (px) whose weight reaches 1e-3; NaN where even the
    largest σ sees no valid pixel. (Normalised convolution instead of a Delaunay interpolator: Qhull on pixel-grid
    samples took minutes per view.)"""
    out = np.full(depth.shape, np.nan)
    todo = np.ones(depth.shape, bool)
    d = np.where(valid, depth, 0.0).astype(np.float64)
    w = valid.astype(np.float64)
    for sigma in sigmas:
        k = int(2 * round(3 * sigma) + 1)
        wd = cv2.GaussianBlur(d, (k, k), sigma, borderType=cv2.BORDER_CONSTANT)
        ww = cv2.GaussianBlur(w, (k, k), sigma, borderType=cv2.BORDER_CONSTANT)
        ready = todo & (ww > 1e-3)
        out[ready] = wd[ready] / ww[ready]
        todo &= ~ready
        if not todo.any():
            break
    return out


def ray_seeds(
    cameras: Cameras,
    masks: Mapping[str, np.ndarray],
    images: Mapping[str, np.ndarray],
    trusted: np.ndarray,
    options: InitOptions,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Points (M, 3) and colours (M, 3) in [0, 1] on mask pixels' rays at interpolated trusted depth; and the
    number of sampled pixels that got no depth (no trusted sample near the mask)."""
    rng = np.random.default_rng(options.seed)
    pts, cols, missing = [], [], 0
    kernel = np.ones((2 * options.band_px + 1, 2 * options.band_px + 1), np.uint8)
    for view in cameras:
        mask = masks.get(view.name)
        if mask is None or not mask.any() or options.rays_per_view == 0:
            continue
        depth = zbuffer_depth(cameras, view, trusted)
        band = (cv2.dilate(mask.astype(np.uint8), kernel) > 0) & ~mask & (depth > 0)
        rows, colsi = np.nonzero(mask)
        pick = rng.choice(len(rows), size=min(options.rays_per_view, len(rows)), replace=False)
        r, c = rows[pick], colsi[pick]
        z = fill_depth(np.where(band, depth, 0.0), band)[r, c]
        ok = np.isfinite(z)
        missing += int((~ok).sum())
        r, c, z = r[ok], c[ok], z[ok]
        query = np.stack([c + 0.5, r + 0.5], axis=1)
        pts.append(cameras.unproject(view, query, z))
        img = np.asarray(images[view.name])
        img = img.astype(np.float64) / 255.0 if img.dtype == np.uint8 else img.astype(np.float64)
        cols.append(img[r, c, :3])
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3)), missing
    return np.concatenate(pts), np.concatenate(cols), missing


def seed_splats(
    cameras: Cameras,
    masks: Mapping[str, np.ndarray],
    images: Mapping[str, np.ndarray] | None,
    mvs_points: np.ndarray,
    mvs_colours: np.ndarray,
    needs_splats: np.ndarray,
    sfm_points: np.ndarray | None = None,
    sfm_colours: np.ndarray | None = None,
    options: InitOptions | None = None,
) -> InitResult:
    """Seeds for the trainable splats (see the module docstring).

    mvs_points (N, 3) float64 and sfm_points (S, 3), local frame of ``cameras``; colours (·, 3) uint8 0–255;
    needs_splats (N,) bool; masks / images: image name → arrays at the camera's size (images needed for ray seeds).
    """
    opts = options or InitOptions()
    rng = np.random.default_rng(opts.seed)
    needs = np.asarray(needs_splats, bool).reshape(-1)
    if len(needs) != len(mvs_points):
        raise DataError(f"needs_splats has {len(needs)} entries for {len(mvs_points)} MVS points")
    parts = [(mvs_points[needs], np.asarray(mvs_colours, np.float64)[needs] / 255.0)]
    n_sfm = 0
    if sfm_points is not None and len(sfm_points):
        inside = points_in_masks(cameras, masks, sfm_points, opts.min_sfm_views)
        n_sfm = int(inside.sum())
        sc = np.full((len(sfm_points), 3), 0.5) if sfm_colours is None else np.asarray(sfm_colours) / 255.0
        parts.append((sfm_points[inside], sc[inside]))
    n_rays, missing = 0, 0
    if images is not None and opts.rays_per_view > 0:
        rp, rc, missing = ray_seeds(cameras, masks, images, mvs_points[~needs], opts)
        n_rays = len(rp)
        parts.append((rp, rc))
    points = np.concatenate([p for p, _ in parts])
    colours = np.concatenate([c for _, c in parts])
    if len(points) == 0:
        raise DataError("no seeds for new splats: no needs_splats point, no SfM point in a mask, no ray sample")
    dropped_close = 0
    if opts.min_spacing > 0 and len(points) > 1:
        pairs = cKDTree(points).query_pairs(opts.min_spacing, output_type="ndarray")
        keep = np.ones(len(points), bool)
        keep[pairs[:, 1]] = False
        dropped_close = int((~keep).sum())
        points, colours = points[keep], colours[keep]
    dropped_cap = 0
    if len(points) > opts.max_seeds:
        keep = np.sort(rng.choice(len(points), opts.max_seeds, replace=False))
        dropped_cap = len(points) - opts.max_seeds
        points, colours = points[keep], colours[keep]
    gs = gaussians_from_points(points, colours, mvs_points[~needs], cameras.origin, opts)
    return InitResult(gs, int(needs.sum()), n_sfm, n_rays, missing, dropped_close, dropped_cap)


def gaussians_from_points(
    points: np.ndarray,
    colours: np.ndarray,
    neighbours: np.ndarray | None,
    origin: np.ndarray,
    options: InitOptions | None = None,
) -> GaussianSet:
    """Isotropic degree-0 Gaussians at ``points`` (N, 3) with ``colours`` (N, 3) in [0, 1]: σ = mean distance to
    the ``k_scale`` nearest of the points and ``neighbours`` (M, 3) (3DGS init, clamped to the 99th percentile),
    α = ``initial_opacity``."""
    opts = options or InitOptions()
    reference = points if neighbours is None or len(neighbours) == 0 else np.concatenate([points, neighbours])
    k = min(opts.k_scale + 1, len(reference))
    spacing = np.full(len(points), 0.01)
    if k > 1:
        d, _ = cKDTree(reference).query(points, k=k)
        mean = d[:, 1:].mean(axis=1)
        spacing = np.where(mean > 0, mean, 0.01)
    top = np.quantile(spacing, 0.99) if len(spacing) > 10 else spacing.max()
    spacing = np.clip(spacing, 1e-5, max(top, 1e-5))
    n = len(points)
    return GaussianSet(
        points,
        np.repeat(np.log(spacing)[:, None], 3, axis=1),
        np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
        np.full(n, float(logit(np.array(opts.initial_opacity)))),
        (np.clip(colours, 0, 1) - 0.5) / SH_C0,
        origin=origin,
    )


def sfm_seeds(points: np.ndarray, colours: np.ndarray | None, origin: np.ndarray,
              options: InitOptions | None = None) -> GaussianSet:  # fmt: skip
    """The whole-scene baseline's initialisation: one Gaussian per SfM point (local frame; colours uint8 0–255)."""
    if len(points) == 0:
        raise DataError("the sparse model has no 3D points to initialise the baseline from")
    c = np.full((len(points), 3), 0.5) if colours is None else np.asarray(colours, np.float64) / 255.0
    return gaussians_from_points(np.asarray(points, np.float64), c, None, origin, options)
