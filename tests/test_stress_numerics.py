"""Numerical stress: large coordinates, degenerate neighbourhoods, extreme values (issue 12).

The same small scene at the origin and at UTM-like coordinates (~5e6 m) must give the same answers:
positions to 1 mm and metrics to 1e-6 relative through conversion, rendering, C2C and the file round
trips. Degenerate inputs (duplicates, collinear and coplanar neighbourhoods, one point, extreme scales
and opacities, a camera that sees nothing) must give finite output. Hypothesis properties hold
conversion, projection and C2C to analytic or brute-force truth.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.distance import cdist

from core.cameras import Camera, View
from core.gaussians import GaussianSet
from core.pointcloud import PointCloud
from fusion.convert import ConversionWarning, ConvertMode, convert_points

UTM = np.array([512_345.0, 5_412_345.0, 312.0])
MM = 1e-3
PROPS = settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(autouse=True)
def _quiet_conversion_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConversionWarning)
        yield


def _scene(n: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A bumpy 4 m × 3 m surface with colours: (N, 3) float64 positions near the origin, (N, 3) uint8."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([-2, -1.5], [2, 1.5], (n, 2))
    z = 0.2 * np.sin(xy[:, 0] * 2) * np.cos(xy[:, 1] * 3)
    return np.c_[xy, z], rng.integers(0, 256, (n, 3)).astype(np.uint8)


def _both(positions: np.ndarray, colors: np.ndarray) -> tuple[PointCloud, PointCloud]:
    """The scene at the origin and the same scene at UTM coordinates (local frame chosen by the toolkit)."""
    return PointCloud(positions, colors=colors), PointCloud.from_world(positions + UTM, colors=colors)


def _assert_finite_gaussians(gs: GaussianSet) -> None:
    for values in (gs.means, gs.log_scales, gs.quats, gs.logit_opacities, gs.sh_dc):
        assert np.isfinite(values).all()
    np.testing.assert_allclose(np.linalg.norm(gs.quats.astype(np.float64), axis=1), 1.0, atol=1e-5)


# -- the same scene at the origin and at UTM coordinates ------------------------------------------------------
@pytest.mark.parametrize("mode", [ConvertMode.PAPER, ConvertMode.ADAPTIVE])
def test_conversion_is_translation_invariant(mode) -> None:
    near, far = _both(*_scene())
    assert np.abs(far.positions).max() < 1e4  # the UTM cloud is held in a local frame
    a = convert_points(near, mode).gaussians
    b = convert_points(far, mode).gaussians
    np.testing.assert_allclose(b.world_means - UTM, a.world_means, atol=MM, rtol=0)
    np.testing.assert_allclose(b.log_scales, a.log_scales, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(b.logit_opacities, a.logit_opacities, rtol=1e-6, atol=1e-6)
    # quaternions: the same rotation (q and -q are equal)
    dots = np.abs(np.sum(a.quats.astype(np.float64) * b.quats.astype(np.float64), axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-5)


def _look_at(center: np.ndarray, target: np.ndarray, image_id: int = 1) -> View:
    """A world-to-camera view at ``center`` looking at ``target`` (OpenCV axes: y down)."""
    z = target - center
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return View.from_matrix(image_id, f"v{image_id}.png", 1, np.c_[R, -R @ center])


def test_rendering_is_translation_invariant() -> None:
    from fusion.render import render_gaussian_set

    near, far = _both(*_scene(300))
    ga = convert_points(near, ConvertMode.ADAPTIVE).gaussians
    gb = convert_points(far, ConvertMode.ADAPTIVE).gaussians
    cam = Camera.pinhole(60, 60, 32, 24, 64, 48)
    centre = np.array([0.3, -4.0, 2.5])
    img_a = render_gaussian_set(ga, cam, _look_at(centre, np.zeros(3)), backend="cpu").to_numpy()
    # the UTM scene's camera pose is expressed relative to its own cameras origin (float64 world offset)
    view_b = _look_at(centre + UTM - gb.origin, UTM - gb.origin)
    img_b = render_gaussian_set(gb, cam, view_b, cameras_origin=gb.origin, backend="cpu").to_numpy()
    assert np.isfinite(img_a.colour).all() and img_a.alpha.max() > 0.5
    # float32 rasterisation in a camera-centred frame: identical up to float32 rounding of the inputs
    np.testing.assert_allclose(img_b.colour, img_a.colour, atol=2e-5)
    np.testing.assert_allclose(img_b.depth, img_a.depth, rtol=1e-5, atol=1e-5)


def test_c2c_is_translation_invariant() -> None:
    from eval.c2c import compare_clouds

    pos, col = _scene(500)
    ref_near, ref_far = _both(pos, col)
    rng = np.random.default_rng(5)
    moved = pos[::2] + rng.normal(0, 0.01, (250, 3))
    cmp_near, cmp_far = _both(moved, col[::2])
    a = compare_clouds(cmp_near, ref_near, tau=0.02)
    b = compare_clouds(cmp_far, ref_far, tau=0.02)
    for key in ("mean", "std", "median", "rmse", "p95", "max"):
        assert getattr(b.stats, key) == pytest.approx(getattr(a.stats, key), rel=1e-6)
    assert b.scores.fscore == pytest.approx(a.scores.fscore, rel=1e-6)


@pytest.mark.parametrize("suffix", [".ply", ".las", ".laz"])
def test_point_cloud_round_trips_keep_millimetres_at_utm(tmp_path, suffix) -> None:
    from core.io import read_point_cloud, write_point_cloud

    pos, col = _scene(200)
    world = pos + UTM + np.array([0.0004, 0.0007, 0.0002])  # sub-millimetre offsets
    write_point_cloud(tmp_path / f"c{suffix}", PointCloud.from_world(world, colors=col))
    back = read_point_cloud(tmp_path / f"c{suffix}")
    # PLY: float32 local (~4 m → 5e-7 m steps); LAS: 1 mm integer steps (half a step is the worst rounding)
    np.testing.assert_allclose(back.world_positions, world, atol=0.5 * MM + 1e-9, rtol=0)


@pytest.mark.parametrize("fmt", ["ply", "splat"])
def test_gaussian_export_round_trips_keep_millimetres_at_utm(tmp_path, fmt) -> None:
    from core.io.gaussian_ply import read_gaussian_ply
    from core.io.origin import read_origin
    from fusion.export import ExportOptions, export_gaussians
    from fusion.splat_format import read_splat

    _, far = _both(*_scene(150))
    gs = convert_points(far, ConvertMode.PAPER).gaussians
    export_gaussians(tmp_path / f"g.{fmt}", gs, ExportOptions(min_opacity=0.0))
    if fmt == "ply":
        back = read_gaussian_ply(tmp_path / "g.ply").world_means
    else:
        back = read_splat(tmp_path / "g.splat").positions.astype(np.float64) + read_origin(tmp_path / "g.splat")
        order = np.lexsort(back.T)  # .splat files are sorted by importance
        back = back[order][np.argsort(np.lexsort(gs.world_means.T))]
    np.testing.assert_allclose(back, gs.world_means, atol=MM, rtol=0)


# -- degenerate input ---------------------------------------------------------------------------------------
def _degenerate_clouds() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(2)
    line = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)]
    plane = np.c_[rng.random((80, 2)), np.zeros(80)]
    dup = np.repeat(rng.random((10, 3)), 8, axis=0)
    return {
        "single": np.array([[1.0, 2.0, 3.0]]),
        "two": np.array([[0.0, 0, 0], [1e-9, 0, 0]]),
        "duplicates": dup,
        "all-identical": np.zeros((30, 3)),
        "collinear": line,
        "coplanar": plane,
        "huge-extent": np.array([[0.0, 0, 0], [1e4, 0, 0], [0, 1e4, 0], [1e-6, 0, 0]]),
        "utm-duplicates": np.repeat(UTM[None], 5, axis=0),
    }


@pytest.mark.parametrize("mode", [ConvertMode.PAPER, ConvertMode.ADAPTIVE])
@pytest.mark.parametrize("name", list(_degenerate_clouds()))
def test_degenerate_clouds_convert_to_finite_gaussians(mode, name) -> None:
    world = _degenerate_clouds()[name]
    gs = convert_points(PointCloud.from_world(world), mode).gaussians
    assert len(gs) == len(world)
    _assert_finite_gaussians(gs)
    np.testing.assert_allclose(gs.world_means, world, atol=MM, rtol=0)


def test_extreme_scales_and_opacities_render_finite() -> None:
    from fusion.render import render_gaussian_set

    n = 6
    gs = GaussianSet(
        means=np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1], [0.05, 0.05, 0], [0, 0, -0.05]]),
        log_scales=np.array([[-30] * 3, [25] * 3, [-30, 25, 0], [0, 0, -30], [-5] * 3, [10, -30, -30]], np.float32),
        quats=np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
        logit_opacities=np.array([-80, 80, 0, 40, -40, 5], np.float32),
        sh_dc=np.full((n, 3), 3.0, np.float32),
        sh_rest=np.zeros((n, 0, 3), np.float32),
    )
    cam = Camera.pinhole(40, 40, 20, 16, 40, 32)
    out = render_gaussian_set(gs, cam, _look_at(np.array([0, -2.0, 0.5]), np.zeros(3)), backend="cpu").to_numpy()
    for image in (out.colour, out.alpha, out.depth):
        assert np.isfinite(image).all()
    assert (out.alpha >= 0).all() and (out.alpha <= 1 + 1e-6).all()


def test_camera_that_sees_nothing_renders_background() -> None:
    from fusion.render import render_gaussian_set

    gs = convert_points(PointCloud(_scene(100)[0]), ConvertMode.PAPER).gaussians
    cam = Camera.pinhole(40, 40, 20, 16, 40, 32)
    away = _look_at(np.array([0, -5.0, 0]), np.array([0, -10.0, 0]))  # looking away from the scene
    out = render_gaussian_set(gs, cam, away, background=(0.25, 0.5, 0.75), backend="cpu").to_numpy()
    assert np.isfinite(out.colour).all() and np.isfinite(out.depth).all()
    np.testing.assert_allclose(out.colour, np.broadcast_to([0.25, 0.5, 0.75], out.colour.shape), atol=1e-6)
    assert out.alpha.max() == 0


# -- properties ---------------------------------------------------------------------------------------------
coords = st.floats(-50, 50, allow_nan=False, width=64)


@PROPS
@given(
    points=st.lists(st.tuples(coords, coords, coords), min_size=1, max_size=40),
    far=st.booleans(),
    mode=st.sampled_from([ConvertMode.PAPER, ConvertMode.ADAPTIVE]),
)
def test_property_conversion_gives_positive_scales_and_unit_quaternions(points, far, mode) -> None:
    world = np.asarray(points, np.float64) + (UTM if far else 0)
    gs = convert_points(PointCloud.from_world(world), mode).gaussians
    _assert_finite_gaussians(gs)
    scales = np.exp(gs.log_scales.astype(np.float64))
    assert (scales > 0).all() and np.isfinite(scales).all()
    np.testing.assert_allclose(gs.world_means, world, atol=MM, rtol=0)


@PROPS
@given(
    fx=st.floats(50, 2000),
    aspect=st.floats(0.8, 1.25),
    u=st.floats(0, 1),
    v=st.floats(0, 1),
    depth=st.floats(0.1, 1e4),
    model=st.sampled_from(["PINHOLE", "SIMPLE_RADIAL", "OPENCV"]),
    k=st.floats(-0.05, 0.05),
)
def test_property_projection_round_trips_pixels(fx, aspect, u, v, depth, model, k) -> None:
    w, h = 640, 480
    params = {
        "PINHOLE": [fx, fx * aspect, w / 2, h / 2],
        "SIMPLE_RADIAL": [fx, w / 2, h / 2, k],
        "OPENCV": [fx, fx * aspect, w / 2, h / 2, k, -k / 2, 0.0, 0.0],
    }[model]
    cam = Camera(model, w, h, params)
    pixel = np.array([[u * w, v * h]])
    points = cam.unproject(pixel, depth)
    assert np.isfinite(points).all()
    np.testing.assert_allclose(points[:, 2], depth, rtol=1e-12)
    np.testing.assert_allclose(cam.project(points), pixel, atol=1e-6)


@PROPS
@given(
    seed=st.integers(0, 2**31 - 1),
    n_ref=st.integers(1, 60),
    n_cmp=st.integers(1, 60),
    far=st.booleans(),
    max_dist=st.one_of(st.none(), st.floats(0.05, 2.0)),
)
def test_property_c2c_equals_brute_force(seed, n_ref, n_cmp, far, max_dist) -> None:
    from eval.c2c import compare_clouds

    rng = np.random.default_rng(seed)
    ref = rng.uniform(-3, 3, (n_ref, 3))
    cmp = rng.uniform(-3, 3, (n_cmp, 3))
    if seed % 3 == 0:
        cmp[: min(n_cmp, n_ref)] = ref[: min(n_cmp, n_ref)]  # exact duplicates: zero distances
    shift = UTM if far else np.zeros(3)
    result = compare_clouds(PointCloud.from_world(cmp + shift), PointCloud.from_world(ref + shift), max_dist=max_dist)
    truth = cdist(cmp, ref).min(axis=1)
    if max_dist is not None:
        truth = np.minimum(truth, max_dist)
        inliers = truth[truth < max_dist]
    else:
        inliers = truth
    np.testing.assert_allclose(result.distances, truth, atol=1e-9)
    if len(inliers):
        assert result.stats.mean == pytest.approx(inliers.mean(), abs=1e-9)
        assert result.stats.max == pytest.approx(inliers.max(), abs=1e-9)
