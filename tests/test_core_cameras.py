"""Camera models: projection/unprojection round trips, distortion inversion, poses — against analytic truth."""

import numpy as np
import pytest
import torch

from core import Camera, CameraModel, Cameras, ConfigError, DataError, View
from core.cameras import quat_to_rotmat, rotmat_to_quat

CAMERAS = {
    CameraModel.SIMPLE_PINHOLE: [500.0, 320.0, 240.0],
    CameraModel.PINHOLE: [500.0, 480.0, 318.0, 243.0],
    CameraModel.SIMPLE_RADIAL: [500.0, 320.0, 240.0, -0.12],
    CameraModel.RADIAL: [500.0, 320.0, 240.0, -0.12, 0.03],
    CameraModel.OPENCV: [500.0, 480.0, 318.0, 243.0, -0.1, 0.02, 0.001, -0.002],
    CameraModel.FULL_OPENCV: [500.0, 480.0, 318.0, 243.0, -0.1, 0.02, 0.001, -0.002, 0.001, 0.01, 0.002, 0.0],
}


def _points(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform([-1.0, -0.8, 1.5], [1.0, 0.8, 6.0], size=(n, 3))


@pytest.mark.parametrize("model", list(CAMERAS), ids=lambda m: m.value)
def test_project_unproject_round_trip_float64(model):
    cam = Camera(model, 640, 480, CAMERAS[model])
    pts = _points()
    pixels = cam.project(pts)
    back = cam.unproject(pixels, pts[:, 2])
    np.testing.assert_allclose(back, pts, atol=1e-9, rtol=0)


@pytest.mark.parametrize("model", list(CAMERAS), ids=lambda m: m.value)
def test_torch_matches_numpy(model):
    cam = Camera(model, 640, 480, CAMERAS[model])
    pts = _points(300)
    px_np = cam.project(pts)
    px_t = cam.project(torch.from_numpy(pts))
    assert isinstance(px_t, torch.Tensor)
    np.testing.assert_allclose(px_t.numpy(), px_np, atol=1e-10)
    back = cam.unproject(px_t, torch.from_numpy(pts[:, 2]))
    np.testing.assert_allclose(back.numpy(), pts, atol=1e-9)


@pytest.mark.parametrize("model", [m for m in CAMERAS if m.has_distortion], ids=lambda m: m.value)
def test_undistort_inverts_distort(model):
    cam = Camera(model, 640, 480, CAMERAS[model])
    uv = np.random.default_rng(1).uniform(-0.6, 0.6, size=(5000, 2))
    np.testing.assert_allclose(cam.undistort(cam.distort(uv)), uv, atol=1e-12)
    # pixels of the distorted image -> undistorted pinhole image -> back
    px = np.random.default_rng(2).uniform([0, 0], [640, 480], size=(500, 2))
    np.testing.assert_allclose(cam.distort_pixels(cam.undistort_pixels(px)), px, atol=1e-8)


def test_simple_radial_against_hand_formula():
    f, cx, cy, k = 400.0, 100.0, 80.0, -0.2
    cam = Camera("SIMPLE_RADIAL", 200, 160, [f, cx, cy, k])
    x, y, z = 0.3, -0.2, 2.0
    u, v = x / z, y / z
    r2 = u * u + v * v
    expected = [f * u * (1 + k * r2) + cx, f * v * (1 + k * r2) + cy]
    np.testing.assert_allclose(cam.project(np.array([x, y, z])), expected, rtol=0, atol=1e-12)


def test_pinhole_matches_K_matrix():
    cam = Camera.pinhole(300.0, 310.0, 160.5, 120.25, 320, 240)
    pts = _points(100)
    hom = pts @ cam.K().T
    np.testing.assert_allclose(cam.project(pts), hom[:, :2] / hom[:, 2:], atol=1e-12)


def test_scaled_camera_maps_pixels_consistently():
    cam = Camera.pinhole(300.0, 300.0, 160.0, 120.0, 320, 240)
    half = cam.scaled(0.5)
    pts = _points(50)
    np.testing.assert_allclose(half.project(pts), cam.project(pts) * 0.5, atol=1e-9)
    assert (half.width, half.height) == (160, 120)


def test_wrong_parameter_count_is_rejected():
    with pytest.raises(ConfigError, match="OPENCV takes 8 parameters"):
        Camera("OPENCV", 10, 10, [1, 2, 3])
    with pytest.raises(DataError):
        Camera("PINHOLE", 10, 10, [1, np.nan, 3, 4])


def test_pose_and_quaternion_conventions():
    rng = np.random.default_rng(3)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    R = quat_to_rotmat(q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    q2 = rotmat_to_quat(R)
    np.testing.assert_allclose(q2, q if q[0] >= 0 else -q, atol=1e-12)
    # 90 degrees about z: x axis -> y axis
    Rz = quat_to_rotmat(np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]))
    np.testing.assert_allclose(Rz @ [1, 0, 0], [0, 1, 0], atol=1e-12)

    view = View(1, "a.png", 1, q, [0.5, -1.0, 2.0])
    centre = view.center
    np.testing.assert_allclose(view.world_to_camera(centre), 0, atol=1e-12)
    pts = _points(20)
    np.testing.assert_allclose(view.camera_to_world(view.world_to_camera(pts)), pts, atol=1e-12)


def test_cameras_project_and_unproject_world_points():
    cam = Camera("OPENCV", 640, 480, CAMERAS[CameraModel.OPENCV])
    view = View.from_matrix(
        7, "v.png", 1, np.hstack([quat_to_rotmat(np.array([0.95, 0.1, -0.2, 0.05])), [[0.1], [0.2], [3.0]]])
    )
    cams = Cameras({1: cam}, {7: view})
    world = np.random.default_rng(4).uniform(-0.5, 0.5, (100, 3))
    px, depth = cams.project(7, world)
    assert (depth > 0).all()
    np.testing.assert_allclose(cams.unproject(7, px, depth), world, atol=1e-9)
    with pytest.raises(DataError, match="camera 9"):
        Cameras({1: cam}, {1: View(1, "x", 9, [1, 0, 0, 0], [0, 0, 0])})
