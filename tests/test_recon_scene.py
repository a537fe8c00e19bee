"""A small synthetic scene with exact ground truth for the recon tests (analytic ray/box casting in float64).

A textured ground plane with a textured box and a textureless slab, seen by an orbit of pinhole cameras.
Textures are procedural value noise on world coordinates, so every view sees the same surface pattern.
The module also checks itself (rendered depth against the analytic plane depth). It needs numpy alone, so that the
GPU tests that build on it run on a machine without open3d (bench/run_gpu_paths.sh).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from core.cameras import Camera, Cameras, View

TEXTURED, TEXTURELESS = 0, 1


@dataclass
class Scene:
    cameras: Cameras
    images: dict[str, np.ndarray]  # name -> (H, W, 3) uint8
    depths: dict[str, np.ndarray]  # name -> (H, W) float64 z-depth at pixel centres, inf = background
    materials: dict[str, np.ndarray]  # name -> (H, W) int, -1 = background
    boxes: list[tuple[np.ndarray, np.ndarray]]  # axis-aligned boxes (min corner, max corner), metres
    gt_points: np.ndarray  # (M, 3) dense surface samples
    gt_material: np.ndarray  # (M,)
    size: float  # scene extent (m)


def _noise(p: np.ndarray, seed: int = 0) -> np.ndarray:
    """Multi-octave value noise in [0, 1] at world points (N, 3) (smooth, deterministic)."""
    rng = np.random.default_rng(seed)
    out = np.zeros(len(p))
    amp_sum = 0.0
    for octave, freq in enumerate((6.0, 13.0, 29.0)):
        table = rng.random(4096)
        q = p * freq
        i0 = np.floor(q).astype(np.int64)
        f = q - i0
        f = f * f * (3 - 2 * f)
        acc = np.zeros(len(p))
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    h = (i0[:, 0] + dx) * 73856093 ^ (i0[:, 1] + dy) * 19349663 ^ (i0[:, 2] + dz) * 83492791
                    w = (
                        (f[:, 0] if dx else 1 - f[:, 0])
                        * (f[:, 1] if dy else 1 - f[:, 1])
                        * (f[:, 2] if dz else 1 - f[:, 2])
                    )
                    acc += w * table[h % 4096]
        amp = 0.5**octave
        out += amp * acc
        amp_sum += amp
    return out / amp_sum


def _sample_surface(vertices: np.ndarray, triangles: np.ndarray, count: int, seed: int) -> np.ndarray:
    """Area-uniform random points (count, 3) on a triangle mesh."""
    rng = np.random.default_rng(seed)
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    tri = rng.choice(len(area), count, p=area / area.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    return a[tri] * (1 - s)[:, None] + b[tri] * (s * (1 - r2))[:, None] + c[tri] * (s * r2)[:, None]


def _look_at(center: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """3×4 world-to-camera (OpenCV axes) for a camera at ``center`` looking at ``target``."""
    z = target - center
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return np.concatenate([R, (-R @ center)[:, None]], axis=1)


# (min corner, max corner, material): the ground plane, a textured box and a textureless slab (metres)
BOXES = (
    ((-2.0, -2.0, -0.02), (2.0, 2.0, 0.0), TEXTURED),
    ((-0.6, -0.5, 0.0), (0.4, 0.3, 0.6), TEXTURED),
    ((0.6, 0.3, 0.0), (1.3, 1.0, 0.25), TEXTURELESS),
)


def _box_triangles(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 8 corners and 12 triangles of an axis-aligned box (for area-uniform surface sampling)."""
    corners = np.array([[(hi if (k >> a) & 1 else lo)[a] for a in range(3)] for k in range(8)], dtype=np.float64)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return corners, np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])


def _cast(origins: np.ndarray, dirs: np.ndarray, boxes) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameter of the first hit (inf where none) and the index of the box hit (-1), by the slab method."""
    best_t = np.full(len(dirs), np.inf)
    best_box = np.full(len(dirs), -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
        for k, (lo, hi, _) in enumerate(boxes):
            t1, t2 = (np.asarray(lo) - origins) * inv, (np.asarray(hi) - origins) * inv
            near, far = np.minimum(t1, t2).max(axis=1), np.maximum(t1, t2).min(axis=1)
            hit = (near <= far) & (near > 0) & (near < best_t)
            best_t[hit], best_box[hit] = near[hit], k
    return best_t, best_box


def make_scene(num_views: int = 10, width: int = 200, height: int = 150, seed: int = 0, radius: float = 3.2) -> Scene:
    fx = 0.9 * width
    cam = Camera.pinhole(fx, fx, width / 2, height / 2, width, height)
    views = {}
    for k in range(num_views):
        a = 2 * np.pi * k / num_views
        c = np.array([radius * np.cos(a), radius * np.sin(a), 2.2 + 0.3 * np.sin(3 * a)])
        views[k + 1] = View.from_matrix(k + 1, f"img_{k:03d}.png", 1, _look_at(c, np.array([0.0, 0.0, 0.2])))
    cams = Cameras({1: cam}, views)
    rows, cols = np.mgrid[0:height, 0:width]
    pix = np.stack([cols + 0.5, rows + 0.5], axis=-1).reshape(-1, 2).astype(np.float64)
    dirs_cam = cam.unproject(pix)  # unit z
    box_material = np.array([m for _, _, m in BOXES])
    images, depths, materials = {}, {}, {}
    for view in cams:
        dirs = dirs_cam @ view.rotation  # world directions
        origin = np.broadcast_to(view.center, dirs.shape)
        t, box = _cast(origin, dirs, BOXES)
        ok = np.isfinite(t)
        pts = origin + dirs * np.where(ok, t, 0)[:, None]
        mat = np.where(ok, box_material[box], -1)
        val = _noise(pts, seed)
        val = np.where(mat == TEXTURELESS, 0.55, val)
        shade = 0.25 + 0.7 * val
        rgb = np.stack([shade, shade * 0.9 + 0.05, shade * 0.8 + 0.1], axis=1)
        rgb[~ok] = 0.0
        images[view.name] = (np.clip(rgb, 0, 1) * 255).round().astype(np.uint8).reshape(height, width, 3)
        depths[view.name] = np.where(ok, t, np.inf).reshape(height, width)  # dirs have unit z: t is z-depth
        materials[view.name] = mat.reshape(height, width)
    meshes = [_box_triangles(np.asarray(lo, float), np.asarray(hi, float)) for lo, hi, _ in BOXES]
    vertices = np.concatenate([v for v, _ in meshes])
    triangles = np.concatenate([f + 8 * k for k, (_, f) in enumerate(meshes)])
    pts = _sample_surface(vertices, triangles, 200_000, seed + 1)
    # material of a sample: inside the slab's bounds
    inslab = (
        (pts[:, 0] >= 0.6 - 1e-6)
        & (pts[:, 0] <= 1.3 + 1e-6)
        & (pts[:, 1] >= 0.3 - 1e-6)
        & (pts[:, 1] <= 1.0 + 1e-6)
        & (pts[:, 2] >= -1e-6)
        & (pts[:, 2] <= 0.25 + 1e-6)
    )
    keep = pts[:, 2] >= -1e-6  # top of the ground plane and objects
    gt_mat = np.where(inslab, TEXTURELESS, TEXTURED)
    boxes = [(np.asarray(lo, float), np.asarray(hi, float)) for lo, hi, _ in BOXES]
    return Scene(cams, images, depths, materials, boxes, pts[keep], gt_mat[keep], 4.0)


def write_scene(scene: Scene, root: Path, num_points: int = 800, seed: int = 0) -> Path:
    """Write images/ and sparse/0 (true cameras + GT surface points with tracks) under ``root``."""
    import cv2
    import pycolmap

    from recon.model import to_reconstruction

    (root / "images").mkdir(parents=True, exist_ok=True)
    for name, img in scene.images.items():
        cv2.imwrite(str(root / "images" / name), img[:, :, ::-1])
    rec = to_reconstruction(scene.cameras)
    rng = np.random.default_rng(seed)
    pts = scene.gt_points[rng.choice(len(scene.gt_points), num_points, replace=False)]
    obs: dict[int, list[np.ndarray]] = {v.image_id: [] for v in scene.cameras}
    tracks = []
    for X in pts:
        seen = []
        for v in scene.cameras:
            uv, z = scene.cameras.project(v, X[None])
            u, vv = uv[0]
            cam = scene.cameras.camera_of(v)
            if not (0 <= u < cam.width and 0 <= vv < cam.height and z[0] > 0):
                continue
            d = scene.depths[v.name][int(vv), int(u)]
            if abs(d - z[0]) < 0.02 * z[0]:
                seen.append((v.image_id, len(obs[v.image_id])))
                obs[v.image_id].append(uv[0])
        tracks.append(seen)
    # rebuild images with their 2D points, then add tracks
    rec2 = pycolmap.Reconstruction()
    for cam in rec.cameras.values():
        rec2.add_camera_with_trivial_rig(cam)
    for v in scene.cameras:
        kp = np.asarray(obs[v.image_id], dtype=np.float64).reshape(-1, 2)
        im = pycolmap.Image(name=v.name, keypoints=kp, camera_id=v.camera_id, image_id=v.image_id)
        rec2.add_image_with_trivial_frame(im, pycolmap.Rigid3d(v.cam_from_world))
    for X, seen in zip(pts, tracks, strict=True):
        if len(seen) < 2:
            continue
        track = pycolmap.Track()
        for iid, idx in seen:
            track.add_element(iid, idx)
        rec2.add_point3D(X, track, np.array([128, 128, 128], dtype=np.uint8))
    out = root / "sparse" / "0"
    out.mkdir(parents=True, exist_ok=True)
    rec2.write(str(out))
    return root


@pytest.fixture(scope="module")
def tiny_scene() -> Scene:
    return make_scene(num_views=8, width=160, height=120)


def test_scene_depth_matches_analytic_plane(tiny_scene: Scene):
    """Rendered z-depth on the ground plane equals the analytic ray/plane intersection."""
    view = next(iter(tiny_scene.cameras))
    cam = tiny_scene.cameras.camera_of(view)
    mat = tiny_scene.materials[view.name]
    depth = tiny_scene.depths[view.name]
    rows, cols = np.nonzero(mat == TEXTURED)
    pix = np.stack([cols + 0.5, rows + 0.5], axis=1).astype(np.float64)
    world = tiny_scene.cameras.unproject(view, pix, depth[rows, cols])
    on_plane = np.abs(world[:, 2]) < 1e-3
    assert on_plane.sum() > 1000
    d = view.rotation.T @ np.array([0, 0, 1.0])  # optical axis in world
    rays = cam.unproject(pix[on_plane]) @ view.rotation  # world directions with unit z in camera
    t = -view.center[2] / rays[:, 2]
    rel = np.abs(depth[rows, cols][on_plane] - t) / t
    # float32 ray casting; pixels on the objects' bottom edges (|z| < 1 mm) are not on the plane
    assert np.median(rel) < 1e-5 and np.mean(rel < 1e-4) > 0.99
    assert d.shape == (3,)


def test_scene_sparse_model_has_tracks(tiny_scene: Scene, tmp_path: Path):
    import pycolmap

    write_scene(tiny_scene, tmp_path, num_points=200)
    rec = pycolmap.Reconstruction(str(tmp_path / "sparse" / "0"))
    assert rec.num_reg_images() == 8
    assert rec.num_points3D() > 100
    assert rec.compute_mean_reprojection_error() < 1e-6
