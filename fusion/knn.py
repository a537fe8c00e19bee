"""Exact k-nearest-neighbour distances for whole point clouds, fast on few cores.

Why by hand: scipy's ``cKDTree`` (the reference, see :func:`knn_kdtree`) spends ~0.4–0.9 µs per point on 2 cores for
k = 1–8 even when queried in leaf order, which caps the conversion at ~1 M points/s. MVS clouds are surfaces
sampled at a roughly known spacing, so a column grid does better: points are bucketed into square (x, y) columns of
side ``h`` (a counting sort, O(N)), sorted by z inside each column, and each point scans the 3×3 neighbouring columns
within a z window of ±r. The search is exact: a point at distance ≤ r lies in a column within ⌈r/h⌉ and in the z
window, so rings of columns are added (r = h, 2h, 3h, …) until the k-th best distance is ≤ r (isolated outliers just
take more rings). Memory: the column table (≤ ``max_columns_per_point`` · N int64) plus a sorted copy of the
points, O(N).

The grid covers a robust box (0.1–99.9 % per axis); points beyond it are clamped into the border columns, which
keeps the search exact (the edge distance r only uses inner block edges). Points that would need more than
``_RING_BUDGET`` rings (far outliers) are finished by a k-d tree, and a cloud whose columns would be badly
overfilled (dense clusters far apart) goes to the k-d tree whole. ``h`` is chosen from the box and N assuming a
2.5-D surface, then refined once from the measured column occupancy; a bad guess only costs time, never exactness.
Tests compare against brute force and ``cKDTree``.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

from core.errors import DataError


def _target_per_column(k: int) -> float:
    """Points per occupied column for a k-NN query (1.75 for k = 1, 3.5 for k = 8: fastest in a sweep on a terrain
    cloud, measured on a loaded 2-core machine; flat between 2.5 and 3.5 for k = 8)."""
    return 1.5 + 0.25 * k


def knn_kdtree(positions: np.ndarray, k: int, workers: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """Reference: (N, k) distances (float64, ascending) and indices (int64) of the k nearest other points."""
    positions = np.asarray(positions, dtype=np.float64)
    tree = cKDTree(positions, leafsize=16, balanced_tree=False, compact_nodes=False)
    order = tree.indices  # leaf order: spatially coherent queries run ~4× faster than input order
    d, i = tree.query(positions[order], k=k + 1, workers=workers)
    dist = np.empty((len(positions), k))
    idx = np.empty((len(positions), k), dtype=np.int64)
    dist[order], idx[order] = drop_self(d, i, order)
    return dist, idx


def drop_self(d: np.ndarray, i: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """From (M, k+1) k-d tree results of the points ``rows``, the (M, k) neighbours other than the point itself.

    With duplicates the point need not come first (all hits are at distance 0), so its own index is removed
    wherever it appears (the last column when it does not appear at all)."""
    m, k1 = i.shape
    own = i == np.asarray(rows)[:, None]
    drop = np.where(own.any(axis=1), own.argmax(axis=1), k1 - 1)
    keep = np.ones((m, k1), dtype=bool)
    keep[np.arange(m), drop] = False
    return d[keep].reshape(m, k1 - 1), i[keep].reshape(m, k1 - 1)


def knn_grid(positions: np.ndarray, k: int, max_columns_per_point: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """Exact (N, k) distances (float64, metres, ascending) and indices (int64) of each point's k nearest *others*.

    ``positions``: (N, 3) float64 local coordinates, N > k, finite. Exact duplicates appear at distance 0. Ties
    between equidistant neighbours may pick different indices than :func:`knn_kdtree`; distances are identical.
    """
    p = _checked(positions, k)
    grid = _build(p, k, max_columns_per_point)
    if grid is None:
        return knn_kdtree(p, k)
    dist, idx, _, unresolved = _query(*grid.args(), k, True, _RING_BUDGET)
    rows = np.flatnonzero(unresolved)
    if len(rows):
        dist[rows], idx[rows] = _kdtree_rows(p, rows, k)
    return dist, idx


def knn_grid_summary(
    positions: np.ndarray, k: int, max_columns_per_point: float = 4.0
) -> tuple[np.ndarray, np.ndarray]:
    """Per point, without the (N, k) arrays: the nearest-other distance (N,) and the median of the k nearest
    distances that are not exact duplicates (N,; 0 when all k are duplicates), float64 metres. Same search as
    :func:`knn_grid` (exact); memory O(N)."""
    p = _checked(positions, k)
    grid = _build(p, k, max_columns_per_point)
    if grid is None:
        dist, _ = knn_kdtree(p, k)
        return dist[:, 0].copy(), median_nonzero(dist)
    _, _, summary, unresolved = _query(*grid.args(), k, False, _RING_BUDGET)
    rows = np.flatnonzero(unresolved)
    if len(rows):
        dist, _ = _kdtree_rows(p, rows, k)
        summary[rows, 0] = dist[:, 0]
        summary[rows, 1] = median_nonzero(dist)
    return summary[:, 0], summary[:, 1]


def median_nonzero(dist: np.ndarray) -> np.ndarray:
    """Median of each row's non-zero distances ((N, k), rows ascending); 0 where every entry is 0."""
    n, k = dist.shape
    zeros = np.count_nonzero(dist <= 0.0, axis=1)
    valid = k - zeros
    rows = np.arange(n)
    lo = np.minimum(zeros + (valid - 1) // 2, k - 1)
    hi = np.minimum(zeros + valid // 2, k - 1)
    med = 0.5 * (dist[rows, lo] + dist[rows, hi])
    med[valid == 0] = 0.0
    return med


_RING_BUDGET = 3
"""Rings of columns a point may search before it is handed to the k-d tree (isolated outliers)."""

_MAX_SCAN_FACTOR = 40.0
"""Fall back to the k-d tree when the grid would scan more than this × the target candidates per point (clouds
made of far-apart dense clusters, where no single column size suits all)."""


def _checked(positions: np.ndarray, k: int) -> np.ndarray:
    p = np.asarray(positions, dtype=np.float64)
    n = len(p)
    if k < 1 or n <= k:
        raise DataError(f"{k} nearest neighbours need k >= 1 and more than k points, got {n}")
    if not np.isfinite(p).all():
        raise DataError("k nearest neighbours need finite coordinates")
    return p


def _kdtree_rows(p: np.ndarray, rows: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact k nearest others of the points ``rows`` from a k-d tree over all points."""
    tree = cKDTree(p, leafsize=16, balanced_tree=False, compact_nodes=False)
    d, i = tree.query(p[rows], k=k + 1, workers=-1)
    return drop_self(d, i, rows)


def _build(p: np.ndarray, k: int, max_columns_per_point: float) -> _Grid | None:
    """The column grid for ``p``, or None when a k-d tree will do better (see ``_MAX_SCAN_FACTOR``)."""
    n = len(p)
    # Grid geometry from a robust box (0.1–99.9 % per axis on a sample): far outliers are clamped into the
    # border columns (still exact, see _query) instead of stretching the grid over empty space.
    sample = p if n <= 100_000 else p[np.random.default_rng(0).integers(0, n, 100_000)]
    lo_r, hi_r = np.percentile(sample, [0.1, 99.9], axis=0)
    axes = np.argsort(-(hi_r - lo_r), kind="stable")  # columns span the two largest extents
    if not (axes == [0, 1, 2]).all():
        p = np.ascontiguousarray(p[:, axes])
        lo_r, hi_r = lo_r[axes], hi_r[axes]
    lo = lo_r
    extent = np.maximum(hi_r - lo_r, 1e-12)
    h = _choose_cell(extent, n, k, max_columns_per_point)
    grid = _Grid(p, lo, extent, h)
    target = _target_per_column(k)
    occupancy = n / max(grid.occupied, 1)
    if occupancy > 4 * target or occupancy < target / 4:  # refine once from the measured occupancy
        h2 = max(h * np.sqrt(target / occupancy), _min_cell(extent, n, max_columns_per_point))
        if not np.isclose(h2, h, rtol=0.25):
            grid = _Grid(p, lo, extent, h2)
    if grid.scan_per_point > _MAX_SCAN_FACTOR * 9 * target:
        return None
    return grid


def _choose_cell(extent: np.ndarray, n: int, k: int, max_columns_per_point: float) -> float:
    area = float(extent[0] * extent[1])
    target = _target_per_column(k)
    h = np.sqrt(area * target / n)  # a 2.5-D surface filling the box: `target` points per column
    return float(max(h, _min_cell(extent, n, max_columns_per_point)))


def _min_cell(extent: np.ndarray, n: int, max_columns_per_point: float) -> float:
    """Smallest h keeping (e0/h + 1)(e1/h + 1) ≤ max_columns_per_point · n + 1 (each term ≤ a third of it)."""
    budget = max_columns_per_point * n / 3.0
    e0, e1 = float(extent[0]), float(extent[1])
    return max(np.sqrt(e0 * e1 / budget), (e0 + e1) / budget, 1e-12)


class _Grid:
    """Points counting-sorted into (x, y) columns of side h (row-major), z-sorted inside each column."""

    def __init__(self, p: np.ndarray, lo: np.ndarray, extent: np.ndarray, h: float) -> None:
        self.h = float(h)
        self.nx = int(extent[0] // h) + 1
        self.ny = int(extent[1] // h) + 1
        # border columns take every point beyond the box (the search stays exact: see _query)
        cx = np.clip(np.floor((p[:, 0] - lo[0]) / h), 0, self.nx - 1).astype(np.int64)
        cy = np.clip(np.floor((p[:, 1] - lo[1]) / h), 0, self.ny - 1).astype(np.int64)
        col = cx * self.ny + cy
        counts = np.bincount(col, minlength=self.nx * self.ny)
        self.occupied = int(np.count_nonzero(counts))
        # rough candidates scanned per point: each point of a column scans ~9 columns like its own
        self.scan_per_point = 9.0 * float(np.dot(counts, counts.astype(np.float64))) / max(len(p), 1)
        self.col_start = np.zeros(self.nx * self.ny + 1, dtype=np.int64)
        np.cumsum(counts, out=self.col_start[1:])
        self.order = _counting_order(col, self.col_start, p[:, 2])
        self.sorted_xyz = np.ascontiguousarray(p[self.order])
        self.lo = (float(lo[0]), float(lo[1]))
        # slack for the rounding of column assignment: relative to h and to the coordinates' magnitude
        self.guard = 1e-9 * self.h + 16 * float(np.spacing(np.abs(p[:, :2]).max() + self.h * (self.nx + self.ny)))

    def args(self) -> tuple:
        return (
            self.sorted_xyz,
            self.order,
            self.col_start,
            self.nx,
            self.ny,
            self.h,
            self.lo[0],
            self.lo[1],
            self.guard,
        )


@numba.njit(cache=True)
def _counting_order(col: np.ndarray, col_start: np.ndarray, z: np.ndarray) -> np.ndarray:
    n = len(col)
    fill = col_start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = col[i]
        order[fill[c]] = i
        fill[c] += 1
    # insertion sort by z inside each column (columns hold a handful of points)
    ncol = len(col_start) - 1
    for c in range(ncol):
        a, b = col_start[c], col_start[c + 1]
        if b - a > 32:
            seg = order[a:b].copy()
            order[a:b] = seg[np.argsort(z[seg], kind="mergesort")]
            continue
        for j in range(a + 1, b):
            v = order[j]
            zv = z[v]
            m = j - 1
            while m >= a and z[order[m]] > zv:
                order[m + 1] = order[m]
                m -= 1
            order[m + 1] = v
    return order


@numba.njit(cache=True, inline="always")
def _lower_bound(zs: np.ndarray, a: int, b: int, value: float) -> int:
    while a < b:
        m = (a + b) >> 1
        if zs[m] < value:
            a = m + 1
        else:
            b = m
    return a


@numba.njit(parallel=True, cache=True)
def _query(
    xyz: np.ndarray,
    order: np.ndarray,
    col_start: np.ndarray,
    nx: int,
    ny: int,
    h: float,
    lox: float,
    loy: float,
    guard: float,
    k: int,
    full: bool,
    ring_budget: int,
):
    """Distances and input-order indices of the k nearest others (``full``), or per point the nearest distance and
    the median non-duplicate distance (``summary``), written at each point's input position. Points that would need
    more than ``ring_budget`` rings are flagged in ``unresolved`` (input order) and left for the caller."""
    n = len(xyz)
    unresolved = np.zeros(n, dtype=np.bool_)
    dist = np.empty((n if full else 0, k))
    idx = np.empty((n if full else 0, k), dtype=np.int64)
    summary = np.empty((0 if full else n, 2))
    zs = np.ascontiguousarray(xyz[:, 2])
    zext = zs.max() - zs.min() if n else 0.0
    max_ring = max(nx, ny, int(np.ceil(zext / h)) + 1)  # by then the window covers every point
    for cx in numba.prange(nx):
        best_d = np.empty(k)
        best_i = np.empty(k, dtype=np.int64)
        for cy in range(ny):
            c = cx * ny + cy
            for i in range(col_start[c], col_start[c + 1]):
                x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
                for j in range(k):
                    best_d[j] = np.inf
                    best_i[j] = -1
                ring = 1
                scanned = 0  # rings fully scanned so far
                while True:
                    # rescan everything when the block grew (simple and still exact; most points need one pass)
                    if scanned > 0:
                        for j in range(k):
                            best_d[j] = np.inf
                            best_i[j] = -1
                    x0, x1 = max(cx - ring, 0), min(cx + ring, nx - 1)
                    y0, y1 = max(cy - ring, 0), min(cy + ring, ny - 1)
                    # r: distance from the point to the nearest edge of the block of columns (>= ring·h; sides
                    # at the grid's edge have nothing beyond), less a hair for the rounding of column assignment.
                    # Every point within r lies in the block; the z window is ±r as well.
                    r = np.inf
                    if x0 > 0:
                        r = min(r, x - (lox + x0 * h))
                    if x1 < nx - 1:
                        r = min(r, lox + (x1 + 1) * h - x)
                    if y0 > 0:
                        r = min(r, y - (loy + y0 * h))
                    if y1 < ny - 1:
                        r = min(r, loy + (y1 + 1) * h - y)
                    r = ring * h if r == np.inf else r - guard
                    for ux in range(x0, x1 + 1):
                        for uy in range(y0, y1 + 1):
                            cc = ux * ny + uy
                            a, b = col_start[cc], col_start[cc + 1]
                            if a == b:
                                continue
                            s = _lower_bound(zs, a, b, z - r)
                            for m in range(s, b):
                                zm = zs[m]
                                if zm > z + r:
                                    break
                                if m == i:
                                    continue
                                dx = xyz[m, 0] - x
                                dy = xyz[m, 1] - y
                                dz = zm - z
                                d2 = dx * dx + dy * dy + dz * dz
                                if d2 < best_d[k - 1]:
                                    q = k - 1
                                    while q > 0 and best_d[q - 1] > d2:
                                        best_d[q] = best_d[q - 1]
                                        best_i[q] = best_i[q - 1]
                                        q -= 1
                                    best_d[q] = d2
                                    best_i[q] = m
                    scanned = ring
                    if best_d[k - 1] <= r * r or ring >= max_ring:
                        break
                    # jump straight to the ring that can hold the current k-th candidate (if any was found)
                    if best_d[k - 1] < np.inf:
                        need = int(np.ceil(np.sqrt(best_d[k - 1]) / h))
                        ring = max(ring + 1, need)
                    else:
                        ring = ring * 2
                    ring = min(ring, max_ring)
                    if ring > ring_budget:
                        break
                o = order[i]
                if ring > ring_budget and not (best_d[k - 1] <= r * r):
                    unresolved[o] = True
                    continue
                if full:
                    for j in range(k):
                        dist[o, j] = np.sqrt(best_d[j])
                        idx[o, j] = order[best_i[j]]
                else:
                    zeros = 0
                    while zeros < k and best_d[zeros] <= 0.0:
                        zeros += 1
                    summary[o, 0] = np.sqrt(best_d[0])
                    if zeros == k:
                        summary[o, 1] = 0.0
                    else:
                        valid = k - zeros
                        lo_ = zeros + (valid - 1) // 2
                        hi_ = zeros + valid // 2
                        summary[o, 1] = 0.5 * (np.sqrt(best_d[lo_]) + np.sqrt(best_d[hi_]))
    return dist, idx, summary, unresolved
