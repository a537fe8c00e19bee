"""Multi-view features: how the photos and the per-view depth maps agree about each fused point.

For every point and every registered view whose frustum holds it (z > 0, inside the image): the depth map at
the projection is compared with the point's depth (agree / sees past the point / empty); for the views that
fused the point (its visibility) the photo colour, a 3×3 grey patch and the viewing ray are accumulated.
Specular and transparent surfaces change colour with the viewpoint (high ``color_std_views``, low ``ncc_views``);
virtual points behind mirrors and points refracted through glass sit in front of surfaces other views see
(``depth_freespace``); textureless surfaces give flat patches (low ``ncc_views``).

Work is chunked over points (outer) and views (inner); images and depth maps are read once through small
caches, so memory stays at O(chunk × features) plus the cached images.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from core.cameras import Cameras
from core.errors import DataError, InputFileError

MULTIVIEW_NAMES = (
    "n_views",
    "view_ratio",
    "triangulation_spread_deg",
    "color_std_views",
    "ncc_views",
    "depth_agree",
    "depth_freespace",
    "depth_invalid",
    "depth_residual",
)


@dataclass(frozen=True)
class MultiViewOptions:
    """depth_tolerance: relative depth difference (|d_map − z| / z) under which a depth map agrees (default 1 %).
    chunk_size: points per chunk. cache_images: photos / depth maps kept in memory at once (default 64)."""

    depth_tolerance: float = 0.01
    chunk_size: int = 200_000
    cache_images: int = 64


@dataclass
class ViewData:
    """The registered views of a dense workspace: undistorted pinhole ``cameras`` (local frame of the cloud) and
    loaders by image name: ``image(name)`` → (H, W, 3) uint8, ``depth(name)`` → (H, W) float32 z-depth metres
    (≤ 0 invalid) or None when the view has no depth map."""

    cameras: Cameras
    image: Callable[[str], np.ndarray]
    depth: Callable[[str], np.ndarray | None]


def views_from_workspace(dense_dir: str | Path, cache: int = 64) -> ViewData:
    """:class:`ViewData` of a COLMAP dense workspace (``dense/sparse``, ``dense/images``, ``dense/stereo``)."""
    from core.io.colmap import read_model
    from core.io.images import read_image
    from recon.workspace import DenseWorkspace, read_array

    ws = DenseWorkspace(Path(dense_dir))
    if not ws.sparse.is_dir():
        raise InputFileError("dense workspace has no sparse/ model", ws.root)
    cameras, _ = read_model(ws.sparse)

    @lru_cache(maxsize=cache)
    def image(name: str) -> np.ndarray:
        return read_image(ws.images / name)

    @lru_cache(maxsize=cache)
    def depth(name: str) -> np.ndarray | None:
        kind = ws.map_kind(name)
        if kind is None:
            path = ws.depth_map(name, "geometric")
            alt = ws.depth_map(name, "photometric")
            path = path if path.is_file() else alt
            return read_array(path) if path.is_file() else None
        return read_array(ws.depth_map(name, kind))

    return ViewData(cameras, image, depth)


def _sample_nearest(img: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    c = np.clip(col.astype(np.int64), 0, w - 1)
    r = np.clip(row.astype(np.int64), 0, h - 1)
    return img[r, c]


def _grey_patches(grey: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """3×3 patches (M, 9) float32 around integer pixels, zero-mean and unit-norm (zero where flat)."""
    h, w = grey.shape
    c = np.clip(col.astype(np.int64), 0, w - 1)
    r = np.clip(row.astype(np.int64), 0, h - 1)
    offs = np.array([-1, 0, 1])
    rr = np.clip(r[:, None, None] + offs[None, :, None], 0, h - 1)
    cc = np.clip(c[:, None, None] + offs[None, None, :], 0, w - 1)
    p = grey[rr, cc].reshape(len(c), 9).astype(np.float32)
    p -= p.mean(axis=1, keepdims=True)
    norm = np.linalg.norm(p, axis=1, keepdims=True)
    # Flat patches (norm below ~1 grey level over the patch) carry no texture: they add nothing to the sum.
    return np.where(norm > 1.0 / 255.0, p / np.maximum(norm, 1e-12), 0.0)


def multiview_features(
    positions: np.ndarray,
    visibility: list[np.ndarray] | None,
    views: ViewData,
    options: MultiViewOptions = MultiViewOptions(),
) -> dict[str, np.ndarray]:
    """The features of :data:`MULTIVIEW_NAMES`, each (N,) float32, for points (N, 3) float64 in the cameras' frame.

    visibility: per point, the image ids that fused it (``PointCloud.visibility`` from
    :func:`recon.workspace.read_fused`); None treats every frustum view whose depth map agrees as fusing.
    """
    pts = np.asarray(positions, dtype=np.float64)
    n = len(pts)
    if visibility is not None and len(visibility) != n:
        raise DataError(f"visibility lists {len(visibility)} points, the cloud has {n}")
    view_list = list(views.cameras)
    if not view_list:
        raise DataError("multi-view features need at least one registered view")
    out = {name: np.zeros(n, dtype=np.float32) for name in MULTIVIEW_NAMES}
    if visibility is not None:
        counts = np.fromiter((len(v) for v in visibility), dtype=np.int64, count=n)
        flat_ids = np.concatenate(visibility) if n and counts.sum() else np.zeros(0, np.int64)
        flat_pts = np.repeat(np.arange(n), counts)
    for start in range(0, n, options.chunk_size):
        stop = min(n, start + options.chunk_size)
        m = stop - start
        p = pts[start:stop]
        fused_of: dict[int, np.ndarray] | None = None
        if visibility is not None:
            sel = (flat_pts >= start) & (flat_pts < stop)
            ids, owners = flat_ids[sel], flat_pts[sel] - start
            order = np.argsort(ids, kind="stable")
            ids, owners = ids[order], owners[order]
            bounds = np.searchsorted(ids, [v.image_id for v in view_list] + [np.iinfo(np.int64).max])
            fused_of = {}
            for j, v in enumerate(view_list):
                fused_of[v.image_id] = owners[bounds[j] : bounds[j + 1]] if j + 1 < len(bounds) else owners[:0]
        n_frustum = np.zeros(m)
        n_fused = np.zeros(m)
        agree = np.zeros(m)
        freespace = np.zeros(m)
        invalid = np.zeros(m)
        residual_sum = np.zeros(m)
        residual_n = np.zeros(m)
        col_sum = np.zeros((m, 3))
        col_sq = np.zeros((m, 3))
        ray_sum = np.zeros((m, 3))
        patch_sum = np.zeros((m, 9), dtype=np.float32)
        patch_n = np.zeros(m)
        for v in view_list:
            cam = views.cameras.camera_of(v)
            uv, z = views.cameras.project(v, p)
            col, row = uv[:, 0], uv[:, 1]
            inside = (z > 0) & (col >= 0) & (row >= 0) & (col < cam.width) & (row < cam.height)
            if not inside.any():
                continue
            idx = np.flatnonzero(inside)
            n_frustum[idx] += 1
            depth = views.depth(v.name)
            rel = None
            if depth is not None:
                sx, sy = depth.shape[1] / cam.width, depth.shape[0] / cam.height
                d = _sample_nearest(depth, col[idx] * sx, row[idx] * sy).astype(np.float64)
                zi = z[idx]
                rel = (d - zi) / zi
                valid = d > 0
                invalid[idx] += ~valid
                agree[idx] += valid & (np.abs(rel) <= options.depth_tolerance)
                freespace[idx] += valid & (rel > options.depth_tolerance)
            if fused_of is not None:
                fused = fused_of[v.image_id]
                fused = fused[inside[fused]]
            elif rel is not None:
                fused = idx[(d > 0) & (np.abs(rel) <= options.depth_tolerance)]
            else:
                fused = idx
            if len(fused) == 0:
                continue
            if rel is not None:
                # Residuals of the fusing views (positions of `fused` inside `idx`).
                pos = np.searchsorted(idx, fused)
                r_abs = np.minimum(np.abs(rel[pos]), 1.0)
                ok = np.isfinite(r_abs) & (d[pos] > 0)
                residual_sum[fused[ok]] += r_abs[ok]
                residual_n[fused[ok]] += 1
            n_fused[fused] += 1
            photo = views.image(v.name)
            sx, sy = photo.shape[1] / cam.width, photo.shape[0] / cam.height
            fc, fr = col[fused] * sx, row[fused] * sy
            rgb = _sample_nearest(photo, fc, fr).astype(np.float64) / 255.0
            col_sum[fused] += rgb
            col_sq[fused] += rgb**2
            grey = photo.astype(np.float32).mean(axis=2) / 255.0 if photo.ndim == 3 else photo / 255.0
            patches = _grey_patches(grey, fc, fr)
            patch_sum[fused] += patches
            patch_n[fused] += np.linalg.norm(patches, axis=1) > 0
            ray = p[fused] - v.center
            ray_sum[fused] += ray / np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-12)
        safe_f = np.maximum(n_fused, 1)
        safe_v = np.maximum(n_frustum, 1)
        var = np.maximum(col_sq / safe_f[:, None] - (col_sum / safe_f[:, None]) ** 2, 0.0)
        mean_ray = np.linalg.norm(ray_sum, axis=1) / safe_f
        sl = slice(start, stop)
        out["n_views"][sl] = n_fused if visibility is None else counts[sl]
        out["view_ratio"][sl] = np.minimum(n_fused / safe_v, 1.0)
        out["triangulation_spread_deg"][sl] = np.where(
            n_fused > 1, 2.0 * np.degrees(np.arccos(np.clip(mean_ray, 0.0, 1.0))), 0.0
        )
        out["color_std_views"][sl] = np.sqrt(var).mean(axis=1)
        # Mean NCC of each view's normalised patch with the views' mean patch = ||sum of patches|| / n.
        out["ncc_views"][sl] = np.linalg.norm(patch_sum, axis=1) / np.maximum(patch_n, 1)
        out["depth_agree"][sl] = agree / safe_v
        out["depth_freespace"][sl] = freespace / safe_v
        out["depth_invalid"][sl] = invalid / safe_v
        out["depth_residual"][sl] = np.where(residual_n > 0, residual_sum / np.maximum(residual_n, 1), 1.0)
    return out
