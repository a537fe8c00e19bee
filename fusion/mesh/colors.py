"""Vertex colours from Gaussians: an opacity- and distance-weighted mean of the SH DC colours of nearby Gaussians.

For vertex v with its k nearest Gaussian centres g (distances d_g), weights w_g = α_g · exp(−d_g² / (2 h²)), with h the
distance to the nearest centre plus the Gaussian's largest σ (so a vertex between sparse large splats still blends
them); colour = Σ w_g c_g / Σ w_g with c_g = clip(0.5 + C0 · f_dc, 0, 1). Where every weight underflows the nearest
Gaussian's colour is used. View-dependent SH terms are ignored: a mesh vertex has one colour.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from core.errors import DataError
from core.gaussians import GaussianSet


def vertex_colors_from_gaussians(
    vertices: np.ndarray, origin: np.ndarray, gaussians: GaussianSet, k: int = 8, chunk: int = 200_000
) -> np.ndarray:
    """(V, 3) float32 RGB in [0, 1] for vertices (V, 3) float64 given relative to ``origin`` (3,) float64."""
    if len(gaussians) == 0:
        raise DataError("vertex colours need at least one Gaussian")
    g = gaussians.with_origin(np.asarray(origin, dtype=np.float64))
    colors = g.base_colors.astype(np.float64)
    alpha = g.opacities.astype(np.float64)
    sigma_max = g.scales.max(axis=1).astype(np.float64)
    k = int(min(max(k, 1), len(g)))
    tree = cKDTree(g.means)
    out = np.empty((len(vertices), 3), dtype=np.float32)
    for s in range(0, len(vertices), chunk):
        d, nb = tree.query(np.asarray(vertices[s : s + chunk], dtype=np.float64), k=k)
        d, nb = d.reshape(len(d), k), nb.reshape(len(nb), k)
        h = d[:, :1] + sigma_max[nb[:, :1]] + 1e-12
        w = alpha[nb] * np.exp(-0.5 * (d / h) ** 2)
        total = w.sum(axis=1, keepdims=True)
        blended = (w[..., None] * colors[nb]).sum(axis=1) / np.maximum(total, 1e-300)
        blended = np.where(total > 1e-300, blended, colors[nb[:, 0]])
        out[s : s + chunk] = np.clip(blended, 0.0, 1.0)
    return out
