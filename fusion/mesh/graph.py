"""Connectivity of a triangle mesh: edge use counts and connected pieces (shared by the checks and the repairs).

Triangles are (T, 3) int64 vertex indices. An undirected edge is a sorted vertex pair; a piece is a set of triangles
connected through shared vertices.
"""

from __future__ import annotations

import numpy as np


def edge_use_counts(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique undirected edges (E, 2) int64 (sorted vertex pairs) and how many triangles use each (E,)."""
    t = np.asarray(triangles, dtype=np.int64)
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    e.sort(axis=1)
    if len(e) == 0:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=np.int64)
    base = int(e.max()) + 1
    # one int64 per edge (a · base + b: exact below 3e9 vertices), far faster than a row-wise unique
    codes, counts = np.unique(e[:, 0] * base + e[:, 1], return_counts=True)
    return np.stack([codes // base, codes % base], axis=1), counts


def triangle_components(triangles: np.ndarray, num_vertices: int) -> np.ndarray:
    """(T,) int64 label per triangle: triangles sharing a vertex are in the same piece (scipy connected components)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    t = len(triangles)
    if t == 0:
        return np.zeros(0, dtype=np.int64)
    # bipartite graph triangles ↔ vertices; the components of its triangle nodes are the pieces
    rows = np.repeat(np.arange(t), 3)
    cols = t + triangles.reshape(-1)
    graph = coo_matrix((np.ones(3 * t, dtype=np.int8), (rows, cols)), shape=(t + num_vertices, t + num_vertices))
    _, labels = connected_components(graph, directed=False)
    _, labels = np.unique(labels[:t], return_inverse=True)
    return labels.astype(np.int64)
