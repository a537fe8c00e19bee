"""Simulated LiDAR: terrestrial scanner stations or an airborne flight block, occlusion-aware by ray casting.

Each pulse is a ray from the scanner; its first hit on the mesh is the return (so occluded surfaces get no
points). The range-noise model adds Gaussian noise along the ray with standard deviation
``sqrt(sigma_m² + (sigma_rel · range)²)``; with both zero the points lie exactly on the float64 mesh.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from core.pointcloud import PointCloud
from data_synth.materials import Material
from data_synth.raytrace import RayTracer, linear_to_srgb8


@dataclass(frozen=True)
class RangeNoise:
    """Range noise: constant ``sigma_m`` (metres) plus ``sigma_rel`` × range, combined in quadrature."""

    sigma_m: float = 0.0
    sigma_rel: float = 0.0

    @property
    def enabled(self) -> bool:
        return self.sigma_m > 0 or self.sigma_rel > 0


@dataclass(frozen=True)
class TerrestrialScan:
    """Static scanner stations (x, y, z local metres), each sweeping a window around the direction to ``target``.

    azimuth_half_deg: half width of the horizontal window; elevation_deg: (min, max) vertical window;
    step_deg: angular step in both directions.
    """

    stations: tuple[tuple[float, float, float], ...]
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    azimuth_half_deg: float = 35.0
    elevation_deg: tuple[float, float] = (-45.0, 15.0)
    step_deg: float = 0.12

    def rays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Origins (N, 3), unit directions (N, 3) float64 and station index (N,) int32 of every pulse."""
        origins, dirs, ids = [], [], []
        for k, station in enumerate(self.stations):
            s = np.asarray(station, dtype=np.float64)
            to_target = np.asarray(self.target) - s
            az0 = np.degrees(np.arctan2(to_target[1], to_target[0]))
            az = np.radians(np.arange(-self.azimuth_half_deg, self.azimuth_half_deg + 1e-9, self.step_deg) + az0)
            el = np.radians(np.arange(self.elevation_deg[0], self.elevation_deg[1] + 1e-9, self.step_deg))
            a, e = np.meshgrid(az, el)
            d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)
            dirs.append(d)
            origins.append(np.broadcast_to(s, d.shape))
            ids.append(np.full(len(d), k, np.int32))
        return np.concatenate(origins), np.concatenate(dirs), np.concatenate(ids)


@dataclass(frozen=True)
class AirborneScan:
    """Parallel flight lines along x at ``altitude_m``, an across-track (y) scanning mirror.

    line_y_m: y of each flight line; x_range_m: (start, end) along the line; line_spacing_m: distance flown
    between scan lines; half_angle_deg: scan half angle; pulses_per_line: pulses across track per scan line.
    """

    line_y_m: tuple[float, ...]
    x_range_m: tuple[float, float]
    altitude_m: float = 80.0
    line_spacing_m: float = 0.4
    half_angle_deg: float = 35.0
    pulses_per_line: int = 400

    def rays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Origins (N, 3), unit directions (N, 3) float64 and flight-line index (N,) int32 of every pulse."""
        xs = np.arange(self.x_range_m[0], self.x_range_m[1] + 1e-9, self.line_spacing_m)
        ang = np.radians(np.linspace(-self.half_angle_deg, self.half_angle_deg, self.pulses_per_line))
        d = np.stack([np.zeros_like(ang), np.sin(ang), -np.cos(ang)], axis=1)
        origins, dirs, ids = [], [], []
        for k, y in enumerate(self.line_y_m):
            o = np.stack(
                [np.repeat(xs, len(ang)), np.full(len(xs) * len(ang), y), np.full(len(xs) * len(ang), self.altitude_m)],
                1,
            )
            origins.append(o)
            dirs.append(np.tile(d, (len(xs), 1)))
            ids.append(np.full(len(o), k, np.int32))
        return np.concatenate(origins), np.concatenate(dirs), np.concatenate(ids)


def simulate_lidar(
    tracer: RayTracer,
    scan: TerrestrialScan | AirborneScan,
    noise: RangeNoise,
    materials: Mapping[int, Material],
    rng: np.random.Generator,
    origin: np.ndarray,
) -> PointCloud:
    """The LiDAR cloud of ``scan`` over the tracer's mesh.

    Returns a :class:`PointCloud` in the local frame of ``origin`` with colours (the true sRGB albedo),
    float32 unit normals (the true face normals, facing the scanner) and fields ``material`` (int32),
    ``classification`` (uint8 ASPRS code), ``range_m`` (float32, true range), ``scanner`` (int32 station or line).
    """
    o, d, ids = scan.rays()
    hits = tracer.cast(o, d)
    keep = np.flatnonzero(hits.hit)
    t = hits.t[keep]
    if noise.enabled:
        sigma = np.sqrt(noise.sigma_m**2 + (noise.sigma_rel * t) ** 2)
        t_noisy = t + sigma * rng.standard_normal(len(t))
        points = o[keep] + t_noisy[:, None] * d[keep]
    else:
        points = hits.points[keep]
    mats = hits.material[keep]
    normals = hits.normal[keep]
    normals = np.where((np.sum(normals * d[keep], axis=1) > 0)[:, None], -normals, normals)
    albedo = np.zeros((len(keep), 3))
    las = np.zeros(len(keep), np.uint8)
    for mid in np.unique(mats).tolist():
        sel = mats == mid
        albedo[sel] = tracer.textures.albedo(materials[mid], hits.points[keep][sel], normals[sel])
        las[sel] = materials[mid].las_class
    return PointCloud(
        positions=points,
        origin=np.asarray(origin, dtype=np.float64),
        colors=linear_to_srgb8(albedo),
        normals=normals.astype(np.float32),
        fields={
            "material": mats.astype(np.int32),
            "classification": las,
            "range_m": t.astype(np.float32),
            "scanner": ids[keep].astype(np.int32),
        },
    )
