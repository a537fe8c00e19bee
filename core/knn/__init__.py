"""Exact k-nearest-neighbour distances for whole point clouds, fast on few cores.

Why by hand: scipy's ``cKDTree`` (the reference, see :func:`knn_kdtree`) is slow to build and to query for a whole cloud
on a few cores, which caps the conversion's throughput (figures in docs/experiments/2026-11-27-domain-defaults.md). MVS
clouds are surfaces sampled at a roughly known spacing, so a column grid does better: points are bucketed into square
(x, y) columns of side ``h`` (a counting sort, O(N)), sorted by z inside each column, and each point scans the 3×3
neighbouring columns within a z window of ±r. The search is exact: a point at distance ≤ r lies in a column within ⌈r/h⌉
and in the z window, so rings of columns are added (r = h, 2h, 3h, …) until the k-th best distance is ≤ r. Ring 1 is
done per column: the 3×3 neighbourhood is gathered once (when it holds at most ``_GATHER_CAP`` points; steep or dense
spots keep the z-windowed per-point scan) and each point of the column takes its k best among the gathered points within
its r (branch-free filter, then insertion); a point whose k-th best is not within r falls back to the per-point ring
scan. Points that would need more than ``_RING_BUDGET`` rings (isolated outliers) switch to a two-level search over
blocks of ``BLOCK``×``BLOCK`` columns, each with its z range: blocks are visited ring by ring and pruned (with their
columns) by the distance to their bounding box, which is exact and stays cheap however far the outlier is. Memory: the
column table (≤ ``max_columns_per_point`` · N int64), a sorted copy of the points and one column key per point, O(N).

The grid covers a robust box (0.1–99.9 % per axis); points beyond it are clamped into the border columns, which
keeps the search exact (border columns and blocks are unbounded outwards). A cloud whose columns would be badly
overfilled (dense clusters far apart) goes to the k-d tree whole. ``h`` is chosen from the box and N assuming a
2.5-D surface, then refined once from the measured column occupancy; a bad guess only costs time, never exactness.
Work is split over Python threads running GIL-free numba kernels on interleaved ranges of column rows (waiting
threads block instead of spinning, which matters on shared cores; see ``fusion/render/cpu.py``).
Tests compare against brute force and ``cKDTree``.

Modules, one job each: :mod:`core.knn.search` (:func:`knn_grid`, :func:`knn_grid_summary`: the public search),
:mod:`core.knn.grid` (the column grid and its numba construction kernels), :mod:`core.knn.kernels` (the numba query
kernels), :mod:`core.knn.reference` (the k-d tree reference and helpers on its results), :mod:`core.knn.threads`
(GIL-free kernels on Python threads).
"""

from core.knn.reference import drop_self, knn_kdtree, median_nonzero
from core.knn.search import knn_grid, knn_grid_summary
from core.knn.threads import run_threads

__all__ = ["drop_self", "knn_grid", "knn_grid_summary", "knn_kdtree", "median_nonzero", "run_threads"]
