"""Splat-surface points (fusion.splat_surface) on analytic scenes: flat Gaussians on a known plane seen by a ring of
cameras give points on the plane with a σ that covers their error; a layer only one view sees and a virtual layer
behind a mirror plane are rejected."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from test_train_trainer import ring_cameras

from core.cameras import Cameras
from core.errors import ConfigError, DataError
from core.gaussians import SH_C0, GaussianSet
from fusion.splat_surface import SplatSurfaceOptions, front_depths_from_points, splat_surface_points


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def layer(z: float, half: float = 0.45, n_side: int = 30, jitter: float = 0.0, seed: int = 0) -> GaussianSet:
    """Opaque flat Gaussians (σ ≈ 0.8 spacing, 0.2 mm thick) on a grid over the plane z = ``z`` within |x|, |y| <=
    half, each moved along z by N(0, ``jitter``) metres."""
    rng = np.random.default_rng(seed)
    g = np.linspace(-half, half, n_side)
    x, y = np.meshgrid(g, g)
    n = x.size
    sigma = 0.8 * (g[1] - g[0])
    means = np.stack([x.ravel(), y.ravel(), z + rng.normal(0, jitter, n) if jitter else np.full(n, z)], 1)
    colours = rng.uniform(0.1, 0.9, (n, 3))
    return GaussianSet(means, np.tile(np.log([sigma, sigma, 2e-4]), (n, 1)), np.tile([1.0, 0, 0, 0], (n, 1)),
                       np.full(n, 4.0), (colours - 0.5) / SH_C0)  # fmt: skip


def all_masks(cams: Cameras) -> dict[str, np.ndarray]:
    return {v.name: np.ones((cams.camera_of(v).height, cams.camera_of(v).width), bool) for v in cams}


def plane_depths(cams: Cameras, z: float) -> dict[str, np.ndarray]:
    """Per view, the exact camera z-depth of the plane z = ``z`` through every pixel centre (0 where it misses)."""
    out = {}
    for v in cams:
        cam = cams.camera_of(v)
        K = cam.K()
        u, w = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
        rays = np.stack([(u - K[0, 2]) / K[0, 0], (w - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
        d = rays @ v.rotation  # world direction of each ray (camera z = 1)
        t = (z - v.center[2]) / np.where(np.abs(d[..., 2]) > 1e-12, d[..., 2], 1e-12)
        out[v.name] = np.where(t > 0, t, 0.0)
    return out


def test_points_of_flat_splats_on_a_plane_lie_on_it_and_their_sigma_covers_the_error() -> None:
    """Splats moved along the normal by N(0, 5 mm): the rendered plane depth differs per view. The fused points lie
    within 2.5 mm of the plane on average (1.9 mm measured), their normals are the plane's, and ±2σ (the 95 %
    interval) holds at least 90 % of the true distances (σ the model's, :func:`fusion.splat_surface.sigma_model`;
    the spread alone held 97 %, median 2.2 mm, above its 0.1-px floor)."""
    cams = ring_cameras(6, width=96, height=72)
    splats = layer(0.0, jitter=0.005)
    pts = splat_surface_points(splats, cams, all_masks(cams))
    assert len(pts) > 1500 and pts.counts["kept"] == len(pts)
    assert pts.positions.dtype == np.float64 and pts.sigma.dtype == np.float64
    err = np.abs(pts.positions[:, 2])
    assert err.mean() < 2.5e-3 and err.max() < 0.015, (err.mean(), err.max())
    assert np.all(np.abs(pts.positions[:, :2]) < 0.45 + 0.08)  # alpha >= 0.5 reaches ~1σ past the last centres
    assert np.all(pts.normals[:, 2] > 0.99)  # +z: the side the cameras see
    coverage = float(np.mean(err <= 2 * pts.sigma))
    assert coverage >= 0.9, coverage
    assert np.all(pts.n_views >= 3) and np.all((pts.confidence > 0) & (pts.confidence <= 1))
    assert np.all((pts.colours >= 0) & (pts.colours <= 1))
    # fused, not emitted once per view: far fewer points than candidate pixels
    assert pts.counts["used"] > 0 and len(pts) < 0.5 * pts.counts["candidates"]
    # an exact plane (no jitter): exact points, the spread at its floor (0.1 px footprint, a few mm at 2 m with
    # f = 86 px); σ is the model's (its footprint term: 1.5 footprints ≈ 3–4 cm at these coarse pixels)
    exact = splat_surface_points(layer(0.0), cams, all_masks(cams))
    assert np.abs(exact.positions[:, 2]).max() < 1e-4 and exact.spread.max() < 5e-3
    assert np.all(exact.sigma >= exact.spread) and np.all(exact.sigma <= 2.0 * exact.footprint)


def test_median_depth_and_a_stricter_k() -> None:
    cams = ring_cameras(6, width=96, height=72)
    splats = layer(0.0)
    median = splat_surface_points(splats, cams, all_masks(cams), options=SplatSurfaceOptions(depth="median"))
    # the median depth is the median Gaussian's *centre* depth: on a plane seen at 30° it is off by up to the
    # spacing (3 cm) × the slope; the plane depth is exact
    err = np.abs(median.positions[:, 2])
    assert len(median) > 1000 and err.mean() < 0.03 and err.max() < 0.06
    strict = splat_surface_points(splats, cams, all_masks(cams), options=SplatSurfaceOptions(min_agreeing=4))
    loose = splat_surface_points(splats, cams, all_masks(cams), options=SplatSurfaceOptions(min_agreeing=1))
    assert np.all(strict.n_views >= 5) and strict.counts["kept"] < loose.counts["kept"]


def test_a_layer_only_one_view_sees_is_rejected() -> None:
    """A small layer 0.3 m in front of camera 0, facing it, outside every other camera's view: its pixels in view 0
    find no other view that agrees; the plane behind stays."""
    cams = ring_cameras(6, width=96, height=72)
    v0 = next(iter(cams))
    R, c = v0.rotation, v0.center
    floater = layer(0.0, half=0.04, n_side=8)
    floater.means = c + (floater.means + np.array([0.0, 0.0, 0.3])) @ R  # camera-0 frame → local
    for v in list(cams)[1:]:  # no other camera sees it
        uv, z = cams.project(v, floater.means)
        cam = cams.camera_of(v)
        assert not np.any(
            (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        )
    floater.quats = np.tile(_quat_of(R.T), (len(floater), 1))
    both = GaussianSet(*(np.concatenate([getattr(floater, k), getattr(layer(0.0), k)]) for k in
                         ("means", "log_scales", "quats", "logit_opacities", "sh_dc")))  # fmt: skip
    pts = splat_surface_points(both, cams, all_masks(cams))
    near_floater = np.linalg.norm(pts.positions - floater.means.mean(0), axis=1) < 0.2
    assert not near_floater.any() and pts.counts["inconsistent"] > 500
    z = np.abs(pts.positions[:, 2])  # the plane; a few at the floater's silhouette blend its plane with the floor's
    assert len(pts) > 1000 and np.mean(z < 1e-4) > 0.99 and z.max() < 0.01


def test_a_virtual_layer_behind_a_mirror_plane_is_rejected_with_the_front_surface() -> None:
    """The reflection of a textured floor in a mirror at z = 0 is a consistent layer at z = −0.3: every view agrees
    on it, so without the mirror's own surface it is kept; with the front depth of z = 0 (exact, or from points on
    the mirror's surface) it is a virtual image and nothing is kept."""
    cams = ring_cameras(6, width=96, height=72)
    virtual = layer(-0.3, half=0.3)
    masks = all_masks(cams)
    kept = splat_surface_points(virtual, cams, masks)
    assert len(kept) > 500 and np.abs(kept.positions[:, 2] + 0.3).max() < 1e-4
    rejected = splat_surface_points(virtual, cams, masks, front_depths=plane_depths(cams, 0.0))
    assert len(rejected) == 0 and rejected.counts["virtual"] > 1000
    g = np.linspace(-1.0, 1.0, 400)
    mirror = np.stack([*np.meshgrid(g, g), np.zeros((400, 400))], -1).reshape(-1, 3)
    from_points = splat_surface_points(virtual, cams, masks, front_depths=front_depths_from_points(mirror, cams))
    assert len(from_points) < 0.02 * len(kept)
    # a real surface in front of (or on) the mirror plane is not virtual
    real = splat_surface_points(layer(0.0, half=0.3), cams, masks, front_depths=plane_depths(cams, 0.0))
    assert len(real) > 500 and real.counts["virtual"] == 0


def test_bad_inputs() -> None:
    cams = ring_cameras(3)
    with pytest.raises(ConfigError):
        SplatSurfaceOptions(min_agreeing=0)
    with pytest.raises(ConfigError):
        SplatSurfaceOptions(depth="mean")
    with pytest.raises(DataError, match="mask"):
        splat_surface_points(layer(0.0), cams, {v.name: np.ones((5, 5), bool) for v in cams})
    empty = splat_surface_points(layer(0.0), cams, {v.name: np.zeros((48, 64), bool) for v in cams})
    assert len(empty) == 0 and empty.positions.shape == (0, 3)


def _quat_of(R: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of a rotation matrix (R with trace > −1)."""
    w = math.sqrt(max(1.0 + np.trace(R), 1e-12)) / 2
    return np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)])
