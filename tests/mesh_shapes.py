"""Gaussian sets on analytic surfaces (sphere, plane) for the fusion.mesh tests; truth is the analytic surface."""

from __future__ import annotations

import numpy as np

from core.gaussians import SH_C0, GaussianSet, logit
from fusion.convert import Source, quats_z_to


def fibonacci_sphere(n: int, radius: float = 1.0) -> np.ndarray:
    """(n, 3) float64 nearly uniform points on a sphere of ``radius`` centred at 0."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z * z)
    phi = np.pi * (1 + 5**0.5) * i
    return radius * np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def surfels(
    points: np.ndarray,
    normals: np.ndarray,
    sigma: float,
    thickness: float = 0.1,
    alpha: float = 0.95,
    source: int = Source.MVS,
    origin: np.ndarray | None = None,
    color: tuple[float, float, float] = (0.8, 0.4, 0.2),
) -> GaussianSet:
    """Flat Gaussians (σ, σ, thickness·σ) whose third axis is the given normal, one colour, one opacity."""
    n = len(points)
    sh_dc = np.tile((np.asarray(color) - 0.5) / SH_C0, (n, 1))
    return GaussianSet(
        means=points,
        log_scales=np.tile(np.log([sigma, sigma, thickness * sigma]), (n, 1)),
        quats=quats_z_to(normals),
        logit_opacities=np.full(n, logit(np.array([alpha]))[0]),
        sh_dc=sh_dc,
        origin=np.zeros(3) if origin is None else origin,
        fields={"source": np.full(n, source, dtype=np.uint8)},
    )


def sphere_gaussians(n: int = 3000, radius: float = 0.5, **kwargs: object) -> GaussianSet:
    """MVS-like surfels on a sphere, σ about the point spacing, normals outward (trusted)."""
    pts = fibonacci_sphere(n, radius)
    spacing = radius * np.sqrt(4 * np.pi / n)
    return surfels(pts, pts / radius, sigma=0.6 * spacing, **kwargs)  # type: ignore[arg-type]


def sphere_distance(points: np.ndarray, radius: float) -> np.ndarray:
    """Exact unsigned distance (N,) of points (N, 3) to the sphere of ``radius`` centred at 0."""
    return np.abs(np.linalg.norm(points, axis=1) - radius)


def mesh_surface_samples(vertices: np.ndarray, triangles: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) points uniform over the mesh surface (area-weighted triangles, uniform barycentrics)."""
    rng = np.random.default_rng(seed)
    v = vertices[triangles]
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    tri = rng.choice(len(triangles), size=n, p=area / area.sum())
    a, b = rng.random(n), rng.random(n)
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    t = v[tri]
    return t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])


def distance_to_mesh(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(N,) unsigned distances of points to a triangle mesh (open3d ray-casting scene, float32 inside)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy().astype(np.float64)
