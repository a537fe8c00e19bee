"""Exact k-nearest-neighbour distances for whole point clouds, fast on few cores (``fusion.knn`` is an alias).

Why by hand: scipy's ``cKDTree`` (the reference, see :func:`knn_kdtree`) spends ~0.4–0.9 µs per point on 2 cores for
k = 1–8 even when queried in leaf order, and its build alone takes seconds at 10 M points, which caps the conversion
at ~1 M points/s. MVS clouds are surfaces sampled at a roughly known spacing, so a column grid does better: points
are bucketed into square (x, y) columns of side ``h`` (a counting sort, O(N)), sorted by z inside each column, and
each point scans the 3×3 neighbouring columns within a z window of ±r. The search is exact: a point at distance ≤ r
lies in a column within ⌈r/h⌉ and in the z window, so rings of columns are added (r = h, 2h, 3h, …) until the k-th
best distance is ≤ r. Ring 1 is done per column: the 3×3 neighbourhood is gathered once (when it holds at most
``_GATHER_CAP`` points; steep or dense spots keep the z-windowed per-point scan) and each point of the column takes
its k best among the gathered points within its r (branch-free filter, then insertion); a point whose k-th best is
not within r falls back to the per-point ring scan. Points that would need more than ``_RING_BUDGET`` rings
(isolated outliers) switch to a two-level search over blocks of ``_BLOCK``×``_BLOCK`` columns, each with its z
range: blocks are visited ring by ring and pruned (with their columns) by the distance to their bounding box,
which is exact and stays cheap however far the outlier is. Memory: the column table (≤ ``max_columns_per_point`` ·
N int64), a sorted copy of the points and one column key per point, O(N).

The grid covers a robust box (0.1–99.9 % per axis); points beyond it are clamped into the border columns, which
keeps the search exact (border columns and blocks are unbounded outwards). A cloud whose columns would be badly
overfilled (dense clusters far apart) goes to the k-d tree whole. ``h`` is chosen from the box and N assuming a
2.5-D surface, then refined once from the measured column occupancy; a bad guess only costs time, never exactness.
Work is split over Python threads running GIL-free numba kernels on interleaved ranges of column rows (waiting
threads block instead of spinning, which matters on shared cores; see ``fusion/render/cpu.py``).
Tests compare against brute force and ``cKDTree``.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

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
    dist, idx, _, _ = _query(grid, k, True)
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
    _, _, summary, _ = _query(grid, k, False)
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
"""Rings of columns a point may search before it switches to the block search (isolated outliers)."""

_BLOCK = 8
"""Columns per side of the blocks (with their z range) of the outliers' search."""

_MAX_SCAN_FACTOR = 40.0
"""Fall back to the k-d tree when the grid would scan more than this × the target candidates per point (clouds
made of far-apart dense clusters, where no single column size suits all)."""

_CHUNKS_PER_THREAD = 16
"""Interleaved work chunks per thread (balances uneven columns without a scheduler)."""


def _checked(positions: np.ndarray, k: int) -> np.ndarray:
    p = np.ascontiguousarray(positions, dtype=np.float64)
    n = len(p)
    if k < 1 or n <= k:
        raise DataError(f"{k} nearest neighbours need k >= 1 and more than k points, got {n}")
    if p.ndim != 2 or p.shape[1] != 3:
        raise DataError(f"k nearest neighbours need (N, 3) positions, got shape {p.shape}")
    if not _all_finite(p):
        raise DataError("k nearest neighbours need finite coordinates")
    return p


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
    col, counts, nx, ny = _columns(p, lo, extent, h)
    target = _target_per_column(k)
    occupancy = n / max(int(np.count_nonzero(counts)), 1)
    if occupancy > 4 * target or occupancy < target / 4:  # refine once from the measured occupancy
        h2 = max(h * np.sqrt(target / occupancy), _min_cell(extent, n, max_columns_per_point))
        if not np.isclose(h2, h, rtol=0.25):
            h = h2
            col, counts, nx, ny = _columns(p, lo, extent, h)
    # rough candidates scanned per point: each point of a column scans ~9 columns like its own
    scan_per_point = 9.0 * float(np.dot(counts, counts.astype(np.float64))) / n
    if scan_per_point > _MAX_SCAN_FACTOR * 9 * target:
        return None
    col_start = np.zeros(nx * ny + 1, dtype=np.int64)
    np.cumsum(counts, out=col_start[1:])
    order = _scatter(col, col_start)
    del col  # the keys are not needed any more (N int64)
    return _Grid(p, lo, h, nx, ny, col_start, order)


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


def _columns(p: np.ndarray, lo: np.ndarray, extent: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Row-major column key (N,) int64 of each point (clamped into the border columns), counts per column, nx, ny."""
    nx = int(extent[0] // h) + 1
    ny = int(extent[1] // h) + 1
    col = np.empty(len(p), dtype=np.int64)
    run_threads(_assign, (p, float(lo[0]), float(lo[1]), float(h), nx, ny, col), numba.get_num_threads())
    return col, np.bincount(col, minlength=nx * ny), nx, ny


class _Grid:
    """Points counting-sorted into (x, y) columns of side h (row-major), z-sorted inside each column, plus the z range
    of each block of ``_BLOCK``×``_BLOCK`` columns."""

    def __init__(
        self, p: np.ndarray, lo: np.ndarray, h: float, nx: int, ny: int, col_start: np.ndarray, order: np.ndarray
    ) -> None:
        self.h = float(h)
        self.nx, self.ny = nx, ny
        self.col_start = col_start  # (nx·ny + 1,) int64: column c holds sorted points col_start[c]:col_start[c+1]
        self.order = order  # (N,) int64: input index of each sorted point (z-sorted below)
        # gather the points column by column and sort each column by z (threads over interleaved column chunks)
        self.sorted_xyz = np.empty_like(p)
        nth = numba.get_num_threads()
        chunk = max(1, (nx * ny) // (nth * _CHUNKS_PER_THREAD) + 1)
        run_threads(_gather_sorted, (p, self.order, self.col_start, chunk, self.sorted_xyz), nth)
        self.lo = (float(lo[0]), float(lo[1]))
        self.nbx = (nx + _BLOCK - 1) // _BLOCK
        self.nby = (ny + _BLOCK - 1) // _BLOCK
        self.bzmin, self.bzmax = _block_bounds(self.sorted_xyz, self.col_start, nx, ny, _BLOCK, self.nbx, self.nby)
        # slack for the rounding of column assignment: relative to h and to the coordinates' magnitude
        self.guard = 1e-9 * self.h + 16 * float(np.spacing(_max_abs_xy(p) + self.h * (nx + ny)))


_POOL: list[ThreadPoolExecutor] = []


def run_threads(kernel: Callable[..., None], args: tuple, n: int) -> None:
    """Run ``kernel(*args, th, n)`` for th in 0..n-1 on n Python threads (GIL-free kernels; blocking, not spinning,
    when the cores are shared: the pattern of ``fusion/render/cpu.py``)."""
    if n <= 1:
        kernel(*args, 0, 1)
        return
    if not _POOL or _POOL[0]._max_workers < n:
        _POOL[:] = [ThreadPoolExecutor(max_workers=n, thread_name_prefix="knn")]
    for future in [_POOL[0].submit(kernel, *args, th, n) for th in range(n)]:
        future.result()


def _query(grid: _Grid, k: int, full: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Distances and input-order indices of the k nearest others (``full``: (N, k) each), or per point the nearest
    distance and the median non-duplicate distance (``summary``: (N, 2)), at each point's input position; also
    the number of points that needed the block search (outliers)."""
    n = len(grid.sorted_xyz)
    dist = np.empty((n if full else 0, k))
    idx = np.empty((n if full else 0, k), dtype=np.int64)
    summary = np.empty((0 if full else n, 2))
    nth = numba.get_num_threads()
    rows_per_chunk = max(1, grid.nx // (nth * _CHUNKS_PER_THREAD))
    far = np.zeros(nth, dtype=np.int64)
    zs = np.ascontiguousarray(grid.sorted_xyz[:, 2])
    args = (grid.sorted_xyz, zs, grid.order, grid.col_start, grid.nx, grid.ny, grid.h, grid.lo[0], grid.lo[1])
    args += (grid.guard, grid.bzmin, grid.bzmax, grid.nbx, grid.nby, _BLOCK, k, full, _RING_BUDGET)
    args += (dist, idx, summary, far, rows_per_chunk)
    run_threads(_query_rows, args, nth)
    if not full:  # a separate scatter pass is cheaper than random writes inside the search
        out = np.empty_like(summary)
        run_threads(_scatter_rows, (summary, grid.order, out), nth)
        summary = out
    return dist, idx, summary, int(far.sum())


# -- numba kernels ------------------------------------------------------------------------------------


@numba.njit(nogil=True, cache=True)
def _all_finite(p: np.ndarray) -> bool:
    for v in p.ravel():
        if not np.isfinite(v):
            return False
    return True


@numba.njit(nogil=True, cache=True)
def _max_abs_xy(p: np.ndarray) -> float:
    m = 0.0
    for i in range(len(p)):
        m = max(m, abs(p[i, 0]), abs(p[i, 1]))
    return m


@numba.njit(nogil=True, cache=True)
def _assign(p: np.ndarray, lox: float, loy: float, h: float, nx: int, ny: int, col: np.ndarray, th: int, nth: int):
    """Column keys of the points of the th-th of nth contiguous ranges."""
    n = len(p)
    for i in range(th * n // nth, (th + 1) * n // nth):
        cx = min(max(np.floor((p[i, 0] - lox) / h), 0.0), nx - 1.0)
        cy = min(max(np.floor((p[i, 1] - loy) / h), 0.0), ny - 1.0)
        col[i] = int(cx) * ny + int(cy)


@numba.njit(nogil=True, cache=True)
def _scatter(col: np.ndarray, col_start: np.ndarray) -> np.ndarray:
    n = len(col)
    fill = col_start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = col[i]
        order[fill[c]] = i
        fill[c] += 1
    return order


@numba.njit(nogil=True, cache=True)
def _gather_sorted(
    p: np.ndarray, order: np.ndarray, col_start: np.ndarray, chunk: int, out: np.ndarray, th: int, nth: int
) -> None:
    """For the chunks th, th + nth, … of ``chunk`` columns: copy each column's points into ``out`` and sort them
    (with ``order``) by z. Sorting the gathered copy keeps the sort's memory accesses local."""
    ncol = len(col_start) - 1
    for start in range(th * chunk, ncol, nth * chunk):
        for c in range(start, min(start + chunk, ncol)):
            a, b = col_start[c], col_start[c + 1]
            if b - a > 32:
                seg = order[a:b].copy()
                seg = seg[np.argsort(p[seg, 2], kind="mergesort")]
                order[a:b] = seg
                for j in range(a, b):
                    v = seg[j - a]
                    out[j, 0], out[j, 1], out[j, 2] = p[v, 0], p[v, 1], p[v, 2]
                continue
            for j in range(a, b):  # insertion sort: columns hold a handful of points
                v = order[j]
                x, y, z = p[v, 0], p[v, 1], p[v, 2]
                m = j - 1
                while m >= a and out[m, 2] > z:
                    order[m + 1] = order[m]
                    out[m + 1, 0], out[m + 1, 1], out[m + 1, 2] = out[m, 0], out[m, 1], out[m, 2]
                    m -= 1
                order[m + 1] = v
                out[m + 1, 0], out[m + 1, 1], out[m + 1, 2] = x, y, z


@numba.njit(nogil=True, cache=True)
def _block_bounds(xyz: np.ndarray, col_start: np.ndarray, nx: int, ny: int, bs: int, nbx: int, nby: int):
    """z range of each block of bs×bs columns (min > max for an empty block), from the z-sorted columns."""
    bzmin = np.full(nbx * nby, np.inf)
    bzmax = np.full(nbx * nby, -np.inf)
    for cx in range(nx):
        for cy in range(ny):
            c = cx * ny + cy
            a, b = col_start[c], col_start[c + 1]
            if a < b:
                bb = (cx // bs) * nby + cy // bs
                bzmin[bb] = min(bzmin[bb], xyz[a, 2])
                bzmax[bb] = max(bzmax[bb], xyz[b - 1, 2])
    return bzmin, bzmax


@numba.njit(nogil=True, cache=True)
def _scatter_rows(src: np.ndarray, order: np.ndarray, out: np.ndarray, th: int, nth: int) -> None:
    """out[order[i]] = src[i] for the th-th of nth contiguous ranges of i."""
    n = len(order)
    for i in range(th * n // nth, (th + 1) * n // nth):
        o = order[i]
        for j in range(src.shape[1]):
            out[o, j] = src[i, j]


@numba.njit(cache=True, inline="always")
def _lower_bound(zs: np.ndarray, a: int, b: int, value: float) -> int:
    while a < b:
        m = (a + b) >> 1
        if zs[m] < value:
            a = m + 1
        else:
            b = m
    return a


@numba.njit(cache=True, inline="always")
def _insert(best_d: np.ndarray, best_i: np.ndarray, d2: float, m: int) -> None:
    q = len(best_d) - 1
    while q > 0 and best_d[q - 1] > d2:
        best_d[q] = best_d[q - 1]
        best_i[q] = best_i[q - 1]
        q -= 1
    best_d[q] = d2
    best_i[q] = m


@numba.njit(cache=True, inline="always")
def _scan_column(xyz, zs, a, b, i, wz, best_d, best_i) -> float:
    """Offer the points of sorted range [a, b) within ±wz in z of point i (not i itself) to the k best; returns the
    z window shrunk to the k-th best distance when that is smaller."""
    k = len(best_d)
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    s = _lower_bound(zs, a, b, z - wz)
    for m in range(s, b):
        zm = zs[m]
        if zm > z + wz:
            break
        if m == i:
            continue
        dx = xyz[m, 0] - x
        dy = xyz[m, 1] - y
        dz = zm - z
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < best_d[k - 1]:
            _insert(best_d, best_i, d2, m)
            if best_d[k - 1] < wz * wz:
                wz = np.sqrt(best_d[k - 1]) * (1.0 + 1e-12)
    return wz


@numba.njit(cache=True, inline="always")
def _gap(v: float, a: float, b: float, guard: float) -> float:
    """Distance from v to the interval [a, b] less the rounding guard, ≥ 0."""
    return max(a - v - guard, v - b - guard, 0.0)


@numba.njit(nogil=True, cache=True)
def _scan_block(xyz, zs, col_start, nx, ny, h, lox, loy, guard, bs, ux, uy, nbx, nby, i, best_d, best_i):
    """Scan the columns of block (ux, uy) that may hold a point closer to point i than the current k-th best."""
    k = len(best_d)
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    c0x, c1x = ux * bs, min((ux + 1) * bs, nx)
    c0y, c1y = uy * bs, min((uy + 1) * bs, ny)
    for cx in range(c0x, c1x):
        # border columns are unbounded outwards (points beyond the box are clamped into them)
        xa = lox + cx * h if cx > 0 else -np.inf
        xb = lox + (cx + 1) * h if cx < nx - 1 else np.inf
        gx = _gap(x, xa, xb, guard)
        if gx * gx >= best_d[k - 1]:
            continue
        for cy in range(c0y, c1y):
            c = cx * ny + cy
            a, b = col_start[c], col_start[c + 1]
            if a == b:
                continue
            ya = loy + cy * h if cy > 0 else -np.inf
            yb = loy + (cy + 1) * h if cy < ny - 1 else np.inf
            gy = _gap(y, ya, yb, guard)
            gz = _gap(z, zs[a], zs[b - 1], 0.0)
            if gx * gx + gy * gy + gz * gz >= best_d[k - 1]:
                continue
            s = a
            zhi = np.inf
            if best_d[k - 1] < np.inf:
                r = np.sqrt(best_d[k - 1]) * (1.0 + 1e-12)
                s = _lower_bound(zs, a, b, z - r)
                zhi = z + r
            for m in range(s, b):
                zm = zs[m]
                if zm > zhi:
                    break
                if m == i:
                    continue
                dx = xyz[m, 0] - x
                dy = xyz[m, 1] - y
                dz = zm - z
                d2 = dx * dx + dy * dy + dz * dz
                if d2 < best_d[k - 1]:
                    _insert(best_d, best_i, d2, m)
                    if best_d[k - 1] < np.inf:
                        zhi = z + np.sqrt(best_d[k - 1]) * (1.0 + 1e-12)


@numba.njit(nogil=True, cache=True)
def _block_search(xyz, zs, col_start, nx, ny, h, lox, loy, guard, bzmin, bzmax, nbx, nby, bs, i, cx, cy, bd, bi):
    """Exact k nearest others of point i (column cx, cy) into bd (squared, ascending) / bi (sorted indices): blocks
    ring by ring around the point's block, each skipped when its bounding box is farther than the k-th best, until
    everything outside the rings is provably farther."""
    k = len(bd)
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    for j in range(k):
        bd[j] = np.inf
        bi[j] = -1
    bx, by = cx // bs, cy // bs
    ring = 0
    while True:
        for ux in range(max(bx - ring, 0), min(bx + ring, nbx - 1) + 1):
            side = ux == bx - ring or ux == bx + ring
            for uy in range(max(by - ring, 0), min(by + ring, nby - 1) + 1):
                if not side and uy != by - ring and uy != by + ring:
                    continue  # inner blocks were visited in earlier rings
                bb = ux * nby + uy
                if bzmin[bb] > bzmax[bb]:
                    continue
                xa = lox + ux * bs * h if ux > 0 else -np.inf
                xb = lox + (ux + 1) * bs * h if ux < nbx - 1 else np.inf
                ya = loy + uy * bs * h if uy > 0 else -np.inf
                yb = loy + (uy + 1) * bs * h if uy < nby - 1 else np.inf
                gx = _gap(x, xa, xb, guard)
                gy = _gap(y, ya, yb, guard)
                gz = _gap(z, bzmin[bb], bzmax[bb], 0.0)
                if gx * gx + gy * gy + gz * gz >= bd[k - 1]:
                    continue
                _scan_block(xyz, zs, col_start, nx, ny, h, lox, loy, guard, bs, ux, uy, nbx, nby, i, bd, bi)
        # every point outside the rings is at least `edge` away (sides at the grid's border have nothing beyond)
        edge = np.inf
        if bx - ring > 0:
            edge = min(edge, x - (lox + (bx - ring) * bs * h))
        if bx + ring < nbx - 1:
            edge = min(edge, lox + (bx + ring + 1) * bs * h - x)
        if by - ring > 0:
            edge = min(edge, y - (loy + (by - ring) * bs * h))
        if by + ring < nby - 1:
            edge = min(edge, loy + (by + ring + 1) * bs * h - y)
        if edge == np.inf:
            return
        edge -= guard
        if edge > 0 and bd[k - 1] <= edge * edge:
            return
        ring += 1


_GATHER_CAP = 64
"""Most candidates in a column's 3×3 neighbourhood for the gathered brute-force pass (steeper or denser spots use
the z-windowed per-point scan)."""


@numba.njit(cache=True, inline="always")
def _gather_ring1(xyz, col_start, nx, ny, cx, cy, cap, gx, gy, gz, gi) -> int:
    """Copy the points of the columns within one ring of (cx, cy), own column first, into gx, gy, gz (coordinates)
    and gi (sorted indices); returns their count, or 0 when it exceeds ``cap``."""
    x0, x1 = max(cx - 1, 0), min(cx + 1, nx - 1)
    y0, y1 = max(cy - 1, 0), min(cy + 1, ny - 1)
    total = 0
    for ux in range(x0, x1 + 1):
        total += col_start[ux * ny + y1 + 1] - col_start[ux * ny + y0]  # a row of columns is contiguous
    if total > cap:
        return 0
    c = cx * ny + cy
    ng = 0
    for m in range(col_start[c], col_start[c + 1]):
        gx[ng], gy[ng], gz[ng], gi[ng] = xyz[m, 0], xyz[m, 1], xyz[m, 2], m
        ng += 1
    for ux in range(x0, x1 + 1):
        for m in range(col_start[ux * ny + y0], col_start[ux * ny + y1 + 1]):
            if ux == cx and col_start[c] <= m < col_start[c + 1]:
                continue
            gx[ng], gy[ng], gz[ng], gi[ng] = xyz[m, 0], xyz[m, 1], xyz[m, 2], m
            ng += 1
    return ng


@numba.njit(cache=True, inline="always")
def _ring1_from_gathered(xyz, i, own, ng, gx, gy, gz, gi, g2, sel, cx, cy, nx, ny, h, lox, loy, guard, best_d, best_i):
    """The k best of point i (at position ``own`` of the gathered set) among the gathered points; True when that is
    provably exact, i.e. the k-th best is within r, the distance from the point to the edge of its 3×3 block (the
    ring-1 test of the per-point scan, which then finds the same distances). Only candidates within r can then be
    among the k best, so the others are dropped first (branch-free) and fewer than k of them means False."""
    k = len(best_d)
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    x0, x1 = max(cx - 1, 0), min(cx + 1, nx - 1)
    y0, y1 = max(cy - 1, 0), min(cy + 1, ny - 1)
    r = np.inf
    if x0 > 0:
        r = min(r, x - (lox + x0 * h))
    if x1 < nx - 1:
        r = min(r, lox + (x1 + 1) * h - x)
    if y0 > 0:
        r = min(r, y - (loy + y0 * h))
    if y1 < ny - 1:
        r = min(r, loy + (y1 + 1) * h - y)
    r = h if r == np.inf else r - guard
    r2 = r * r
    for m in range(ng):  # same arithmetic as _scan_column: identical distances
        dx = gx[m] - x
        dy = gy[m] - y
        dz = gz[m] - z
        g2[m] = dx * dx + dy * dy + dz * dz
    g2[own] = np.inf
    cnt = 0
    for m in range(ng):
        sel[cnt] = m
        cnt += 1 if g2[m] <= r2 else 0
    if cnt < k:
        return False
    for j in range(k):
        best_d[j] = np.inf
        best_i[j] = -1
    for t in range(cnt):
        m = sel[t]
        if g2[m] < best_d[k - 1]:
            _insert(best_d, best_i, g2[m], gi[m])
    return best_d[k - 1] <= r2


@numba.njit(nogil=True, cache=True)
def _query_rows(
    xyz: np.ndarray,
    zs: np.ndarray,
    order: np.ndarray,
    col_start: np.ndarray,
    nx: int,
    ny: int,
    h: float,
    lox: float,
    loy: float,
    guard: float,
    bzmin: np.ndarray,
    bzmax: np.ndarray,
    nbx: int,
    nby: int,
    bs: int,
    k: int,
    full: bool,
    ring_budget: int,
    dist: np.ndarray,
    idx: np.ndarray,
    summary: np.ndarray,
    far: np.ndarray,
    rows_per_chunk: int,
    th: int,
    nth: int,
) -> None:
    """The k nearest others of the points in column rows [s, s + rows_per_chunk) for s = th·rows_per_chunk, then
    every nth chunk; results at each point's input position (disjoint per thread)."""
    best_d = np.empty(k)
    best_i = np.empty(k, dtype=np.int64)
    zext = zs.max() - zs.min() if len(zs) else 0.0
    max_ring = max(nx, ny, int(np.ceil(zext / h)) + 1)  # by then the window covers every point
    cap = _GATHER_CAP
    qx, qy, qz, q2 = np.empty(cap), np.empty(cap), np.empty(cap), np.empty(cap)
    qi = np.empty(cap, dtype=np.int64)
    qs = np.empty(cap, dtype=np.int64)
    for start in range(th * rows_per_chunk, nx, nth * rows_per_chunk):
        for cx in range(start, min(start + rows_per_chunk, nx)):
            for cy in range(ny):
                c = cx * ny + cy
                if col_start[c] == col_start[c + 1]:
                    continue
                # the column's 3×3 neighbourhood gathered once (own column first) for all its points, when small
                ng = _gather_ring1(xyz, col_start, nx, ny, cx, cy, cap, qx, qy, qz, qi)
                for i in range(col_start[c], col_start[c + 1]):
                    x, y = xyz[i, 0], xyz[i, 1]
                    ring = 1
                    done = False
                    if ng > 0:
                        done = _ring1_from_gathered(
                            xyz, i, i - col_start[c], ng, qx, qy, qz, qi, q2, qs, cx, cy, nx, ny, h, lox, loy, guard,
                            best_d, best_i,
                        )  # fmt: skip
                    while not done:
                        # rescan everything when the block grew (simple and still exact; most points need one pass)
                        for j in range(k):
                            best_d[j] = np.inf
                            best_i[j] = -1
                        x0, x1 = max(cx - ring, 0), min(cx + ring, nx - 1)
                        y0, y1 = max(cy - ring, 0), min(cy + ring, ny - 1)
                        # r: distance from the point to the nearest edge of the block of columns (>= ring·h; sides
                        # at the grid's edge have nothing beyond), less a hair for the rounding of column
                        # assignment. Every point within r lies in the block; the z window is ±r as well.
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
                        # own column first, then outwards, nearer side first (a tight k-th best early, so fewer
                        # insertions); a column is skipped when its (x, y) gap already exceeds the k-th best, and
                        # the z window shrinks with the k-th best
                        wz = _scan_column(xyz, zs, col_start[c], col_start[c + 1], i, r, best_d, best_i)
                        sx = 1 if x - (lox + cx * h) > 0.5 * h else -1
                        sy = 1 if y - (loy + cy * h) > 0.5 * h else -1
                        for tx in range(2 * ring + 1):
                            ux = cx + ((tx + 1) // 2) * (sx if tx % 2 == 1 else -sx)
                            if ux < 0 or ux > nx - 1:
                                continue
                            xa = lox + ux * h if ux > 0 else -np.inf
                            xb = lox + (ux + 1) * h if ux < nx - 1 else np.inf
                            gx = _gap(x, xa, xb, guard)
                            gx2 = gx * gx
                            if gx2 >= best_d[k - 1]:
                                continue
                            for ty in range(2 * ring + 1):
                                uy = cy + ((ty + 1) // 2) * (sy if ty % 2 == 1 else -sy)
                                if uy < 0 or uy > ny - 1:
                                    continue
                                cc = ux * ny + uy
                                a, b = col_start[cc], col_start[cc + 1]
                                if a == b or cc == c:
                                    continue
                                ya = loy + uy * h if uy > 0 else -np.inf
                                yb = loy + (uy + 1) * h if uy < ny - 1 else np.inf
                                gy = _gap(y, ya, yb, guard)
                                if gx2 + gy * gy >= best_d[k - 1]:
                                    continue
                                wz = _scan_column(xyz, zs, a, b, i, wz, best_d, best_i)
                        if best_d[k - 1] <= r * r or ring >= max_ring:
                            break
                        # jump straight to the ring that can hold the current k-th candidate (if any was found)
                        if best_d[k - 1] < np.inf:
                            ring = max(ring + 1, int(np.ceil(np.sqrt(best_d[k - 1]) / h)))
                        else:
                            ring = ring * 2
                        ring = min(ring, max_ring)
                        if ring > ring_budget:
                            # an isolated point: the block search prunes whole blocks instead of scanning rings
                            _block_search(
                                xyz, zs, col_start, nx, ny, h, lox, loy, guard, bzmin, bzmax, nbx, nby, bs, i, cx,
                                cy, best_d, best_i,
                            )  # fmt: skip
                            far[th] += 1
                            break
                    if full:
                        o = order[i]
                        for j in range(k):
                            dist[o, j] = np.sqrt(best_d[j])
                            idx[o, j] = order[best_i[j]]
                    else:
                        zeros = 0
                        while zeros < k and best_d[zeros] <= 0.0:
                            zeros += 1
                        summary[i, 0] = np.sqrt(best_d[0])  # in sorted order: scattered by the caller
                        if zeros == k:
                            summary[i, 1] = 0.0
                        else:
                            valid = k - zeros
                            lo_ = zeros + (valid - 1) // 2
                            hi_ = zeros + valid // 2
                            summary[i, 1] = 0.5 * (np.sqrt(best_d[lo_]) + np.sqrt(best_d[hi_]))
