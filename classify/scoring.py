"""Scoring against a synthetic scene's truth: which pixels of a photo truly need splats.

A pixel truly needs splats when its GT material is non-collaborative, or when its true depth is not explained
by a fused point within τ (a hole), whatever its material (the issue's definition). Background pixels
(label 255) never need splats. "Explained": the pixel's true surface point (its true depth back-projected)
has a fused point within τ in 3D.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from classify.masks import disk_kernel
from core.cameras import Cameras, View


def depth_buffer(
    cameras: Cameras, view: View, positions: np.ndarray, spacing: float, footprint: float = 1.5, max_radius: int = 12
) -> np.ndarray:
    """(H, W) float64 nearest z-depth (metres) of the points drawn as disks of ``footprint × spacing``; inf where
    none. Disks are drawn by grouping points by integer radius and eroding each group's depth image."""
    cam = cameras.camera_of(view)
    h, w = cam.height, cam.width
    uv, z = cameras.project(view, positions)
    ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < w) & (uv[:, 1] < h)
    col, row, zz = uv[ok, 0].astype(np.int64), uv[ok, 1].astype(np.int64), z[ok]
    rad = np.clip(np.round(footprint * spacing * cam.focal[0] / zz).astype(np.int64), 0, max_radius)
    out = np.full((h, w), np.inf)
    for r in np.unique(rad):
        sel = rad == r
        layer = np.full((h, w), np.inf, dtype=np.float64)
        np.minimum.at(layer, (row[sel], col[sel]), zz[sel])
        if r > 0:
            finite_max = np.nanmax(np.where(np.isfinite(layer), layer, np.nan)) if np.isfinite(layer).any() else 1.0
            filled = np.where(np.isfinite(layer), layer, 2 * finite_max + 1).astype(np.float32)
            eroded = cv2.erode(filled, disk_kernel(int(r)))
            layer = np.where(eroded <= finite_max * (1 + 1e-6), eroded.astype(np.float64), np.inf)
        out = np.minimum(out, layer)
    return out


@dataclass(frozen=True)
class PixelTruth:
    """needs: (H, W) bool truly needs splats; material_bad: non-collaborative material; hole: depth unexplained;
    background: label 255."""

    needs: np.ndarray
    material_bad: np.ndarray
    hole: np.ndarray
    background: np.ndarray


def distance_to_cloud(cameras: Cameras, view: View, true_depth: np.ndarray, tree: object) -> np.ndarray:
    """(H, W) float64 metres from each pixel's true surface point (pixel centre, true z-depth) to the nearest
    fused point (``tree``: a scipy cKDTree of the fused positions, same frame); inf where there is no surface."""
    h, w = true_depth.shape
    rows, cols = np.mgrid[0:h, 0:w]
    ok = true_depth > 0
    pix = np.c_[cols[ok] + 0.5, rows[ok] + 0.5]
    pts = cameras.unproject(view, pix, true_depth[ok].astype(np.float64))
    out = np.full((h, w), np.inf)
    out[ok] = tree.query(pts, k=1)[0]  # type: ignore[attr-defined]
    return out


def pixel_truth(
    labels: np.ndarray,
    true_depth: np.ndarray,
    collaborative_ids: set[int],
    distance: np.ndarray,
    tau: float,
) -> PixelTruth:
    """The truth of one photo from its label map (H, W) uint8, true z-depth (H, W) metres (0 = none), the
    collaborative material ids, each pixel's distance to the fused cloud (:func:`distance_to_cloud`) and τ."""
    background = (labels == 255) | (true_depth <= 0)
    lut = np.ones(256, dtype=bool)
    for m in collaborative_ids:
        lut[m] = False
    material_bad = lut[labels] & ~background
    hole = ~background & ~(distance <= tau)
    return PixelTruth(material_bad | hole, material_bad, hole, background)
