"""View-dependent colour features against analytic set-ups: photos whose luminance is a known function of the
viewpoint (mirror direction about a tilted normal, angle to a peak view), a Lambertian surface, and the neutral
values; the flat-sample reductions against a per-point loop."""

from __future__ import annotations

import numpy as np
import pytest

from classify.features import FeatureOptions, ViewData, compute_features
from classify.features.view_dependent import LUM_FLOOR, luminance_features, view_dependent_features
from core.cameras import Camera, Cameras, View
from core.pointcloud import PointCloud

F, W, H = 50.0, 64, 48


def _look_at(centre: np.ndarray, target: np.ndarray) -> np.ndarray:
    """cam_from_world (3, 4) of a camera at ``centre`` looking at ``target`` (COLMAP axes: x right, y down)."""
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.stack([x, y, z])
    return np.c_[r, -r @ centre]


def _ring(n: int = 7) -> np.ndarray:
    """n camera centres on a cone above the origin (1 m away, 20–50° off the vertical, spread in azimuth)."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    tilt = np.radians(np.linspace(20, 50, n))
    return np.c_[np.sin(tilt) * np.cos(a), np.sin(tilt) * np.sin(a), np.cos(tilt)]


def _views(centres: np.ndarray, grey_of) -> tuple[Cameras, ViewData]:
    """Views at ``centres`` looking at the origin; view i's photo is uniform grey ``grey_of(i, view)`` (uint8)."""
    cam = Camera.pinhole(F, F, W / 2, H / 2, W, H)
    views = {i + 1: View.from_matrix(i + 1, f"v{i}.png", 1, _look_at(c, np.zeros(3))) for i, c in enumerate(centres)}
    cams = Cameras({1: cam}, views)

    def image(name: str) -> np.ndarray:
        v = cams.by_name(name)
        return np.full((H, W, 3), grey_of(int(name[1:-4]), v), dtype=np.uint8)

    return cams, ViewData(cams, image, lambda name: None)


def _mirror_up(v: View, p: np.ndarray, n: np.ndarray) -> float:
    """z of the view's ray (camera → point) reflected by the mirror plane of normal n (Householder matrix)."""
    ray = (p - v.center) / np.linalg.norm(p - v.center)
    return float(((np.eye(3) - 2 * np.outer(n, n)) @ ray)[2])


def test_luminance_rising_with_the_mirror_direction_up_gives_correlation_one():
    n = np.array([np.sin(np.radians(30)), 0.0, np.cos(np.radians(30))])  # a tilted shiny facet
    centres = _ring()
    probe, _ = _views(centres, lambda i, v: 0)
    up = np.array([_mirror_up(v, np.zeros(3), n) for v in probe])
    lo, hi = up.min(), up.max()
    grey = np.rint(30 + 200 * (up - lo) / (hi - lo)).astype(np.uint8)
    _, views = _views(centres, lambda i, v: grey[i])
    vis = [np.arange(1, len(centres) + 1)] * 2
    pts = np.zeros((2, 3))
    normals = np.array([n, [0.0, 0.0, 0.0]])  # the second point has no normal
    f = view_dependent_features(pts, vis, normals, views)
    # Quantisation to 8 bits bounds how far the correlation falls from 1 (~1e-4 here).
    assert f["specular_up_corr"][0] == pytest.approx(1.0, abs=1e-3)
    assert f["specular_up_corr"][1] == 0.0
    y = grey / 255.0
    assert f["lum_cv_views"][0] == pytest.approx(y.std() / y.mean(), rel=1e-5)
    assert f["lum_peak_views"][0] == pytest.approx(y.max() - np.median(y), rel=1e-5)
    # The sign of the normal does not matter (a mirror has two sides).
    g = view_dependent_features(pts[:1], vis[:1], -normals[:1], views)
    assert g["specular_up_corr"][0] == pytest.approx(f["specular_up_corr"][0], abs=1e-7)


def test_a_lobe_around_the_brightest_view_and_a_lambertian_surface():
    centres = _ring(8)
    peak = centres[3] / np.linalg.norm(centres[3])
    cos = centres @ peak / np.linalg.norm(centres, axis=1)  # cosine of each ray (to the origin) to the peak's ray
    lobe = np.rint(20 + 200 * (cos - cos.min()) / (1 - cos.min())).astype(np.uint8)
    _, views = _views(centres, lambda i, v: lobe[i])
    vis = [np.arange(1, 9)]
    f = view_dependent_features(np.zeros((1, 3)), vis, None, views)
    assert lobe.argmax() == 3 and f["lum_lobe_corr"][0] == pytest.approx(1.0, abs=1e-3)
    assert f["specular_up_corr"][0] == 0.0  # no normals
    _, flat = _views(centres, lambda i, v: 90)
    g = view_dependent_features(np.zeros((1, 3)), vis, np.array([[0.0, 0.0, 1.0]]), flat)
    assert all(g[k][0] == pytest.approx(0.0, abs=1e-12) for k in g)


def test_neutral_values_for_few_views_and_dark_points():
    owner = np.array([0, 1, 1, 2, 2, 2])
    lum = np.array([0.5, 0.2, 0.4, 0.0, 0.0, 0.01])
    ray = np.tile([0.0, 0.0, -1.0], (6, 1))
    f = luminance_features(owner, lum, ray, None, 4)  # point 3: no sample
    assert f["lum_cv_views"][0] == 0.0 and f["lum_peak_views"][0] == 0.0  # one view
    assert f["lum_cv_views"][1] == pytest.approx(0.1 / 0.3) and f["lum_peak_views"][1] == pytest.approx(0.1)
    # A dark point: the mean (1/300) is floored at LUM_FLOOR.
    assert f["lum_cv_views"][2] == pytest.approx(np.std([0, 0, 0.01]) / LUM_FLOOR)
    assert all(v[3] == 0.0 for v in f.values())
    assert all(v[:2].tolist() == [0.0, 0.0] for k, v in f.items() if k.endswith("corr"))  # < 3 views


def test_flat_reductions_match_a_per_point_loop():
    rng = np.random.default_rng(0)
    m, e = 50, 400
    owner = rng.integers(0, m, e)
    lum = rng.random(e)
    ray = rng.normal(size=(e, 3))
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    normals = rng.normal(size=(m, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    f = luminance_features(owner, lum, ray, normals, m)
    for i in range(m):
        sel = owner == i
        y, r = lum[sel], ray[sel]
        if sel.sum() < 2:
            continue
        assert f["lum_cv_views"][i] == pytest.approx(y.std() / max(y.mean(), LUM_FLOOR))
        assert f["lum_peak_views"][i] == pytest.approx(y.max() - np.median(y))
        householder = np.eye(3) - 2 * np.outer(normals[i], normals[i])
        if sel.sum() >= 3:
            mirror_up = (r @ householder.T)[:, 2]
            assert f["specular_up_corr"][i] == pytest.approx(np.corrcoef(y, mirror_up)[0, 1], abs=1e-9)
        b = y.argmax()
        if sel.sum() >= 4:
            cos = np.delete(r @ r[b], b)
            assert f["lum_lobe_corr"][i] == pytest.approx(np.corrcoef(np.delete(y, b), cos)[0, 1], abs=1e-9)


def test_compute_features_view_dependent_group():
    centres = _ring(5)
    _, views = _views(centres, lambda i, v: 40 + 30 * i)
    pts = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.01, 0.01, 0.0]])
    cloud = PointCloud(pts, normals=np.tile([0.0, 0.0, 1.0], (4, 1)), visibility=[np.arange(1, 6)] * 4)
    t = compute_features(cloud, FeatureOptions(names=("view_dependent",)), views)
    assert t.names == ("lum_cv_views", "lum_peak_views", "lum_lobe_corr", "specular_up_corr")
    y = (40 + 30 * np.arange(5)) / 255.0
    np.testing.assert_allclose(t.column("lum_cv_views"), y.std() / y.mean(), rtol=1e-5)
