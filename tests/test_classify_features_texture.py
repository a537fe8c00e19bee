"""Image-texture features against windows of known content: a step edge (its window std in closed form, no
corner strength), a brute-force window statistic on a random photo, and points seen by two views on a uniform and
a chequered half of a plane, with a view that sees no texture where the other sees it."""

from __future__ import annotations

import numpy as np
import pytest

from classify.features import FeatureOptions, ViewData, compute_features
from classify.features.image_texture import TEXTURE_EPS, TEXTURE_RADIUS_PX, image_texture_features, texture_maps
from core.cameras import Camera, Cameras, View
from core.pointcloud import PointCloud

F, W, H = 50.0, 64, 48
DOWN = np.diag([1.0, -1.0, -1.0])
R = TEXTURE_RADIUS_PX


def test_window_std_of_a_step_and_no_corner_on_a_straight_edge():
    step = np.zeros((48, 64), np.uint8)
    step[:, 32:] = 200
    std, corner = texture_maps(step)
    for col in range(32 - R - 2, 32 + R + 2):
        # The window's share p of bright columns: its grey std is h sqrt(p (1 − p)).
        p = np.clip((col + R + 1 - 32) / (2 * R + 1), 0.0, 1.0)
        assert float(std[24, col]) == pytest.approx(200 / 255 * np.sqrt(p * (1 - p)), abs=2e-3)
    # A straight edge has one gradient direction: the smaller eigenvalue of its structure tensor is zero.
    assert np.abs(corner.astype(float)).max() == pytest.approx(0.0, abs=1e-3)
    flat_std, flat_corner = texture_maps(np.full((20, 30, 3), 90, np.uint8))
    assert not flat_std.any() and not flat_corner.any()


def test_window_statistics_match_a_brute_force_on_a_random_photo():
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, size=(40, 50, 3), dtype=np.uint8)
    std, corner = texture_maps(img)
    grey = img.astype(np.float64).mean(axis=2) / 255.0
    pad = np.pad(grey, 1, mode="reflect")
    # 3 × 3 Sobel by hand, / 8 (grey per pixel).
    gx = (pad[:-2, 2:] + 2 * pad[1:-1, 2:] + pad[2:, 2:] - pad[:-2, :-2] - 2 * pad[1:-1, :-2] - pad[2:, :-2]) / 8
    gy = (pad[2:, :-2] + 2 * pad[2:, 1:-1] + pad[2:, 2:] - pad[:-2, :-2] - 2 * pad[:-2, 1:-1] - pad[:-2, 2:]) / 8
    for r, c in [(10, 10), (20, 33), (R, R), (30, 45)]:
        win = np.s_[r - R : r + R + 1, c - R : c + R + 1]
        assert float(std[r, c]) == pytest.approx(grey[win].std(), rel=2e-3)
        tensor = np.array(
            [[(gx[win] ** 2).mean(), (gx[win] * gy[win]).mean()], [(gx[win] * gy[win]).mean(), (gy[win] ** 2).mean()]]
        )
        assert float(corner[r, c]) == pytest.approx(np.sqrt(np.linalg.eigvalsh(tensor)[0]), rel=2e-3)


def _rig(textured_in_view2: bool = True) -> tuple[Cameras, ViewData]:
    """Two views 1 m above z = 0 looking down (x = ±0.1). The plane is uniform grey for x < 0 and a chequer of
    2 × 2-pixel squares (grey 60 / 180) for x ≥ 0; with ``textured_in_view2`` False the second view sees it
    uniform everywhere (as a pane or a mirror shows one view a sky and another a pattern)."""
    cam = Camera.pinhole(F, F, W / 2, H / 2, W, H)
    views = {
        i + 1: View.from_matrix(i + 1, f"v{i}.png", 1, np.c_[DOWN, -DOWN @ np.array([cx, 0.0, 1.0])])
        for i, cx in enumerate((-0.1, 0.1))
    }
    cams = Cameras({1: cam}, views)

    def image(name: str) -> np.ndarray:
        v = cams.by_name(name)
        cols, rows = np.meshgrid(np.arange(W), np.arange(H))
        world_x = v.center[0] + (cols + 0.5 - W / 2) / F
        chequer = np.where((cols // 2 + rows // 2) % 2 == 0, 60, 180)
        textured = world_x >= 0 if (name == "v0.png" or textured_in_view2) else np.zeros_like(world_x, bool)
        grey = np.where(textured, chequer, 120).astype(np.uint8)
        return np.repeat(grey[..., None], 3, axis=2)

    return cams, ViewData(cams, image, lambda name: None)


def test_points_on_the_uniform_and_the_chequered_half():
    _, views = _rig()
    pts = np.array([[-0.3, 0.0, 0.0], [0.3, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.0, 5.0]])
    vis = [np.array([1, 2]), np.array([1, 2]), np.array([1]), np.array([], dtype=np.int64)]
    f = image_texture_features(pts, vis, views)
    # Uniform side: no texture. Chequer of 2-pixel squares, 7 × 7 window: 60 / 180 in near-equal shares, std close
    # to 60 grey levels (the exact share depends on the window's phase: within 10 %).
    assert f["texture_std_views"][0] == 0.0 and f["texture_corner_views"][0] == 0.0
    assert f["texture_std_views"][1] == pytest.approx(60 / 255, rel=0.1)
    assert f["texture_corner_views"][1] > 0.05
    assert f["texture_log_spread"][1] < 0.1  # both views see the same texture
    # One fusing view: no spread; no fusing view: every feature neutral.
    assert f["texture_log_spread"][2] == 0.0 and f["texture_std_views"][2] > 0.2
    assert [f[n][3] for n in f] == [0.0, 0.0, 0.0]


def test_a_view_that_sees_no_texture_where_the_other_does():
    _, views = _rig(textured_in_view2=False)
    f = image_texture_features(np.array([[0.3, 0.0, 0.0]]), [np.array([1, 2])], views)
    cams, _ = _rig()
    # Per view: the chequer's std s (view 1) and 0 (view 2); the spread is the std of their logs, half the gap.
    s = float(texture_maps(views.image("v0.png"))[0][24, int(round(F * (0.3 + 0.1) + W / 2 - 0.5))])
    assert f["texture_log_spread"][0] == pytest.approx(0.5 * (np.log(s + TEXTURE_EPS) - np.log(TEXTURE_EPS)), rel=1e-2)
    assert f["texture_std_views"][0] == pytest.approx(s / 2, rel=1e-2)
    assert cams.camera_of(cams.by_name("v0.png")).width == W


def test_compute_features_image_texture_group():
    cams, views = _rig()
    calls: list[str] = []

    def image(name: str) -> np.ndarray:
        calls.append(name)
        return views.image(name)

    x = np.linspace(-0.3, 0.3, 40)
    cloud = PointCloud(np.c_[x, 0.01 * np.sin(7 * x), np.zeros(40)], visibility=[np.array([1, 2])] * 40)
    opts = FeatureOptions(names=("image_texture",), multiview=FeatureOptions().multiview.__class__(chunk_size=7))
    t = compute_features(cloud, opts, ViewData(cams, image, views.depth))
    assert t.names == ("texture_std_views", "texture_corner_views", "texture_log_spread")
    assert sorted(calls) == ["v0.png", "v1.png"]  # six chunks, one pair of maps per view
    assert np.isfinite(t.values).all()
    # A window reaches the other half within (R + 1) px = 0.08 m of x = 0 in either view's image.
    std = t.column("texture_std_views")
    assert (std[x < -0.1] == 0).all() and (std[x > 0.1] > 0.2).all()
