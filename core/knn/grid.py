"""The column grid of the k-NN search: points counting-sorted into square (x, y) columns of side h, z-sorted inside
each column, with the z range of each block of ``BLOCK``×``BLOCK`` columns (see :mod:`core.knn`).

``h`` is chosen from a robust box (0.1–99.9 % per axis) and N assuming a 2.5-D surface, then refined once from the
measured column occupancy; points beyond the box are clamped into the border columns. The numba kernels that build
the grid live here too.
"""

from __future__ import annotations

import numba
import numpy as np

from core.errors import DataError
from core.knn.threads import CHUNKS_PER_THREAD, run_threads


def _target_per_column(k: int) -> float:
    """Points per occupied column for a k-NN query (1.75 for k = 1, 3.5 for k = 8): the fastest occupancy in a sweep
    on a terrain cloud; see docs/experiments/2026-11-27-domain-defaults.md."""
    return 1.5 + 0.25 * k


BLOCK = 8
"""Columns per side of the blocks (with their z range) of the outliers' search."""

_MAX_SCAN_FACTOR = 40.0
"""Fall back to the k-d tree when the grid would scan more than this × the target candidates per point (clouds
made of far-apart dense clusters, where no single column size suits all)."""


def checked_positions(positions: np.ndarray, k: int) -> np.ndarray:
    """``positions`` as contiguous (N, 3) float64 (metres), checked for a k-NN query: k ≥ 1, more than k points,
    finite coordinates; raises :class:`DataError` otherwise."""
    p = np.ascontiguousarray(positions, dtype=np.float64)
    n = len(p)
    if k < 1 or n <= k:
        raise DataError(f"{k} nearest neighbours need k >= 1 and more than k points, got {n}")
    if p.ndim != 2 or p.shape[1] != 3:
        raise DataError(f"k nearest neighbours need (N, 3) positions, got shape {p.shape}")
    if not _all_finite(p):
        raise DataError("k nearest neighbours need finite coordinates")
    return p


def build_grid(p: np.ndarray, k: int, max_columns_per_point: float) -> ColumnGrid | None:
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
    return ColumnGrid(p, lo, h, nx, ny, col_start, order)


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


class ColumnGrid:
    """Points counting-sorted into (x, y) columns of side h (row-major), z-sorted inside each column, plus the z range
    of each block of ``BLOCK``×``BLOCK`` columns."""

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
        chunk = max(1, (nx * ny) // (nth * CHUNKS_PER_THREAD) + 1)
        run_threads(_gather_sorted, (p, self.order, self.col_start, chunk, self.sorted_xyz), nth)
        self.lo = (float(lo[0]), float(lo[1]))
        self.nbx = (nx + BLOCK - 1) // BLOCK
        self.nby = (ny + BLOCK - 1) // BLOCK
        self.bzmin, self.bzmax = _block_bounds(self.sorted_xyz, self.col_start, nx, ny, BLOCK, self.nbx, self.nby)
        # slack for the rounding of column assignment: relative to h and to the coordinates' magnitude
        self.guard = 1e-9 * self.h + 16 * float(np.spacing(_max_abs_xy(p) + self.h * (nx + ny)))


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
