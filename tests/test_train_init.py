"""Seeds for new splats: SfM points in masks, needs_splats MVS points, ray samples at interpolated MVS depth."""

from __future__ import annotations

import numpy as np
import pytest

from core.cameras import Camera, Cameras, View
from core.errors import DataError
from fusion.train.init import InitOptions, fill_depth, points_in_masks, seed_splats, sfm_seeds


def one_camera() -> Cameras:
    """Camera at the origin looking down +z, 100×80 px, focal 100, principal point (50, 40)."""
    cam = Camera.pinhole(100.0, 100.0, 50.0, 40.0, 100, 80)
    return Cameras({1: cam}, {1: View(1, "a.png", 1, np.array([1.0, 0, 0, 0]), np.zeros(3))})


def centre_mask() -> np.ndarray:
    m = np.zeros((80, 100), bool)
    m[30:50, 40:60] = True
    return m


def test_points_in_masks_follows_the_projection() -> None:
    pts = np.array([[0.0, 0.0, 2.0], [0.5, 0.0, 2.0], [0.0, 0.0, -2.0], [0.19, 0.19, 2.0]])
    # pixels: (50, 40) in, (75, 40) out, behind the camera, (59.5, 49.5) in (last mask pixel)
    np.testing.assert_array_equal(points_in_masks(one_camera(), {"a.png": centre_mask()}, pts), [1, 0, 0, 1])


def test_fill_depth_closes_holes_in_a_constant_surface() -> None:
    depth = np.full((60, 60), 3.0)
    valid = np.ones((60, 60), bool)
    valid[20:40, 20:40] = False
    filled = fill_depth(np.where(valid, depth, 0.0), valid)
    np.testing.assert_allclose(filled, 3.0, rtol=1e-12)
    lonely = np.zeros((60, 60), bool)
    lonely[0, 0] = True
    out = fill_depth(np.where(lonely, 1.0, 0.0), lonely, sigmas=(2,))
    assert np.isnan(out[59, 59]) and out[1, 1] == pytest.approx(1.0)


def test_ray_seeds_land_on_the_surface_around_a_hole() -> None:
    """Trusted MVS points on the plane z = 2 everywhere except behind the mask (an MVS hole): the ray seeds in the
    hole must lie on that plane."""
    cams = one_camera()
    xs, ys = np.meshgrid(np.linspace(-1.2, 1.2, 241), np.linspace(-1.0, 1.0, 201))
    plane = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 2.0)])
    uv, _ = cams.project(cams.views[1], plane)
    mask = centre_mask()
    col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    hole = (col >= 40) & (col < 60) & (row >= 30) & (row < 50)
    mvs = plane[~hole]
    image = np.full((80, 100, 3), 128, np.uint8)
    res = seed_splats(cams, {"a.png": mask}, {"a.png": image}, mvs, np.zeros((len(mvs), 3), np.uint8),
                      np.zeros(len(mvs), bool), options=InitOptions(rays_per_view=50))  # fmt: skip
    assert res.from_rays == 50 and res.from_mvs == 0 and res.from_sfm == 0
    np.testing.assert_allclose(res.gaussians.means[:, 2], 2.0, atol=1e-9)
    assert points_in_masks(cams, {"a.png": mask}, res.gaussians.means).all()
    np.testing.assert_allclose(res.gaussians.base_colors, 128 / 255, atol=1e-6)


def test_seed_sources_are_counted() -> None:
    cams = one_camera()
    mvs = np.array([[0.0, 0.0, 2.0], [1.0, 1.0, 2.0], [0.05, 0.0, 2.0]])
    needs = np.array([True, False, True])
    sfm = np.array([[0.02, 0.02, 2.0], [0.9, 0.0, 2.0]])  # first inside the mask, second outside
    res = seed_splats(cams, {"a.png": centre_mask()}, None, mvs, np.full((3, 3), 200, np.uint8), needs, sfm,
                      np.full((2, 3), 50, np.uint8))  # fmt: skip
    assert (res.from_mvs, res.from_sfm, res.from_rays) == (2, 1, 0)
    assert len(res.gaussians) == 3
    # 3DGS init: σ = mean distance to the 3 nearest other seeds-or-trusted points, isotropic
    assert np.all(res.gaussians.log_scales[:, 0] == res.gaussians.log_scales[:, 1])
    with pytest.raises(DataError):
        seed_splats(cams, {"a.png": centre_mask()}, None, mvs, np.zeros((3, 3), np.uint8), needs[:2])


def test_sfm_seeds_for_the_baseline() -> None:
    pts = np.random.default_rng(0).normal(size=(50, 3))
    gs = sfm_seeds(pts, np.full((50, 3), 255, np.uint8), np.zeros(3))
    assert len(gs) == 50 and np.allclose(gs.base_colors, 1.0) and np.all(np.isfinite(gs.log_scales))
    np.testing.assert_allclose(gs.opacities, 0.1, rtol=1e-5)
