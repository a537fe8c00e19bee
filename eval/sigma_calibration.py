"""Is a point's σ honest? Its stated uncertainty against its distance to the reference surface, per material.

A survey point that carries a σ (a ``sigma`` field of a product's points, metres) claims that its distance to the
true surface is within 1.96 σ with 95 % probability (a normal error along the surface normal).
:func:`calibration_per_material` counts how often that holds against a reference cloud (a LiDAR scan):

- the distance of a point to the reference *surface* is estimated as CloudCompare's C2C with a local model does: a
  least-squares plane through the ``k`` nearest reference points (their PCA), the point's distance to that plane,
  but never more than its distance to the nearest reference point (that point lies on the surface, so the surface
  is at least that near). The nearest-point distance alone would add the reference's sampling spacing to every
  error and make any σ look too small;
- the point belongs to the material of its nearest reference point (as :mod:`eval.per_material` assigns accuracy);
- per material and over all points: how many, the share within 1 σ (a calibrated normal error: 0.683) and within
  1.96 σ (0.95), the median σ and the median distance.

Coordinates: world float64, differences taken about the reference's first point (georeferenced clouds keep
millimetres). Distances and σ in metres.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

Z95 = 1.959963984540054
"""Half-width of the two-sided 95 % interval of a normal error, in σ."""


def local_plane_distances(
    points_local: np.ndarray, reference_local: np.ndarray, k: int = 8
) -> tuple[np.ndarray, np.ndarray]:
    """(distances (N,) float64 metres, nearest (N,) int64 reference index) of each point to the reference surface.

    points_local, reference_local: (N, 3), (M, 3) float64 in one local frame. The distance is the point's distance
    to the least-squares plane of its ``k`` nearest reference points, capped at its distance to the nearest one;
    with fewer than 3 reference points, the nearest-point distance.
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points_local, np.float64).reshape(-1, 3)
    ref = np.asarray(reference_local, np.float64).reshape(-1, 3)
    if len(ref) == 0:
        raise ValueError("the reference cloud is empty")
    tree = cKDTree(ref)
    kk = min(k, len(ref))
    d_nearest, nearest = tree.query(pts, k=1, workers=-1)
    if kk < 3 or len(pts) == 0:
        return np.asarray(d_nearest, np.float64), np.asarray(nearest, np.int64)
    _, nb = tree.query(pts, k=kk, workers=-1)
    patches = ref[nb]  # (N, k, 3)
    centroids = patches.mean(axis=1)
    centred = patches - centroids[:, None]
    # the normal of each patch = the eigenvector of its scatter matrix with the smallest eigenvalue
    _, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
    normals = vectors[:, :, 0]
    d_plane = np.abs(np.einsum("ni,ni->n", pts - centroids, normals))
    return np.minimum(d_plane, d_nearest), np.asarray(nearest, np.int64)


def calibration_row(distances: np.ndarray, sigma: np.ndarray) -> dict[str, Any]:
    """One row of the calibration table: points, share within 1 σ and within 1.96 σ, median σ and distance (m).

    distances, sigma: (N,) metres; a σ that is not finite or not positive never holds a distance (counted as a
    miss, not dropped; 0 in the median σ). An empty group: shares and medians None."""
    d = np.asarray(distances, np.float64).reshape(-1)
    s = np.asarray(sigma, np.float64).reshape(-1)
    if len(d) != len(s):
        raise ValueError(f"{len(d)} distances but {len(s)} sigmas")
    if len(d) == 0:
        return {"points": 0, "within_1sigma": None, "within_95": None, "median_sigma_m": None,
                "median_distance_m": None}  # fmt: skip
    valid = np.isfinite(s) & (s > 0)
    s_safe = np.where(valid, s, 0.0)
    return {
        "points": int(len(d)),
        "within_1sigma": float((valid & (d <= s_safe)).mean()),
        "within_95": float((valid & (d <= Z95 * s_safe)).mean()),
        "median_sigma_m": float(np.median(s_safe)),
        "median_distance_m": float(np.median(d)),
    }


def calibration_per_material(
    points_world: np.ndarray, sigma: np.ndarray, reference_world: np.ndarray, reference_material: np.ndarray,
    names: Mapping[int, str], k: int = 8,
) -> dict[str, dict[str, Any]]:  # fmt: skip
    """The calibration table: ``{"all": row, material name: row, ...}`` (rows of :func:`calibration_row`).

    points_world: (N, 3) float64 world coordinates of points with a σ; sigma: (N,) metres; reference_world: (M, 3)
    float64; reference_material: (M,) integer material id per reference point; names: material id → name (ids
    without a name are counted in ``all`` only). k: reference points of each local plane."""
    ref = np.asarray(reference_world, np.float64).reshape(-1, 3)
    pts = np.asarray(points_world, np.float64).reshape(-1, 3)
    sig = np.asarray(sigma, np.float64).reshape(-1)
    if len(sig) != len(pts):
        raise ValueError(f"{len(pts)} points but {len(sig)} sigmas")
    if len(ref) == 0:
        return {}
    anchor = ref[0]
    distances, nearest = local_plane_distances(pts - anchor, ref - anchor, k)
    owner = np.asarray(reference_material).astype(np.int64).reshape(-1)[nearest]
    table = {"all": calibration_row(distances, sig)}
    for m in sorted(set(owner.tolist()) & set(names)):
        on_m = owner == m
        table[names[m]] = calibration_row(distances[on_m], sig[on_m])
    return table
