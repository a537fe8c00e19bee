"""Threaded numba kernels for the per-point bookkeeping of :func:`classify.features.compute_features`.

Features are computed on the points sorted along a Morton curve and written back in the cloud's order. With numpy
each of these steps is a one-threaded fancy-index pass that allocates a temporary of the whole array; the kernels
below do each in one threaded pass without temporaries, several times faster (timings in
docs/experiments/2026-11-27-domain-defaults.md). ``tests/test_classify_features.py``
compares them with their numpy twins.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(parallel=True, cache=True, nogil=True)
def _morton_kernel(pts, lo, span, bits):  # pragma: no cover - compiled
    n = pts.shape[0]
    top = (1 << bits) - 1
    cells = float(1 << bits)
    out = np.empty(n, dtype=np.uint64)
    for i in numba.prange(n):
        code = np.uint64(0)
        for axis in range(3):
            q = int((pts[i, axis] - lo[axis]) / span * cells)
            q = min(max(q, 0), top)
            for b in range(bits):
                code |= np.uint64((q >> b) & 1) << np.uint64(3 * b + axis)
        out[i] = code
    return out


def morton_codes(
    positions: np.ndarray, bits: int = 16, lo: np.ndarray | None = None, span: float | None = None
) -> np.ndarray:
    """(N,) uint64 Morton (Z-order) codes of points (N, 3) float64 in their bounding cube, ``bits`` per axis
    (bit b of axis a at position 3b + a; coordinates quantised by truncation, clamped to 2^bits − 1).

    lo (3,) metres and span (metres): the cube's lowest corner and side; default the points' own bounding cube (a
    part of a cloud passes the whole cloud's, so that its codes are the whole cloud's)."""
    pts = np.ascontiguousarray(positions, dtype=np.float64)
    if len(pts) == 0:
        return np.zeros(0, np.uint64)
    if lo is None or span is None:
        lo, span = cube_of(pts.min(axis=0), pts.max(axis=0))
    return _morton_kernel(pts, np.asarray(lo, dtype=np.float64), float(span), bits)


def cube_of(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, float]:
    """The Morton cube of a bounding box: its lowest corner (3,) float64 and side (metres, > 0)."""
    lo = np.asarray(lo, dtype=np.float64)
    return lo, max(float((np.asarray(hi, dtype=np.float64) - lo).max()), 1e-300)


@numba.njit(parallel=True, cache=True, nogil=True)
def _gather_rows_kernel(a, order):  # pragma: no cover - compiled
    n, m = order.shape[0], a.shape[1]
    out = np.empty((n, m), dtype=a.dtype)
    for i in numba.prange(n):
        row = order[i]
        for j in range(m):
            out[i, j] = a[row, j]
    return out


def gather_rows(a: np.ndarray, order: np.ndarray) -> np.ndarray:
    """``a[order]`` for a 2-D array (N, M) of any numeric dtype and an index array (K,) int64: (K, M), a's dtype."""
    return _gather_rows_kernel(np.ascontiguousarray(a), np.ascontiguousarray(order, np.int64))


@numba.njit(parallel=True, cache=True, nogil=True)
def _scatter_column_kernel(values, order, j, column):  # pragma: no cover - compiled
    for i in numba.prange(order.shape[0]):
        values[order[i], j] = column[i]


def scatter_column(values: np.ndarray, order: np.ndarray, j: int, column: np.ndarray) -> None:
    """``values[order, j] = column`` in place: values (N, F) float32, order (N,) int64 a permutation, column (N,)."""
    _scatter_column_kernel(values, np.ascontiguousarray(order, np.int64), int(j),
                           np.ascontiguousarray(column, np.float32))  # fmt: skip


@numba.njit(parallel=True, cache=True, nogil=True)
def _renumber_kernel(neighbours, order):  # pragma: no cover - compiled
    n, m = neighbours.shape
    out = np.empty((n, m), dtype=np.int64)
    for i in numba.prange(n):
        row = order[i]
        for j in range(m):
            out[row, j] = order[neighbours[i, j]]
    return out


def renumber_neighbours(neighbours: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Neighbour lists of points sorted by ``order`` (row i is point order[i], entries index sorted rows) in the
    original numbering: out[order[i]] = order[neighbours[i]]; (N, m) int64."""
    return _renumber_kernel(np.ascontiguousarray(neighbours, np.int64), np.ascontiguousarray(order, np.int64))
