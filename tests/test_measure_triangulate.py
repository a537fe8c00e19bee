"""Multi-ray triangulation against exact synthetic truth, its covariance against Monte-Carlo, degenerate cases.

Tolerances: noise-free picks of exactly projected points must come back to ~1e-9 m (float64 Gauss–Newton on
a 1 m scene; undistortion converges to ~1e-12 in normalised coordinates). Monte-Carlo with N = 1000 samples:
a sample variance has a relative standard error sqrt(2/N) = 4.5 %, so ratios within ±18 % are 4σ; a sample
correlation has a standard error ≤ 1/sqrt(N) = 3.2 %, so 0.12 is ~4σ; the χ²₃ 95 % coverage has a binomial
standard error sqrt(0.95·0.05/N) = 0.69 %, so [0.925, 0.975] is ~3.6σ (plus the small first-order model
error of a 0.5 px pick at these ranges). A sample standard deviation (distances, N = 800) has a relative
standard error 1/sqrt(2N) = 2.5 %: ±10 % is 4σ.
"""

from __future__ import annotations

import numpy as np
import pytest

from core.cameras import Camera, CameraModel, View
from core.errors import DataError
from eval.measure import CHI2_3_95, Pick, TriangulationOptions, distance, triangulate


def look_at(center: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """3×4 world-to-camera matrix of a camera at ``center`` looking at ``target`` (OpenCV axes)."""
    z = np.asarray(target, float) - center
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world
    return np.concatenate([R, (-R @ center)[:, None]], axis=1)


def distorted_camera(camera_id: int = 1) -> Camera:
    return Camera(
        CameraModel.OPENCV, 640, 480, np.array([520.0, 515.0, 321.5, 238.0, -0.12, 0.03, 0.001, -0.0007]), camera_id
    )


def ring_views(n: int, radius: float = 1.0, height: float = 0.6, span_deg: float = 120.0) -> list[View]:
    views = []
    for i, a in enumerate(np.radians(np.linspace(-span_deg / 2, span_deg / 2, n))):
        c = np.array([radius * np.cos(a), radius * np.sin(a), height])
        views.append(View.from_matrix(i + 1, f"{i + 1:04d}.png", 1, look_at(c, np.zeros(3))))
    return views


def exact_picks(camera: Camera, views: list[View], x: np.ndarray, sigma: float = 0.5) -> list[Pick]:
    return [Pick(camera, v, camera.project(v.world_to_camera(x[None]))[0], sigma) for v in views]


@pytest.mark.parametrize("n_views", [2, 3, 5])
@pytest.mark.parametrize("model", ["PINHOLE", "OPENCV"])
def test_exact_projections_give_the_true_point(n_views: int, model: str) -> None:
    cam = distorted_camera() if model == "OPENCV" else Camera.pinhole(500, 500, 320, 240, 640, 480)
    views = ring_views(n_views)
    rng = np.random.default_rng(1)
    for truth in rng.uniform(-0.15, 0.15, size=(5, 3)):
        point = triangulate(exact_picks(cam, views, truth), name="T")
        assert np.abs(point.local - truth).max() < 1e-9
        assert np.abs(point.residuals_px).max() < 1e-6
        assert point.n_rays == n_views
        assert np.all(np.linalg.eigvalsh(point.covariance) > 0)


def test_covariance_matches_monte_carlo_and_chi2_coverage() -> None:
    cam = distorted_camera()
    views = ring_views(3, span_deg=70.0)
    truth = np.array([0.05, -0.03, 0.08])
    sigmas = [0.5, 0.8, 0.3]  # per-pick σ, different on purpose
    base = [Pick(cam, v, p.pixel, s) for v, p, s in zip(views, exact_picks(cam, views, truth), sigmas, strict=True)]
    predicted = triangulate(base).covariance
    rng = np.random.default_rng(7)
    n = 1000
    estimates = np.empty((n, 3))
    inside = 0
    for k in range(n):
        noisy = [Pick(p.camera, p.view, p.pixel + rng.normal(0, p.sigma_px, 2), p.sigma_px) for p in base]
        est = triangulate(noisy)
        estimates[k] = est.local
        inside += est.mahalanobis2(truth) <= CHI2_3_95
    sample = np.cov(estimates.T)
    # Variances within ±18 % along the principal axes of the predicted covariance ...
    _, axes = np.linalg.eigh(predicted)
    ratio = np.diag(axes.T @ sample @ axes) / np.diag(axes.T @ predicted @ axes)
    assert np.all((ratio > 0.82) & (ratio < 1.18)), ratio
    # ... normalised covariances within 0.12, the estimator unbiased at the 4σ level ...
    d = np.sqrt(np.diag(predicted))
    assert np.abs(sample / np.outer(d, d) - predicted / np.outer(d, d)).max() < 0.12
    bias = estimates.mean(axis=0) - truth
    assert np.all(np.abs(bias) < 4 * d / np.sqrt(n))
    # ... and the 95 % ellipsoid holds the truth 95 % of the time.
    assert 0.925 <= inside / n <= 0.975, inside / n


def test_distance_sigma_matches_monte_carlo() -> None:
    cam = Camera.pinhole(500, 500, 320, 240, 640, 480)
    views = ring_views(2, span_deg=60.0)
    a_true, b_true = np.array([-0.1, 0.0, 0.0]), np.array([0.12, 0.05, 0.02])
    pa, pb = exact_picks(cam, views, a_true, 0.7), exact_picks(cam, views, b_true, 0.7)
    d0 = distance(triangulate(pa, name="A"), triangulate(pb, name="B"))
    assert d0.length == pytest.approx(np.linalg.norm(b_true - a_true), abs=1e-9)
    rng = np.random.default_rng(3)
    lengths = []
    for _ in range(800):
        na = [Pick(p.camera, p.view, p.pixel + rng.normal(0, 0.7, 2), 0.7) for p in pa]
        nb = [Pick(p.camera, p.view, p.pixel + rng.normal(0, 0.7, 2), 0.7) for p in pb]
        lengths.append(distance(triangulate(na), triangulate(nb)).length)
    assert np.std(lengths) / d0.sigma == pytest.approx(1.0, abs=0.10)


def test_more_rays_and_wider_angles_shrink_the_ellipsoid() -> None:
    cam = Camera.pinhole(500, 500, 320, 240, 640, 480)
    truth = np.zeros(3)
    narrow = triangulate(exact_picks(cam, ring_views(2, span_deg=10.0), truth))
    wide = triangulate(exact_picks(cam, ring_views(2, span_deg=90.0), truth))
    many = triangulate(exact_picks(cam, ring_views(8, span_deg=90.0), truth))
    assert wide.sigma_3d < narrow.sigma_3d / 3
    assert many.sigma_3d < wide.sigma_3d
    axes, _ = narrow.ellipsoid(0.95)
    assert axes.max() / axes.min() > 5  # elongated along the viewing direction


def test_georeferenced_origin_keeps_millimetres() -> None:
    origin = np.array([500123.456, 5000987.654, 312.5])
    cam = distorted_camera()
    truth = np.array([0.0123, -0.0456, 0.0789])
    point = triangulate(exact_picks(cam, ring_views(3), truth), origin=origin, name="G")
    np.testing.assert_allclose(point.world - origin, truth, atol=1e-9)
    assert point.world.dtype == np.float64
    assert abs(point.world[1] - (5000987.654 - 0.0456)) < 1e-8


# -- degenerate input ---------------------------------------------------------------------------------------


def test_one_ray_is_refused() -> None:
    cam = Camera.pinhole(500, 500, 320, 240, 640, 480)
    with pytest.raises(DataError, match="at least 2 images"):
        triangulate(exact_picks(cam, ring_views(2), np.zeros(3))[:1], name="P1")


def test_parallel_rays_are_refused() -> None:
    cam = Camera.pinhole(500, 500, 320, 240, 640, 480)
    # Two cameras with the same orientation, picks at the same pixel: the rays are parallel.
    R = look_at(np.array([0.0, -1.0, 0.0]), np.zeros(3))
    v1 = View.from_matrix(1, "a.png", 1, R)
    shifted = R.copy()
    shifted[:, 3] -= R[:, :3] @ np.array([0.2, 0.0, 0.0])
    v2 = View.from_matrix(2, "b.png", 1, shifted)
    picks = [Pick(cam, v1, (300.0, 200.0)), Pick(cam, v2, (300.0, 200.0))]
    with pytest.raises(DataError, match="parallel"):
        triangulate(picks, name="P")
    # Nearly parallel (0.3° apart) is refused by the default 1° threshold, accepted with a lower one.
    near = [Pick(cam, v1, (300.0, 200.0)), Pick(cam, v2, (300.0 - 500 * np.tan(np.radians(0.3)), 200.0))]
    with pytest.raises(DataError, match="nearly"):
        triangulate(near)
    assert triangulate(near, options=TriangulationOptions(min_angle_deg=0.1)).max_angle_deg == pytest.approx(
        0.3, abs=0.005
    )


def test_rays_meeting_behind_a_camera_are_refused() -> None:
    cam = Camera.pinhole(500, 500, 320, 240, 640, 480)
    R = look_at(np.array([0.0, -1.0, 0.0]), np.zeros(3))
    v1 = View.from_matrix(1, "a.png", 1, R)
    shifted = R.copy()
    shifted[:, 3] -= R[:, :3] @ np.array([0.2, 0.0, 0.0])  # second camera 0.2 m to the right
    v2 = View.from_matrix(2, "b.png", 1, shifted)
    # Left camera looks left, right camera looks right: the rays diverge and meet behind both cameras.
    picks = [Pick(cam, v1, (200.0, 240.0)), Pick(cam, v2, (440.0, 240.0))]
    with pytest.raises(DataError, match="behind the camera"):
        triangulate(picks, name="P")


@pytest.mark.parametrize(
    ("pixel", "sigma", "match"),
    [((np.nan, 10.0), 1.0, "not finite"), ((10.0, 10.0), 0.0, "sigma_px"), ((700.0, 10.0), 1.0, "outside image")],
)
def test_bad_picks_are_refused(pixel, sigma, match) -> None:
    cam = Camera.pinhole(500, 500, 320, 240, 640, 480)
    picks = exact_picks(cam, ring_views(2), np.zeros(3))
    picks[1] = Pick(cam, picks[1].view, pixel, sigma)
    with pytest.raises(DataError, match=match):
        triangulate(picks, name="P")


def test_same_image_twice_is_refused() -> None:
    cam = Camera.pinhole(500, 500, 320, 240, 640, 480)
    picks = exact_picks(cam, ring_views(2), np.zeros(3))
    with pytest.raises(DataError, match="picked twice"):
        triangulate([picks[0], picks[0], picks[1]])
