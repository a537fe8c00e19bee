"""Multi-view features: how the photos and the per-view depth maps agree about each fused point.

For every point and every view of the dense reconstruction (the fused photos: held-out ones never take part) whose
frustum holds it (z > 0, inside the image): the depth map at the projection is compared with the point's depth
(agree / sees past the point / empty); for the views that fused the point (its visibility) the photo colour, a 3×3
grey patch and the viewing ray are accumulated.
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

from core.cameras import Camera, Cameras, View
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
    """:class:`ViewData` of a COLMAP dense workspace (``dense/sparse``, ``dense/images``, ``dense/stereo``).

    Only the photos of the dense reconstruction take part: those of ``stereo/fusion.cfg`` (every registered photo
    when the workspace has none). Held-out photos are registered and undistorted for evaluation but never fused, so
    neither their camera, their photo nor any depth map of theirs reaches a feature; the loaders refuse other names
    (``KeyError``).
    """
    from core.io.colmap import read_model
    from core.io.images import read_image
    from recon.workspace import DenseWorkspace, read_array

    ws = DenseWorkspace(Path(dense_dir))
    if not ws.sparse.is_dir():
        raise InputFileError("dense workspace has no sparse/ model", ws.root)
    cameras, _ = read_model(ws.sparse)
    fused = ws.fused_names()
    if fused is not None:
        keep = set(fused)
        views = {i: v for i, v in cameras.views.items() if v.name in keep}
        cameras = Cameras(cameras.cameras, views, cameras.origin)
    names = frozenset(v.name for v in cameras)

    def _check(name: str) -> None:
        if name not in names:
            raise KeyError(f"{name!r} is not a photo of the dense reconstruction (held out, or not registered)")

    @lru_cache(maxsize=cache)
    def image(name: str) -> np.ndarray:
        _check(name)
        return read_image(ws.images / name)

    @lru_cache(maxsize=cache)
    def depth(name: str) -> np.ndarray | None:
        _check(name)
        kind = ws.map_kind(name)
        if kind is None:
            path = ws.depth_map(name, "geometric")
            alt = ws.depth_map(name, "photometric")
            path = path if path.is_file() else alt
            return read_array(path) if path.is_file() else None
        return read_array(ws.depth_map(name, kind))

    return ViewData(cameras, image, depth)


def sample_nearest(img: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Values of ``img`` at the nearest pixel of each (``col``, ``row``) (pixel units, clamped to the image)."""
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
        p = pts[start:stop]
        fused_of = None if visibility is None else fused_by_view(flat_ids, flat_pts, start, stop, view_list)
        acc = _ChunkSums.zeros(stop - start)
        for v in view_list:
            _accumulate_view(acc, views, v, p, fused_of, options.depth_tolerance)
        _finish_chunk(out, acc, slice(start, stop), None if visibility is None else counts)
    return out


def fused_by_view(
    flat_ids: np.ndarray, flat_pts: np.ndarray, start: int, stop: int, view_list: list[View]
) -> dict[int, np.ndarray]:
    """Per image id, the chunk-local indices (int64, ascending) of the points of [start, stop) that the view fused.

    ``flat_ids`` / ``flat_pts``: the visibility lists flattened into (image id, point index) pairs."""
    sel = (flat_pts >= start) & (flat_pts < stop)
    ids, owners = flat_ids[sel], flat_pts[sel] - start
    order = np.argsort(ids, kind="stable")
    ids, owners = ids[order], owners[order]
    # Each view's own run of ids (left to right bound): ids of no listed view (a photo not in the dense
    # reconstruction) belong to none, rather than to the listed view before them.
    wanted = np.array([v.image_id for v in view_list], dtype=np.int64)
    lo, hi = np.searchsorted(ids, wanted, "left"), np.searchsorted(ids, wanted, "right")
    return {v.image_id: owners[lo[j] : hi[j]] for j, v in enumerate(view_list)}


@dataclass
class _ChunkSums:
    """Per-point sums over the views of one chunk of M points (float64 unless stated)."""

    n_frustum: np.ndarray  # (M,) views whose frustum holds the point
    n_fused: np.ndarray  # (M,) views that fused the point
    agree: np.ndarray  # (M,) views whose depth map agrees within the tolerance
    freespace: np.ndarray  # (M,) views whose depth map sees past the point
    invalid: np.ndarray  # (M,) views whose depth map is empty at the projection
    residual_sum: np.ndarray  # (M,) relative depth residuals (capped at 1) of the fusing views
    residual_n: np.ndarray  # (M,) count of those residuals
    col_sum: np.ndarray  # (M, 3) photo colour in [0, 1] of the fusing views
    col_sq: np.ndarray  # (M, 3) its square
    ray_sum: np.ndarray  # (M, 3) unit viewing rays (camera centre → point) of the fusing views
    patch_sum: np.ndarray  # (M, 9) float32 normalised 3×3 grey patches of the fusing views
    patch_n: np.ndarray  # (M,) count of non-flat patches

    @classmethod
    def zeros(cls, m: int) -> _ChunkSums:
        return cls(
            n_frustum=np.zeros(m),
            n_fused=np.zeros(m),
            agree=np.zeros(m),
            freespace=np.zeros(m),
            invalid=np.zeros(m),
            residual_sum=np.zeros(m),
            residual_n=np.zeros(m),
            col_sum=np.zeros((m, 3)),
            col_sq=np.zeros((m, 3)),
            ray_sum=np.zeros((m, 3)),
            patch_sum=np.zeros((m, 9), dtype=np.float32),
            patch_n=np.zeros(m),
        )


def _accumulate_view(
    acc: _ChunkSums,
    views: ViewData,
    v: View,
    p: np.ndarray,
    fused_of: dict[int, np.ndarray] | None,
    tolerance: float,
) -> None:
    """Add view ``v``'s depth comparison (frustum points) and photo samples (fusing points) for points ``p`` (M, 3)."""
    cam = views.cameras.camera_of(v)
    uv, z = views.cameras.project(v, p)
    col, row = uv[:, 0], uv[:, 1]
    inside = (z > 0) & (col >= 0) & (row >= 0) & (col < cam.width) & (row < cam.height)
    if not inside.any():
        return
    idx = np.flatnonzero(inside)
    acc.n_frustum[idx] += 1
    depth = views.depth(v.name)
    rel = d = None
    if depth is not None:
        rel, d = _compare_depth(acc, depth, cam, col, row, z, idx, tolerance)
    if fused_of is not None:
        fused = fused_of[v.image_id]
        fused = fused[inside[fused]]
    elif rel is not None:
        fused = idx[(d > 0) & (np.abs(rel) <= tolerance)]
    else:
        fused = idx
    if len(fused) == 0:
        return
    if rel is not None:
        # Residuals of the fusing views (positions of `fused` inside `idx`).
        pos = np.searchsorted(idx, fused)
        r_abs = np.minimum(np.abs(rel[pos]), 1.0)
        ok = np.isfinite(r_abs) & (d[pos] > 0)
        acc.residual_sum[fused[ok]] += r_abs[ok]
        acc.residual_n[fused[ok]] += 1
    acc.n_fused[fused] += 1
    _accumulate_photo(acc, views.image(v.name), cam, col[fused], row[fused], fused)
    ray = p[fused] - v.center
    acc.ray_sum[fused] += ray / np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-12)


def _compare_depth(
    acc: _ChunkSums,
    depth: np.ndarray,
    cam: Camera,
    col: np.ndarray,
    row: np.ndarray,
    z: np.ndarray,
    idx: np.ndarray,
    tolerance: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Count agree / free-space / invalid for the frustum points ``idx``; returns their relative depth difference
    (d_map − z) / z and the depth-map value d_map (metres, ≤ 0 invalid), both aligned with ``idx``."""
    sx, sy = depth.shape[1] / cam.width, depth.shape[0] / cam.height
    d = sample_nearest(depth, col[idx] * sx, row[idx] * sy).astype(np.float64)
    zi = z[idx]
    rel = (d - zi) / zi
    valid = d > 0
    acc.invalid[idx] += ~valid
    acc.agree[idx] += valid & (np.abs(rel) <= tolerance)
    acc.freespace[idx] += valid & (rel > tolerance)
    return rel, d


def _accumulate_photo(
    acc: _ChunkSums, photo: np.ndarray, cam: Camera, col: np.ndarray, row: np.ndarray, fused: np.ndarray
) -> None:
    """Add the colour and the normalised grey patch at pixels (col, row) (camera pixels) to the points ``fused``."""
    sx, sy = photo.shape[1] / cam.width, photo.shape[0] / cam.height
    fc, fr = col * sx, row * sy
    rgb = sample_nearest(photo, fc, fr).astype(np.float64) / 255.0
    acc.col_sum[fused] += rgb
    acc.col_sq[fused] += rgb**2
    grey = photo.astype(np.float32).mean(axis=2) / 255.0 if photo.ndim == 3 else photo / 255.0
    patches = _grey_patches(grey, fc, fr)
    acc.patch_sum[fused] += patches
    acc.patch_n[fused] += np.linalg.norm(patches, axis=1) > 0


def _finish_chunk(out: dict[str, np.ndarray], acc: _ChunkSums, sl: slice, counts: np.ndarray | None) -> None:
    """Write the features of the chunk ``sl`` from its sums; ``counts``: visibility list lengths (N,) or None."""
    n_fused, n_frustum = acc.n_fused, acc.n_frustum
    safe_f = np.maximum(n_fused, 1)
    safe_v = np.maximum(n_frustum, 1)
    var = np.maximum(acc.col_sq / safe_f[:, None] - (acc.col_sum / safe_f[:, None]) ** 2, 0.0)
    mean_ray = np.linalg.norm(acc.ray_sum, axis=1) / safe_f
    out["n_views"][sl] = n_fused if counts is None else counts[sl]
    out["view_ratio"][sl] = np.minimum(n_fused / safe_v, 1.0)
    out["triangulation_spread_deg"][sl] = np.where(
        n_fused > 1, 2.0 * np.degrees(np.arccos(np.clip(mean_ray, 0.0, 1.0))), 0.0
    )
    out["color_std_views"][sl] = np.sqrt(var).mean(axis=1)
    # Mean NCC of each view's normalised patch with the views' mean patch = ||sum of patches|| / n.
    out["ncc_views"][sl] = np.linalg.norm(acc.patch_sum, axis=1) / np.maximum(acc.patch_n, 1)
    out["depth_agree"][sl] = acc.agree / safe_v
    out["depth_freespace"][sl] = acc.freespace / safe_v
    out["depth_invalid"][sl] = acc.invalid / safe_v
    out["depth_residual"][sl] = np.where(acc.residual_n > 0, acc.residual_sum / np.maximum(acc.residual_n, 1), 1.0)
