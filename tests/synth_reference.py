"""Brute-force float64 references for the synthetic-scene tests (slow, obvious, independent of open3d)."""

from __future__ import annotations

import numpy as np


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (P,) float64 from each point (P, 3) to the nearest of triangles (T, 3, 3), and that triangle's index.

    Closest point on a triangle by Voronoi regions (Ericson, Real-Time Collision Detection, 5.1.5), evaluated
    for every point-triangle pair: O(P·T) memory per chunk, meant for a few hundred points.
    """
    a, b, c = triangles[None, :, 0], triangles[None, :, 1], triangles[None, :, 2]
    best = np.full(len(points), np.inf)
    best_idx = np.zeros(len(points), np.int64)
    for start in range(0, len(points), 64):
        p = points[start : start + 64, None, :]
        ab, ac, ap = b - a, c - a, p - a
        d1, d2 = np.sum(ab * ap, -1), np.sum(ac * ap, -1)
        bp = p - b
        d3, d4 = np.sum(ab * bp, -1), np.sum(ac * bp, -1)
        cp = p - c
        d5, d6 = np.sum(ab * cp, -1), np.sum(ac * cp, -1)
        va = d3 * d6 - d5 * d4
        vb = d5 * d2 - d1 * d6
        vc = d1 * d4 - d3 * d2
        denom = va + vb + vc
        with np.errstate(divide="ignore", invalid="ignore"):
            v = vb / denom
            w = vc / denom
            q = a + ab * v[..., None] + ac * w[..., None]  # inside the face
            t_ab = d1 / (d1 - d3)
            q = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[..., None], a + ab * t_ab[..., None], q)
            t_ac = d2 / (d2 - d6)
            q = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[..., None], a + ac * t_ac[..., None], q)
            t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            q = np.where(((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0))[..., None], b + (c - b) * t_bc[..., None], q)
        q = np.where(((d1 <= 0) & (d2 <= 0))[..., None], a, q)
        q = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b, q)
        q = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c, q)
        dist = np.linalg.norm(p - q, axis=-1)
        dist = np.where(np.isfinite(dist), dist, np.inf)
        idx = np.argmin(dist, axis=1)
        best[start : start + 64] = dist[np.arange(len(idx)), idx]
        best_idx[start : start + 64] = idx
    return best, best_idx
