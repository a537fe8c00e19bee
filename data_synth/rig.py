"""Camera rigs: an object-scale orbit and an aerial nadir grid + oblique passes, plus held-out test views.

Test cameras sit *between* training cameras (midway in azimuth on an orbit ring, midway between grid nodes
for nadir), so image metrics measure interpolation, not extrapolation. All poses are COLMAP world-to-camera
(OpenCV axes) in the scene's local frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.cameras import Camera, Cameras, View
from core.errors import ConfigError


def look_at(center: np.ndarray, target: np.ndarray, up_hint: np.ndarray | None = None) -> np.ndarray:
    """3×4 world-to-camera matrix [R | t] of a camera at ``center`` looking at ``target`` (OpenCV axes).

    The image's "up" (−y) is as close as possible to ``up_hint`` (default +z; use +y for nadir views).
    """
    c = np.asarray(center, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64) - c
    f /= np.linalg.norm(f)
    up = np.array([0.0, 0.0, 1.0]) if up_hint is None else np.asarray(up_hint, dtype=np.float64)
    right = np.cross(f, up)
    if np.linalg.norm(right) < 1e-9:
        raise ConfigError(f"camera at {c.tolist()} looks along its up hint {up.tolist()}; give another up_hint")
    right /= np.linalg.norm(right)
    down = np.cross(f, right)
    R = np.stack([right, down, f])
    return np.concatenate([R, (-R @ c)[:, None]], axis=1)


def pinhole_from_fov(width: int, height: int, hfov_deg: float) -> Camera:
    """A PINHOLE camera with square pixels, horizontal field of view ``hfov_deg``, centred principal point."""
    fx = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
    return Camera.pinhole(fx, fx, width / 2.0, height / 2.0, width, height)


@dataclass(frozen=True)
class OrbitRig:
    """Cameras on rings around ``target``.

    radius_m: distance to the target. elevations_deg: one ring per elevation. views_per_ring: training views
    per ring, evenly spaced over ``azimuth_span_deg`` starting at ``azimuth_start_deg`` (360 = full orbit;
    rings are staggered by half a step). n_test: held-out views, midway between training views.
    """

    radius_m: float
    elevations_deg: tuple[float, ...]
    views_per_ring: int
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    azimuth_start_deg: float = 0.0
    azimuth_span_deg: float = 360.0
    n_test: int = 4
    hfov_deg: float = 50.0

    def _step(self) -> float:
        full = abs(self.azimuth_span_deg - 360.0) < 1e-9
        return self.azimuth_span_deg / (self.views_per_ring if full else max(self.views_per_ring - 1, 1))

    def _center(self, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
        az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
        offset = self.radius_m * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        return np.asarray(self.target) + offset

    def poses(self) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Training and test 3×4 world-to-camera matrices."""
        step = self._step()
        train, test = [], []
        for r, el in enumerate(self.elevations_deg):
            stagger = 0.5 * step * (r % 2)
            for k in range(self.views_per_ring):
                az = self.azimuth_start_deg + k * step + stagger
                train.append(look_at(self._center(az, el), np.asarray(self.target)))
        rings = len(self.elevations_deg)
        gaps = self.views_per_ring if abs(self.azimuth_span_deg - 360.0) < 1e-9 else self.views_per_ring - 1
        for k in range(self.n_test):
            r = k % rings
            per_ring = -(-self.n_test // rings)
            gap = int((k // rings + 0.5) * gaps / per_ring) % max(gaps, 1)
            az = self.azimuth_start_deg + (gap + 0.5) * step + 0.5 * step * (r % 2)
            test.append(look_at(self._center(az, self.elevations_deg[r]), np.asarray(self.target)))
        return train, test


@dataclass(frozen=True)
class AerialRig:
    """A UAV block: a nadir grid at ``nadir_height_m`` and oblique passes at ``oblique_height_m``.

    area_m: (x, y) size of the nadir grid (centred on the origin); grid: (nx, ny) nadir stations.
    oblique_tilt_deg: tilt from nadir of the oblique views; oblique_per_side: views per cardinal direction,
    spread along a line across the block, each looking at the block's centre line. n_test: held-out nadir
    views midway between grid nodes (plus one oblique when n_test > 1).
    """

    area_m: tuple[float, float]
    grid: tuple[int, int]
    nadir_height_m: float = 40.0
    oblique_height_m: float = 60.0
    oblique_tilt_deg: float = 45.0
    oblique_per_side: int = 4
    n_test: int = 4
    hfov_deg: float = 70.0

    def _oblique(self, side: int, s: float) -> np.ndarray:
        h = self.oblique_height_m
        back = h * np.tan(np.radians(self.oblique_tilt_deg))  # horizontal distance to the aimed ground point
        half = 0.5 * np.asarray(self.area_m)
        along = [(s * half[0], 0.0), (0.0, s * half[1]), (-s * half[0], 0.0), (0.0, -s * half[1])][side]
        heading = [np.array([0.0, 1.0]), np.array([-1.0, 0.0]), np.array([0.0, -1.0]), np.array([1.0, 0.0])][side]
        aim = np.array([along[0], along[1], 0.0])
        center = aim - back * np.array([heading[0], heading[1], 0.0]) + np.array([0.0, 0.0, h])
        return look_at(center, aim)

    def poses(self) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Training and test 3×4 world-to-camera matrices."""
        nx, ny = self.grid
        xs = np.linspace(-self.area_m[0] / 2, self.area_m[0] / 2, nx)
        ys = np.linspace(-self.area_m[1] / 2, self.area_m[1] / 2, ny)
        up = np.array([0.0, 1.0, 0.0])
        h = self.nadir_height_m
        train = [look_at((x, y, h), (x, y, 0.0), up) for y in ys for x in xs]
        spread = np.linspace(-0.8, 0.8, self.oblique_per_side) if self.oblique_per_side > 1 else np.zeros(1)
        train += [self._oblique(side, s) for side in range(4) for s in spread]
        test = []
        mx, my = (xs[:-1] + xs[1:]) / 2, (ys[:-1] + ys[1:]) / 2
        n_nadir = self.n_test - 1 if self.n_test > 1 else self.n_test
        for k in range(n_nadir):
            i = int((k + 0.5) * len(mx) / n_nadir) % max(len(mx), 1)
            j = int((k * 0.618 + 0.5) * len(my)) % max(len(my), 1)
            test.append(look_at((mx[i], my[j], h), (mx[i], my[j], 0.0), up))
        if self.n_test > 1:
            test.append(self._oblique(0, 0.8 / max(self.oblique_per_side - 1, 1)))
        return train, test


def build_cameras(rig: OrbitRig | AerialRig, width: int, height: int, origin: np.ndarray) -> tuple[Cameras, Cameras]:
    """Training and test :class:`Cameras` (one shared PINHOLE camera, id 1) for a rig at an image size.

    Training images are named ``train_###.png`` and test images ``test_###.png`` (image ids from 1).
    """
    camera = pinhole_from_fov(width, height, rig.hfov_deg)
    train_poses, test_poses = rig.poses()
    if not train_poses:
        raise ConfigError("the rig produced no training views; raise the number of views")

    def views(poses: list[np.ndarray], prefix: str) -> dict[int, View]:
        return {i + 1: View.from_matrix(i + 1, f"{prefix}_{i:03d}.png", 1, m) for i, m in enumerate(poses)}

    return (
        Cameras({1: camera}, views(train_poses, "train"), origin),
        Cameras({1: camera}, views(test_poses, "test"), origin),
    )
