"""render_gaussian_set: local origins, large coordinates and camera models."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.cameras import Camera, CameraModel, View
from core.errors import ConfigError
from core.gaussians import GaussianSet
from fusion.render import render, render_gaussian_set
from fusion.render.synthetic import random_scene


def _set_and_view(origin, seed=51):
    scene = random_scene(300, 40, 30, seed=seed, sh_degree=1, dtype=torch.float64)
    gs = GaussianSet(
        means=scene.means.numpy(),
        log_scales=scene.log_scales.numpy(),
        quats=scene.quats.numpy(),
        logit_opacities=scene.logit_opacities.numpy(),
        sh_dc=scene.sh_coeffs[:, 0].numpy(),
        sh_rest=scene.sh_coeffs[:, 1:].numpy(),
        origin=origin,
    )
    view = View.from_matrix(1, "a.png", 1, scene.viewmat[:3].numpy())
    K = scene.K.numpy()
    return scene, gs, view, Camera.pinhole(K[0, 0], K[1, 1], K[0, 2], K[1, 2], 40, 30)


def test_matches_direct_render_at_small_coordinates():
    scene, gs, view, camera = _set_and_view(np.zeros(3))
    ours = render_gaussian_set(gs, camera, view, backend="cpu").to_numpy()
    direct = render(*[p.float() for p in scene.params], scene.viewmat.float(), scene.K.float(), 40, 30, backend="cpu")
    np.testing.assert_allclose(ours.colour, direct.colour.numpy(), atol=1e-4)


def test_large_coordinates_keep_precision():
    """The same scene 5e6 m away from the origin renders identically: shifts happen in float64.

    A naive float32 cast of such coordinates would quantise positions to 0.5 m (image completely wrong).
    """
    _, near, view, camera = _set_and_view(np.zeros(3))
    far_origin = np.array([4.0e5, 5.6e6, 812.0])
    far = near.with_origin(far_origin)  # same world positions, means relative to the far origin
    assert np.abs(far.means).max() > 1e6
    a = render_gaussian_set(near, camera, view, cameras_origin=np.zeros(3), backend="cpu").to_numpy()
    b = render_gaussian_set(far, camera, view, cameras_origin=np.zeros(3), backend="cpu").to_numpy()
    np.testing.assert_allclose(a.colour, b.colour, atol=1e-4)
    # Both the Gaussians and the cameras far away, in their own (different) frames.
    world = near.with_origin(far_origin - 100.0)
    shifted_view = View(1, "a.png", 1, view.quat_wxyz, view.translation + view.rotation @ (far_origin + 50.0))
    c = render_gaussian_set(world, camera, shifted_view, cameras_origin=far_origin + 50.0, backend="cpu")
    np.testing.assert_allclose(a.colour, c.to_numpy().colour, atol=1e-4)


def test_distorted_cameras_refused_or_warned():
    _, gs, view, camera = _set_and_view(np.zeros(3))
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    distorted = Camera(CameraModel.OPENCV, 40, 30, [fx, fy, cx, cy, 0.1, 0.0, 0.0, 0.0])
    with pytest.raises(ConfigError, match="undistort"):
        render_gaussian_set(gs, distorted, view, backend="cpu")
    with pytest.warns(UserWarning, match="distortion ignored"):
        warned = render_gaussian_set(gs, distorted, view, backend="cpu", ignore_distortion=True).to_numpy()
    plain = render_gaussian_set(gs, camera, view, backend="cpu").to_numpy()
    np.testing.assert_array_equal(warned.colour, plain.colour)
