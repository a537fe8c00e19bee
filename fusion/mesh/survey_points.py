"""Oriented points from the survey point product (``export/merged_points.ply``): the input of a mesh made from
what the survey measured (``MeshSource.SURVEY``) rather than from the Gaussians' ellipses.

The survey product holds the MVS points (``source`` 1) and the splat centres that passed the survey-point rule (2).
Each point becomes one oriented point: its normal is the cloud's own where the file has normals, else the PCA
normal of its ``normal_neighbors`` nearest survey points, turned to face the cameras (:func:`orient_normals`); its
footprint (the support radius trimming uses) is ``footprint_sigmas`` × its ``scale`` field (the σ of the Gaussian it
came from), or the mean distance to its nearest neighbours where there is none.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from core.errors import DataError
from core.pointcloud import PointCloud
from fusion.convert import pca_normals
from fusion.mesh.options import OrientedPointOptions
from fusion.mesh.oriented_points import orient_normals
from fusion.mesh.types import OrientedPoints


def oriented_points_from_survey(
    cloud: PointCloud, options: OrientedPointOptions | None = None, viewpoints: np.ndarray | None = None
) -> OrientedPoints:
    """One oriented point per point of the survey ``cloud`` (its local frame and origin), see the module docstring.

    viewpoints: (M, 3) float64 camera centres relative to ``cloud.origin``, or None. Raises :class:`DataError` for a
    cloud of fewer than 3 points or with non-finite positions.
    """
    options = options or OrientedPointOptions()
    n = len(cloud.positions)
    if n < 3:
        raise DataError(f"the survey product holds {n} points: too few to mesh (need at least 3)")
    if not np.isfinite(cloud.positions).all():
        raise DataError("the survey product holds non-finite positions")
    positions = cloud.positions
    trusted = np.zeros(n, dtype=bool)
    if cloud.normals is not None:
        normals = cloud.normals.astype(np.float64)
        length = np.linalg.norm(normals, axis=1)
        trusted = np.isfinite(length) & (length > 0.5)
        normals[trusted] /= length[trusted, None]
    else:
        normals = np.zeros((n, 3))
    scale = np.asarray(cloud.fields.get("scale", np.zeros(n)), dtype=np.float64)
    footprint = options.footprint_sigmas * np.where(np.isfinite(scale), scale, 0.0)
    unscaled = footprint <= 0
    if (~trusted).any() or unscaled.any():  # one neighbour query serves the PCA normals and the missing footprints
        distances, neighbours = cKDTree(positions).query(positions, k=min(options.normal_neighbors, n - 1) + 1)
        rows = np.flatnonzero(~trusted)
        normals[rows] = pca_normals(positions, rows, neighbours[rows, 1:])
        footprint[unscaled] = distances[unscaled, 1:].mean(axis=1)
    normals = orient_normals(positions, normals, trusted, viewpoints, options.normal_neighbors)
    colors = np.full((n, 3), 0.5, np.float32) if cloud.colors is None else cloud.colors.astype(np.float32) / 255.0
    source = np.asarray(cloud.fields.get("source", np.zeros(n)), dtype=np.uint8)
    return OrientedPoints(positions, normals, colors, source, np.full(n, -1, np.int64), cloud.origin.copy(), footprint)
