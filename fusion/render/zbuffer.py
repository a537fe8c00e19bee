"""The z-buffer of a point set in one pinhole view: per pixel, the depth of the nearest point landing in it.

Torch-free (NumPy). Conventions as the renderer's (``shared/DESIGN.md``): ``viewmat`` (4, 4) maps the points' frame
to the camera (OpenCV axes: x right, y down, z forward), ``K`` (3, 3) pinhole with pixel (col, row) covering
[col, col + 1) × [row, row + 1) (centres at +0.5, COLMAP); depths are camera z in metres.
"""

from __future__ import annotations

import numpy as np


def zbuffer(points: np.ndarray, viewmat: np.ndarray, K: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W) float64 z-depth of the nearest of ``points`` (N, 3, the frame ``viewmat`` maps from) per pixel; 0
    where none lands.

    viewmat: (4, 4) points' frame → camera (OpenCV axes); K: (3, 3) pinhole, pixel centres at +0.5. A point lands
    in the pixel that contains its projection (floor of u, v); points with z <= 1e-6 m are left out.
    """
    cam = points @ viewmat[:3, :3].T + viewmat[:3, 3]
    z = cam[:, 2]
    front = z > 1e-6
    uv = (cam[front] @ K.T)[:, :2] / z[front, None]
    col = np.floor(uv[:, 0]).astype(np.int64)
    row = np.floor(uv[:, 1]).astype(np.int64)
    ok = (col >= 0) & (col < width) & (row >= 0) & (row < height)
    depth = np.full(height * width, np.inf)
    np.minimum.at(depth, row[ok] * width + col[ok], z[front][ok])
    depth[~np.isfinite(depth)] = 0.0
    return depth.reshape(height, width)
