"""The public k-NN search over the column grid: :func:`knn_grid` (the (N, k) neighbours) and
:func:`knn_grid_summary` (per point the nearest distance and the median non-duplicate distance), both exact."""

from __future__ import annotations

import numba
import numpy as np

from core.knn.grid import BLOCK, ColumnGrid, build_grid, checked_positions
from core.knn.kernels import query_rows, scatter_rows
from core.knn.reference import knn_kdtree, median_nonzero
from core.knn.threads import CHUNKS_PER_THREAD, run_threads


def knn_grid(positions: np.ndarray, k: int, max_columns_per_point: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """Exact (N, k) distances (float64, metres, ascending) and indices (int64) of each point's k nearest *others*.

    ``positions``: (N, 3) float64 local coordinates, N > k, finite. Exact duplicates appear at distance 0. Ties
    between equidistant neighbours may pick different indices than :func:`knn_kdtree`; distances are identical.
    """
    p = checked_positions(positions, k)
    grid = build_grid(p, k, max_columns_per_point)
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
    p = checked_positions(positions, k)
    grid = build_grid(p, k, max_columns_per_point)
    if grid is None:
        dist, _ = knn_kdtree(p, k)
        return dist[:, 0].copy(), median_nonzero(dist)
    _, _, summary, _ = _query(grid, k, False)
    return summary[:, 0], summary[:, 1]


_RING_BUDGET = 3
"""Rings of columns a point may search before it switches to the block search (isolated outliers)."""


def _query(grid: ColumnGrid, k: int, full: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Distances and input-order indices of the k nearest others (``full``: (N, k) each), or per point the nearest
    distance and the median non-duplicate distance (``summary``: (N, 2)), at each point's input position; also
    the number of points that needed the block search (outliers)."""
    n = len(grid.sorted_xyz)
    dist = np.empty((n if full else 0, k))
    idx = np.empty((n if full else 0, k), dtype=np.int64)
    summary = np.empty((0 if full else n, 2))
    nth = numba.get_num_threads()
    rows_per_chunk = max(1, grid.nx // (nth * CHUNKS_PER_THREAD))
    far = np.zeros(nth, dtype=np.int64)
    zs = np.ascontiguousarray(grid.sorted_xyz[:, 2])
    args = (grid.sorted_xyz, zs, grid.order, grid.col_start, grid.nx, grid.ny, grid.h, grid.lo[0], grid.lo[1])
    args += (grid.guard, grid.bzmin, grid.bzmax, grid.nbx, grid.nby, BLOCK, k, full, _RING_BUDGET)
    args += (dist, idx, summary, far, rows_per_chunk)
    run_threads(query_rows, args, nth)
    if not full:  # a separate scatter pass is cheaper than random writes inside the search
        out = np.empty_like(summary)
        run_threads(scatter_rows, (summary, grid.order, out), nth)
        summary = out
    return dist, idx, summary, int(far.sum())
