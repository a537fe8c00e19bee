"""Statistics that show a scene is a meaningful test: cross-view colour spread and image gradients per material.

Cross-view colour standard deviation: for random surface points of each material (area-weighted), find the
training views that truly see the point (ray from the camera centre hits it first, not grazing), observe
its colour in each and take the standard deviation across views (8-bit sRGB units, mean of R, G, B), averaged
over points seen by at least ``min_views`` views. Two observations are reported:

- ``exact``: the colour of a single ray traced from the camera centre exactly through the point. Lambertian
  surfaces are view-independent by construction, so this is 0 for them up to 8-bit rounding; mirror, glass
  and metal vary with the viewpoint.
- ``image``: the rendered photo bilinearly sampled at the point's exact projection: what MVS sees, including
  supersampling blur and texture resampling.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from core.cameras import Cameras
from data_synth.geometry import SceneMesh
from data_synth.materials import Material
from data_synth.raytrace import RayTracer, linear_to_srgb8


@dataclass(frozen=True)
class ColorSpread:
    """Per material name: mean cross-view colour std (8-bit units) by exact rays and by image sampling,
    and the number of points that entered the mean."""

    exact: dict[str, float]
    image: dict[str, float]
    points: dict[str, int]


def sample_surface(
    mesh: SceneMesh, material_id: int, count: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` area-uniform points (count, 3) float64 on faces of ``material_id`` and their unit normals."""
    faces = np.flatnonzero(mesh.face_material == material_id)
    areas = mesh.face_areas()[faces]
    if len(faces) == 0 or areas.sum() <= 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    pick = faces[rng.choice(len(faces), size=count, p=areas / areas.sum())]
    r1, r2 = rng.random(count), rng.random(count)
    flip = r1 + r2 > 1
    r1, r2 = np.where(flip, 1 - r1, r1), np.where(flip, 1 - r2, r2)
    tri = mesh.triangles[pick]
    pts = tri[:, 0] + r1[:, None] * (tri[:, 1] - tri[:, 0]) + r2[:, None] * (tri[:, 2] - tri[:, 0])
    return pts, mesh.face_normals()[pick]


def _bilinear(image: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Bilinear colours (N, 3) float64 of an (H, W, 3) image at COLMAP pixel coordinates (N, 2)."""
    map_x = (pixels[:, 0] - 0.5).astype(np.float32).reshape(-1, 1)
    map_y = (pixels[:, 1] - 0.5).astype(np.float32).reshape(-1, 1)
    out = cv2.remap(image.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3).astype(np.float64)


def color_spread(
    tracer: RayTracer,
    cameras: Cameras,
    images: Mapping[str, np.ndarray],
    materials: Sequence[Material],
    rng: np.random.Generator,
    points_per_material: int = 300,
    min_views: int = 3,
    min_cos: float = 0.25,
) -> ColorSpread:
    """Cross-view colour spread per material over the training views (see the module docstring).

    ``images`` maps image names to (H, W, 3) uint8 photos; ``min_cos`` rejects grazing observations.
    """
    mesh = tracer.mesh
    tol = 1e-6 * float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    exact_out, image_out, count_out = {}, {}, {}
    views = list(cameras)
    for mat in materials:
        pts, normals = sample_surface(mesh, mat.id, points_per_material, rng)
        if len(pts) == 0:
            continue
        obs_exact = np.full((len(views), len(pts), 3), np.nan)
        obs_image = np.full((len(views), len(pts), 3), np.nan)
        for v, view in enumerate(views):
            cam = cameras.camera_of(view)
            pix, z = cameras.project(view, pts)
            inside = (z > 0) & (pix[:, 0] >= 1) & (pix[:, 0] <= cam.width - 1) & (pix[:, 1] >= 1)
            inside &= pix[:, 1] <= cam.height - 1
            to_pt = pts - view.center
            dist = np.linalg.norm(to_pt, axis=1)
            dirs = to_pt / dist[:, None]
            inside &= np.abs(np.sum(dirs * normals, axis=1)) > min_cos
            idx = np.flatnonzero(inside)
            if len(idx) == 0:
                continue
            origins = np.broadcast_to(view.center, (len(idx), 3)).copy()
            hits = tracer.cast(origins, dirs[idx])
            seen = idx[hits.hit & (np.abs(hits.t - dist[idx]) <= tol + 1e-9 * dist[idx])]
            if len(seen) == 0:
                continue
            origins = np.broadcast_to(view.center, (len(seen), 3)).copy()
            obs_exact[v, seen] = linear_to_srgb8(tracer.radiance(origins, dirs[seen])).astype(np.float64)
            obs_image[v, seen] = _bilinear(images[view.name], pix[seen])
        n_seen = np.sum(~np.isnan(obs_exact[..., 0]), axis=0)
        keep = n_seen >= min_views
        count_out[mat.name] = int(keep.sum())
        if keep.any():
            exact_out[mat.name] = float(np.nanstd(obs_exact[:, keep], axis=0).mean())
            image_out[mat.name] = float(np.nanstd(obs_image[:, keep], axis=0).mean())
    return ColorSpread(exact_out, image_out, count_out)


@dataclass(frozen=True)
class GradientStats:
    """Per material name: mean and median Sobel gradient magnitude (grey levels per pixel, 0-255 scale).

    The median ignores the few crease and shadow-edge pixels inside a region (a box's roof/wall edge has
    the same label on both sides), so it reads ~0 for textureless surfaces."""

    mean: dict[str, float]
    median: dict[str, float]


def gradient_by_material(
    images: Sequence[np.ndarray], labels: Sequence[np.ndarray], materials: Sequence[Material]
) -> GradientStats:
    """Sobel gradient magnitude statistics inside each material's regions.

    Only pixels whose 5×5 neighbourhood carries the same label count, so object outlines do not enter.
    """
    parts: dict[str, list[np.ndarray]] = {m.name: [] for m in materials}
    kernel = np.ones((5, 5), np.uint8)
    for image, lab in zip(images, labels, strict=True):
        grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
        gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3) / 8.0
        mag = np.sqrt(gx * gx + gy * gy)
        for m in materials:
            interior = cv2.erode((lab == m.id).astype(np.uint8), kernel).astype(bool)
            parts[m.name].append(mag[interior])
    mean, median = {}, {}
    for name, chunks in parts.items():
        values = np.concatenate(chunks) if chunks else np.zeros(0, np.float32)
        if len(values):
            mean[name] = float(values.astype(np.float64).mean())
            median[name] = float(np.median(values))
    return GradientStats(mean, median)
