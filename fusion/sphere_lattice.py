"""Near-uniform lattices of unit directions (the golden-angle spiral), for sampling the sphere of view directions."""

from __future__ import annotations

import numpy as np


def fibonacci_sphere(count: int) -> np.ndarray:
    """``count`` unit vectors (count, 3) spread near-uniformly over the sphere: z steps evenly from near +1 to
    near −1, the azimuth turns by the golden angle each step; about ``4π / count`` steradians each."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    ring = np.sqrt(1.0 - z * z)
    azimuth = np.pi * (1.0 + np.sqrt(5.0)) * i
    return np.stack([np.cos(azimuth) * ring, np.sin(azimuth) * ring, z], axis=1)
