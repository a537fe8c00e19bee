"""Points projected onto the pixel grid of a view, and looked up in its mask.

One helper for what seeding (:func:`fusion.train.init.points_in_masks`, :func:`fusion.train.init.zbuffer_depth`)
and cleaning (:func:`fusion.clean.mask_views`) all do: project local-frame points with
:meth:`core.cameras.Cameras.project`, take the pixel each lands in (floor of the projection: pixel centres at
+0.5, COLMAP / OpenCV convention) and keep those in front of the camera and inside the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.cameras import Cameras, View


@dataclass(frozen=True)
class PixelProjection:
    """Where N points land in a ``width`` × ``height`` image.

    row, col: (N,) int64 pixel indices (floor of the projection; meaningless where not ``ok``). z: (N,) float64
    depth along the camera's z axis (metres). ok: (N,) bool, in front of the camera (z > 0) and inside the image.
    """

    row: np.ndarray
    col: np.ndarray
    z: np.ndarray
    ok: np.ndarray

    def lookup(self, image: np.ndarray) -> np.ndarray:
        """(N,) bool: ``image`` (H, W) bool at each point's pixel; False where the point is not ``ok``."""
        hit = np.zeros(len(self.ok), bool)
        hit[self.ok] = image[self.row[self.ok], self.col[self.ok]]
        return hit


def project_to_pixels(cameras: Cameras, view: View, points: np.ndarray, width: int, height: int) -> PixelProjection:
    """The pixels of ``view`` (an image of ``width`` × ``height`` px) that ``points`` (N, 3, local frame) land in."""
    uv, z = cameras.project(view, points)
    col = np.floor(uv[:, 0]).astype(np.int64)
    row = np.floor(uv[:, 1]).astype(np.int64)
    ok = (z > 0) & (col >= 0) & (col < width) & (row >= 0) & (row < height)
    return PixelProjection(row, col, z, ok)
