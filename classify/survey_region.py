"""The survey region as a solid, and which pixels' rays meet it: where a missing surface is a hole, not background.

The region is the volume under the cloud's upper surface over its footprint, with "up" a world axis
(``MaskOptions.up``). It is held as a height field on a square grid of ``cell`` metres in the plane normal to up:

- a cell is *occupied* when a point falls in it; its height is the highest point's;
- the *footprint* is the convex hull of the occupied cells (a lone occupied cell, with no occupied neighbour among
  its 8, is an outlier and left out of the hull), the survey's site boundary: it holds every gap among the points
  (a hole in the floor, a lawn MVS did not match at the edge of an aerial block, a missing window): those cells
  take the height of the nearest occupied cell;
- every other cell is outside the region.

A pixel's ray *meets the region* when, somewhere over the footprint, it passes at or below the height field: it
went under the cloud's top surface, so the surface it shows lies in the region, and a pixel that no fused point
explains there shows a surface MVS missed (a hole). A ray that leaves the footprint or stays above the height field
all the way (the sky, a backdrop behind a silhouette, the floor beyond the table) never meets the region: its
pixel is background, for the background layer, not for fill splats. This is a rule from the geometry alone (no
threshold tuned on a scene): the only scale is the grid's cell, which callers set to the radius within which a
point explains pixels (the masks' ``hole_gsd`` GSDs), so that "no point explains this pixel" and "this ray meets
the region" are judged at the same resolution.

Hand-written: open3d's ray casting needs a closed mesh of the region, which a noisy cloud with holes does not give
without the surface reconstruction whose gaps are the question; a height field answers it directly.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np
from scipy import ndimage

from core.cameras import Cameras, View
from core.errors import DataError


@dataclass(frozen=True)
class SurveyRegion:
    """The region's height field. ``frame`` (3, 3) float64: rows e1, e2, up (orthonormal, world frame of the points
    given); ``corner`` (3,) float64: the grid's corner in that frame (e1, e2 of cell (0, 0)'s low corner, and the
    lowest point's height); ``cell`` metres; ``heights`` (n1, n2) float64: the upper surface's height above
    ``corner[2]`` per cell, NaN outside the footprint; ``occupied`` (n1, n2) bool: cells holding a point."""

    frame: np.ndarray
    corner: np.ndarray
    cell: float
    heights: np.ndarray
    occupied: np.ndarray

    @property
    def footprint(self) -> np.ndarray:
        """(n1, n2) bool: the cells of the region (occupied or enclosed by occupied ones)."""
        return np.isfinite(self.heights)

    def to_grid(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) float64: world points in the grid's frame (e1, e2 from the grid's corner; height above the
        lowest point)."""
        return np.asarray(points, dtype=np.float64) @ self.frame.T - self.corner


def up_frame(up: np.ndarray) -> np.ndarray:
    """(3, 3) float64 orthonormal rows e1, e2, up with e1 the world axis least aligned with ``up``, made normal."""
    u = np.asarray(up, dtype=np.float64).reshape(3)
    norm = float(np.linalg.norm(u))
    if not (norm > 0 and np.isfinite(norm)):
        raise DataError(f"the up axis must be a finite non-zero vector, got {tuple(u)}")
    u = u / norm
    axis = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = axis - (axis @ u) * u
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1), u])


def survey_region(positions: np.ndarray, up: np.ndarray, cell: float, max_cells: int = 4_000_000) -> SurveyRegion:
    """The height field of the cloud ``positions`` (N, 3) float64 metres with up axis ``up`` (3,) at ``cell``
    metres; coarser (by whole factors) when the grid would exceed ``max_cells`` cells (memory bound)."""
    pts = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if not (cell > 0 and np.isfinite(cell)):
        raise DataError(f"the region's cell must be a positive length, got {cell}")
    frame = up_frame(up)
    finite = np.isfinite(pts).all(axis=1)
    if not finite.any():
        raise DataError("the cloud has no finite point: no survey region")
    local = pts[finite] @ frame.T
    low = local.min(axis=0)
    extent = local.max(axis=0) - low
    while (int(extent[0] / cell) + 1) * (int(extent[1] / cell) + 1) > max_cells:
        cell *= 2.0
    shape = (int(extent[0] / cell) + 1, int(extent[1] / cell) + 1)
    i1 = np.minimum((local[:, 0] - low[0]) / cell, shape[0] - 1).astype(np.int64)
    i2 = np.minimum((local[:, 1] - low[1]) / cell, shape[1] - 1).astype(np.int64)
    top = np.full(shape, -np.inf)
    np.maximum.at(top, (i1, i2), local[:, 2] - low[2])
    occupied = np.isfinite(top)
    footprint = _hull_of(occupied)
    # Empty cells of the footprint take the height of the nearest occupied cell.
    _, (n1, n2) = ndimage.distance_transform_edt(~occupied, return_indices=True)
    heights = np.where(footprint, top[n1, n2], np.nan)
    return SurveyRegion(frame, np.array([low[0], low[1], low[2]]), float(cell), heights, occupied)


def _hull_of(occupied: np.ndarray) -> np.ndarray:
    """(n1, n2) bool: the cells inside the convex hull of the occupied cells that have an occupied neighbour (cell
    corners, OpenCV's hull and polygon fill), with every occupied cell."""
    neighbours = ndimage.convolve(occupied.astype(np.int32), np.ones((3, 3), np.int32), mode="constant") - 1
    kept = np.argwhere(occupied & (neighbours > 0))
    out = occupied.copy()
    if len(kept) >= 3:
        corners = (kept[:, None, :] + np.array([[0, 0], [0, 1], [1, 0], [1, 1]])[None]).reshape(-1, 2)
        hull = cv2.convexHull(corners[:, ::-1].astype(np.int32))  # OpenCV points are (x = column, y = row)
        img = np.zeros((occupied.shape[0] + 1, occupied.shape[1] + 1), dtype=np.uint8)
        cv2.fillConvexPoly(img, hull, 1)
        # A cell is inside when its four corners are (the polygon fill includes the hull's boundary).
        inside = img.astype(bool)
        out |= inside[:-1, :-1] & inside[1:, :-1] & inside[:-1, 1:] & inside[1:, 1:]
    return out


def rays_meeting_region(
    cameras: Cameras, view: View, region: SurveyRegion, candidates: np.ndarray | None = None
) -> np.ndarray:
    """(H, W) bool: the pixels of ``view`` (through their centres) whose rays meet ``region`` (module docstring),
    tested only where ``candidates`` (H, W) bool is set (default: every pixel; the others are False). The cameras'
    frame must be the frame of the points the region was built from."""
    cam = cameras.camera_of(view)
    h, w = cam.height, cam.width
    todo = np.ones((h, w), dtype=bool) if candidates is None else np.asarray(candidates, dtype=bool)
    if todo.shape != (h, w):
        raise DataError(f"candidate pixels of shape {todo.shape} for a {w}×{h} photo")
    rows, cols = np.nonzero(todo)
    out = np.zeros((h, w), dtype=bool)
    if len(rows) == 0:
        return out
    pix = np.c_[cols + 0.5, rows + 0.5].astype(np.float64)
    dirs = cam.unproject(pix, 1.0) @ view.rotation  # world directions (d_w = Rᵀ d_c)
    dirs = dirs @ region.frame.T
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origin = region.to_grid(view.center[None])[0]
    out[rows, cols] = _march(origin, dirs, region.heights, region.cell)
    return out


@numba.njit(parallel=True, cache=True, nogil=True)
def _march(origin: np.ndarray, dirs: np.ndarray, heights: np.ndarray, cell: float) -> np.ndarray:
    """Per ray (unit ``dirs`` (M, 3) from ``origin`` (3,), grid frame): does it pass at or below ``heights`` over a
    footprint cell? Steps of half a cell along the part of the ray inside the grid's box (slab clipping)."""
    n1, n2 = heights.shape
    top = 0.0
    for i in range(n1):
        for j in range(n2):
            if heights[i, j] == heights[i, j] and heights[i, j] > top:  # NaN-safe max
                top = heights[i, j]
    hi = np.array([n1 * cell, n2 * cell, top + cell])
    lo = np.array([0.0, 0.0, -cell])
    m = dirs.shape[0]
    out = np.zeros(m, dtype=np.bool_)
    for k in numba.prange(m):
        t0, t1 = 0.0, np.inf
        for a in range(3):
            d = dirs[k, a]
            if abs(d) < 1e-15:
                if origin[a] < lo[a] or origin[a] > hi[a]:
                    t1 = -1.0
                continue
            ta, tb = (lo[a] - origin[a]) / d, (hi[a] - origin[a]) / d
            t0 = max(t0, min(ta, tb))
            t1 = min(t1, max(ta, tb))
        t = t0
        step = 0.5 * cell
        while t <= t1:
            x = origin[0] + t * dirs[k, 0]
            y = origin[1] + t * dirs[k, 1]
            i = int(x / cell)
            j = int(y / cell)
            if x >= 0.0 and y >= 0.0 and i < n1 and j < n2:
                hgt = heights[i, j]
                if hgt == hgt and origin[2] + t * dirs[k, 2] <= hgt:
                    out[k] = True
                    break
            t += step
    return out
