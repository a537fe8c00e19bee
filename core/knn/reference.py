"""The k-d tree reference of the k-NN search (scipy's ``cKDTree``) and helpers on (N, k) neighbour results."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


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
