"""Fusion evidence: does each fused point sit where the depth maps that made it, and its neighbours, say it should?

MVS fusion averages the back-projected pixels of several depth maps into one point. On collaborative surfaces the
views agree and the point lies on the surface its neighbours describe. Mirrors, glass and shiny or thin objects
make depth maps that disagree (each view "sees" a different virtual surface) and fused points that hover in front
of or behind the surface around them. Three features measure this, per point, over the views that fused it
(``PointCloud.visibility``; held-out photos never take part):

``fusion_backproj_dist`` (1: point spacings)
    For each fusing view with a valid depth ``d`` at the point's projection (nearest pixel), the back-projection
    ``X_i = C_i + (P − C_i) d / z`` of that depth along the view's ray through the point; the mean of ``|X_i − P|``
    over those views, divided by the cloud's median point spacing, capped at :data:`DIST_CAP`. Neutral (no fusing
    view with a valid depth): the cap, as ``depth_residual`` counts a point no depth map supports as inconsistent.
``fusion_reproj_px`` (px)
    The RMS, over ordered pairs (i, j ≠ i) of fusing views (i with a valid depth), of the pixel offset in view j
    between the projections of ``X_i`` and of ``P``: how far view i's depth moves the point in the other photos.
    The projection is linearised at ``P`` (``J_j (X_i − P)``, J_j the 2 × 3 pinhole Jacobian of view j): with
    ``S = Σ_i δ_i δ_iᵀ`` and ``Q = Σ_j J_jᵀ J_j`` the pair sum is ``tr(S Q) − Σ_i |J_i δ_i|²``, one pass over the
    views (no pairs). Capped at :data:`REPROJ_CAP`; neutral (no pair): the cap.
``fusion_plane_offset`` (1: point spacings, signed)
    The distance from the point, along the mean unit viewing ray of its fusing views, to the PCA plane (through
    the centroid, normal = smallest eigenvector) of its k − 1 nearest *other* points: positive when the plane lies
    beyond the point (the point hovers in front of the surface, towards the cameras), negative when behind.
    ``|n · ray|`` is floored at :data:`MIN_COS` (grazing rays), the result divided by the spacing and clipped to
    ±:data:`OFFSET_CAP`. Neutral (no fusing view: no ray): 0.

Work is chunked over points (outer) and views (inner), as the multi-view group; the neighbour lists are those
of the finest geometric neighbourhood (:attr:`~classify.features.FeatureTable.neighbours`) when given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from classify.features.fusing import FusingSamples, fusing_chunks
from classify.features.multiview import MultiViewOptions, ViewData
from core.errors import DataError

FUSION_NAMES = ("fusion_backproj_dist", "fusion_reproj_px", "fusion_plane_offset")
DIST_CAP = 50.0  # point spacings
REPROJ_CAP = 50.0  # pixels
OFFSET_CAP = 50.0  # point spacings
MIN_COS = 0.1  # floor of |n · ray| (rays within ~84° of the plane's normal keep their exact offset)


@dataclass
class _FusionSums:
    """Per-point sums over the fusing views of one chunk of M points (float64)."""

    dist_sum: np.ndarray  # (M,) |X_i − P| (metres) over the views with a valid depth
    n_valid: np.ndarray  # (M,) views with a valid depth
    n_fused: np.ndarray  # (M,) fusing views (in the image, z > 0)
    s: np.ndarray  # (M, 3, 3) Σ δ_i δ_iᵀ (m²)
    q: np.ndarray  # (M, 3, 3) Σ J_jᵀ J_j (px² / m²)
    self_sq: np.ndarray  # (M,) Σ |J_i δ_i|² (px²) over the views with a valid depth
    ray_sum: np.ndarray  # (M, 3) unit viewing rays

    @classmethod
    def zeros(cls, m: int) -> _FusionSums:
        return cls(
            np.zeros(m),
            np.zeros(m),
            np.zeros(m),
            np.zeros((m, 3, 3)),
            np.zeros((m, 3, 3)),
            np.zeros(m),
            np.zeros((m, 3)),
        )


def fusion_features(
    positions: np.ndarray,
    visibility: list[np.ndarray] | None,
    views: ViewData,
    spacing: float,
    neighbours: np.ndarray | None = None,
    options: MultiViewOptions = MultiViewOptions(),
    k: int = 16,
) -> dict[str, np.ndarray]:
    """The features of :data:`FUSION_NAMES`, each (N,) float32 and finite, for points (N, 3) float64 (metres, the
    cameras' local frame).

    visibility: per point, the image ids that fused it (None: the frustum views whose depth map agrees within
    ``options.depth_tolerance``). spacing: the cloud's median point spacing (metres, > 0). neighbours: (N, m) int64,
    each point's nearest other points (row indices); None searches the ``k − 1`` nearest. options: chunking.
    """
    pts = np.asarray(positions, dtype=np.float64)
    n = len(pts)
    if not spacing > 0 or not np.isfinite(spacing):
        raise DataError(f"fusion features need a positive point spacing, got {spacing}")
    if neighbours is None:
        neighbours = _neighbours(pts, k)
    elif len(neighbours) != n:
        raise DataError(f"neighbour lists for {len(neighbours)} points, the cloud has {n}")
    out = {name: np.zeros(n, dtype=np.float32) for name in FUSION_NAMES}
    for sl, samples in fusing_chunks(pts, visibility, views, options.chunk_size, options.depth_tolerance):
        p = pts[sl]
        acc = _FusionSums.zeros(len(p))
        for s in samples:
            _accumulate_view(acc, views, s, p)
        _finish_chunk(out, acc, sl, spacing)
        offset = plane_offset(pts, neighbours[sl], p, acc.ray_sum)
        out["fusion_plane_offset"][sl] = np.clip(offset / spacing, -OFFSET_CAP, OFFSET_CAP)
    return out


def _neighbours(pts: np.ndarray, k: int) -> np.ndarray:
    from classify.features.geometric import GeometricOptions, level_neighbours

    if len(pts) < 2:
        return np.zeros((len(pts), 0), dtype=np.int64)
    return level_neighbours(pts, k, GeometricOptions(k=max(3, k)))[1]


def pinhole_jacobian(s: FusingSamples) -> tuple[np.ndarray, np.ndarray]:
    """The two rows (S, 3) float64 each of d(pixel) / d(local point) of the view's pinhole projection at the
    samples (px / m): d(col) = fx / z (R_0 − x / z R_2), d(row) = fy / z (R_1 − y / z R_2), with R the view's rotation
    and (x, y, z) the samples in its camera frame."""
    fx, fy = s.camera.focal
    r = s.view.rotation
    z = s.z
    j0 = (fx / z)[:, None] * (r[0] - (s.cam_pts[:, 0] / z)[:, None] * r[2])
    j1 = (fy / z)[:, None] * (r[1] - (s.cam_pts[:, 1] / z)[:, None] * r[2])
    return j0, j1


def _accumulate_view(acc: _FusionSums, views: ViewData, s: FusingSamples, p: np.ndarray) -> None:
    """Add one view's back-projection evidence to the sums of the chunk's points ``p`` (M, 3)."""
    j0, j1 = pinhole_jacobian(s)
    acc.n_fused[s.idx] += 1
    acc.q[s.idx] += j0[:, :, None] * j0[:, None, :] + j1[:, :, None] * j1[:, None, :]
    acc.ray_sum[s.idx] += s.ray
    depth = views.depth(s.view.name)
    if depth is None:
        return
    d = s.sample(depth).astype(np.float64)
    ok = (d > 0) & np.isfinite(d)
    if not ok.any():
        return
    idx, z = s.idx[ok], s.z[ok]
    # X_i − P = (P − C)(d / z − 1): the depth map's point on the same ray.
    delta = (p[idx] - s.view.center) * (d[ok] / z - 1.0)[:, None]
    acc.dist_sum[idx] += np.sqrt(np.sum(delta * delta, axis=1))
    acc.n_valid[idx] += 1
    acc.s[idx] += delta[:, :, None] * delta[:, None, :]
    acc.self_sq[idx] += np.sum(j0[ok] * delta, axis=1) ** 2 + np.sum(j1[ok] * delta, axis=1) ** 2


def _finish_chunk(out: dict[str, np.ndarray], acc: _FusionSums, sl: slice, spacing: float) -> None:
    """Write the back-projection features of the chunk ``sl`` from its sums."""
    has = acc.n_valid > 0
    dist = acc.dist_sum / np.maximum(acc.n_valid, 1) / spacing
    out["fusion_backproj_dist"][sl] = np.where(has, np.minimum(dist, DIST_CAP), DIST_CAP)
    pairs = acc.n_valid * acc.n_fused - acc.n_valid  # ordered (i valid, j fusing, j ≠ i)
    pair_sq = np.maximum(np.einsum("mij,mji->m", acc.s, acc.q) - acc.self_sq, 0.0)
    rms = np.sqrt(pair_sq / np.maximum(pairs, 1))  # NaN only from absurd depths (inf − inf): the cap
    out["fusion_reproj_px"][sl] = np.where((pairs > 0) & ~np.isnan(rms), np.minimum(rms, REPROJ_CAP), REPROJ_CAP)


def plane_offset(points: np.ndarray, neighbours: np.ndarray, p: np.ndarray, ray_sum: np.ndarray) -> np.ndarray:
    """Signed distance (M,) float64 metres from each point of ``p`` (M, 3) along the direction of ``ray_sum``
    (M, 3) to the PCA plane of its neighbours ``points[neighbours]`` ((M, m) int64 rows of ``points`` (N, 3),
    the point itself not among them): positive when the plane lies beyond the point along the ray. 0 where the
    ray sum is zero or there are fewer than 3 neighbours."""
    from classify.features.eigen_numba import eigen_numba

    m = len(p)
    if m == 0 or neighbours.shape[1] < 3:
        return np.zeros(m)
    _, normal = eigen_numba(points, neighbours, with_self=False)
    centroid = points[neighbours].mean(axis=1)
    length = np.linalg.norm(ray_sum, axis=1)
    ray = ray_sum / np.maximum(length, 1e-300)[:, None]
    cos = np.sum(normal * ray, axis=1)
    cos = np.where(cos < 0, -1.0, 1.0) * np.maximum(np.abs(cos), MIN_COS)
    t = np.sum(normal * (centroid - p), axis=1) / cos  # P + t·ray lies on the plane
    return np.where(length > 1e-12, t, 0.0)
