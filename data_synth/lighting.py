"""Sun and sky: the light of the synthetic scenes and the environment seen in reflections.

The environment map is analytic (a function of direction): a sky gradient with seeded noise clouds and a
sun glow above the horizon, and a tiled distant ground below it, so that mirrors reflect something textured
that moves with the viewpoint. All radiances are linear RGB.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from data_synth.textures import NoiseTable


def direction_from_angles(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector (3,) float64 pointing to azimuth (from +x towards +y) and elevation above the xy plane."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


@dataclass(frozen=True)
class Environment:
    """Sun (a directional light with hard shadows) plus a sky dome.

    sun_azimuth_deg, sun_elevation_deg: where the sun is (direction towards it).
    sun_rgb: irradiance scale of the sun on a surface facing it (linear, ~1 gives white for albedo 1).
    sky_zenith, sky_horizon: sky radiance at the zenith and at the horizon.
    ground_rgb: radiance of the distant ground below the horizon (two tones in tiles of ``ground_tile``).
    ambient: diffuse sky light on an upward-facing surface.
    seed: seed of the cloud noise.
    """

    sun_azimuth_deg: float = 35.0
    sun_elevation_deg: float = 50.0
    sun_rgb: tuple[float, float, float] = (1.0, 0.95, 0.88)
    sky_zenith: tuple[float, float, float] = (0.18, 0.32, 0.70)
    sky_horizon: tuple[float, float, float] = (0.70, 0.78, 0.90)
    ground_rgb: tuple[tuple[float, float, float], tuple[float, float, float]] = ((0.30, 0.26, 0.20), (0.12, 0.13, 0.10))
    ground_tile: float = 0.5
    ambient: tuple[float, float, float] = (0.28, 0.31, 0.36)
    seed: int = 0
    table: NoiseTable = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "table", NoiseTable(self.seed + 991))

    @property
    def sun_dir(self) -> np.ndarray:
        """Unit vector (3,) towards the sun."""
        return direction_from_angles(self.sun_azimuth_deg, self.sun_elevation_deg)

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        """Environment radiance (N, 3) float64 seen along unit directions (N, 3) that hit nothing."""
        d = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        up = d[:, 2]
        t = np.sqrt(np.clip(up, 0.0, 1.0))[:, None]
        sky = np.asarray(self.sky_horizon) * (1 - t) + np.asarray(self.sky_zenith) * t
        cloud = self.table.fbm(d * 3.0 + 5.0, octaves=4)
        cover = np.clip((cloud - 0.5) / 0.2, 0.0, 1.0)[:, None]
        sky = sky * (1 - 0.8 * cover) + 0.95 * cover
        sun = self.sun_dir
        cos_sun = np.clip(d[:, 0] * sun[0] + d[:, 1] * sun[1] + d[:, 2] * sun[2], 0.0, 1.0)
        sky = sky + np.asarray(self.sun_rgb) * (4.0 * cos_sun**2000 + 0.25 * cos_sun**16)[:, None]
        # Distant ground: tiles of the ray's footprint on a plane one unit below the viewer.
        q = d[:, :2] / np.maximum(-up, 0.02)[:, None] / self.ground_tile
        checker = ((np.floor(q[:, 0]).astype(np.int64) + np.floor(q[:, 1]).astype(np.int64)) & 1)[:, None]
        g0, g1 = (np.asarray(c) for c in self.ground_rgb)
        ground = np.where(checker == 1, g0, g1) * (0.8 + 0.4 * self.table.noise(np.c_[q, up * 0.0]))[:, None]
        return np.where((up >= 0.0)[:, None], sky, ground)

    def ambient_irradiance(self, normals: np.ndarray) -> np.ndarray:
        """Diffuse sky + ground-bounce light (N, 3) on surfaces with unit normals (N, 3)."""
        nz = np.asarray(normals, dtype=np.float64)[:, 2:3]
        return np.asarray(self.ambient) * (0.65 + 0.35 * nz)
