"""fusion.convert: the paper's Eq. 1–4 against a hand computation, the adaptive surfels against analytic cases,
and the degenerate inputs that must stay finite."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from core.cameras import quat_to_rotmat
from core.errors import ConfigError, DataError
from core.gaussians import SH_C0
from core.pointcloud import PointCloud
from fusion.convert import (
    ConversionWarning,
    ConvertOptions,
    Source,
    convert_points,
    knn_distances,
    pca_normals,
    points_to_gaussians,
    quats_z_to,
)


def _brute_nn(p: np.ndarray) -> np.ndarray:
    """Distance from each point to its nearest other point, by brute force (float64)."""
    d = np.sqrt(((p[:, None, :] - p[None, :, :]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1)


def _grid(h: float, n: int = 12, z: float = 0.0) -> np.ndarray:
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    return np.c_[i.ravel() * h, j.ravel() * h, np.full(n * n, z)]


def test_paper_mode_equals_hand_computation_of_eq_1_to_4():
    rng = np.random.default_rng(3)
    pos = rng.normal(size=(40, 3)) * [0.3, 0.2, 0.05]
    rgb = rng.integers(0, 256, (40, 3)).astype(np.uint8)
    rgb[0] = (0, 128, 255)
    cloud = PointCloud(pos, origin=[100.0, 200.0, 5.0], colors=rgb, fields={"classification": np.arange(40) % 3})
    opts = ConvertOptions(opacity_logit_min=-50.0, opacity_logit_max=50.0)  # no clamp: pure Eq. 3
    gs = points_to_gaussians(cloud, "paper", opts)

    d = _brute_nn(pos).mean()  # Eq. 2: global mean nearest-neighbour distance
    f_dc = (rgb / 255.0 - 0.5) / 0.28209479177387814  # Eq. 1
    np.testing.assert_array_equal(gs.sh_dc, f_dc.astype(np.float32))
    assert gs.sh_rest.shape == (40, 0, 3)  # f_rest = 0 (degree 0)
    np.testing.assert_array_equal(gs.logit_opacities, np.full(40, np.float32(np.log(1.0 / d))))  # Eq. 3
    np.testing.assert_array_equal(gs.log_scales, np.full((40, 3), np.float32(np.log(d))))  # Eq. 4
    np.testing.assert_array_equal(gs.quats, np.tile(np.float32([1, 0, 0, 0]), (40, 1)))
    np.testing.assert_array_equal(gs.means, pos)  # float64, untouched
    np.testing.assert_array_equal(gs.origin, [100.0, 200.0, 5.0])
    np.testing.assert_array_equal(gs.fields["classification"], np.arange(40) % 3)
    assert (gs.fields["source"] == Source.MVS).all() and gs.fields["source"].dtype == np.uint8
    # SH DC decodes back to the 8-bit colour
    np.testing.assert_array_equal(np.rint((0.5 + SH_C0 * gs.sh_dc.astype(np.float64)) * 255), rgb)


def test_paper_mode_opacity_clamp_bites_with_warning():
    pos = _grid(0.001, 5)  # d = 1 mm -> log(1/d) = 6.91
    cloud = PointCloud(pos, colors=np.zeros((25, 3), np.uint8))
    with pytest.warns(ConversionWarning, match="25 of 25"):
        gs = points_to_gaussians(cloud, "paper", ConvertOptions(opacity_logit_max=4.0))
    assert np.all(gs.logit_opacities == np.float32(4.0))
    np.testing.assert_allclose(gs.log_scales, np.log(0.001), rtol=1e-6)


def test_knn_matches_brute_force_and_is_chunk_invariant():
    rng = np.random.default_rng(0)
    p = rng.random((500, 3))
    p[10] = p[11]  # a duplicate
    full = np.sqrt(((p[:, None] - p[None]) ** 2).sum(-1))
    np.fill_diagonal(full, np.inf)
    expected = np.sort(full, axis=1)[:, :5]
    expected[10, 0] = expected[11, 0] = 0.0  # the duplicates see each other at 0
    for chunk in (7, 100, 10_000):
        dist, idx = knn_distances(p, 5, chunk_size=chunk, return_index=True)
        np.testing.assert_allclose(dist, expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(p[idx] - p[:, None], axis=2), dist, atol=1e-12)


def test_adaptive_on_a_regular_grid_matches_the_analytic_spacing():
    h = 0.02
    pos = _grid(h, 15)
    normals = np.tile([0.0, 0.0, 1.0], (len(pos), 1))
    cloud = PointCloud(pos, colors=np.full((len(pos), 3), 90, np.uint8), normals=normals)
    opts = ConvertOptions(k_neighbors=8, tangent_scale=0.6, thickness_ratio=0.1)
    gs = points_to_gaussians(cloud, "adaptive", opts)
    # interior points: 4 neighbours at h, 4 at h·√2 -> median of 8 = (h + h√2) / 2
    interior = np.all((pos[:, :2] > 1.5 * h) & (pos[:, :2] < 12.5 * h), axis=1)
    s = (h + h * np.sqrt(2)) / 2
    np.testing.assert_allclose(np.exp(gs.log_scales[interior, 0]), 0.6 * s, rtol=1e-6)
    np.testing.assert_allclose(np.exp(gs.log_scales[interior, 2]), 0.06 * s, rtol=1e-6)
    # the normal is +z: identity rotation
    np.testing.assert_allclose(gs.unit_quats, np.tile([1, 0, 0, 0], (len(pos), 1)), atol=1e-7)
    # no visibility or confidence, no outliers: max opacity everywhere
    np.testing.assert_allclose(gs.opacities, 0.98, rtol=1e-5)


@pytest.mark.parametrize("normal", [(0, 0, 1), (0, 0, -1), (1, 0, 0), (0.3, -0.5, 0.81), (0, -1e-12, -1)])
def test_quats_rotate_the_thin_axis_onto_the_normal(normal):
    n = np.asarray(normal, float)
    n /= np.linalg.norm(n)
    q = quats_z_to(n[None])
    R = quat_to_rotmat(q.astype(np.float64))[0]
    np.testing.assert_allclose(R @ [0, 0, 1], n, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-6)


def test_adaptive_surfels_lie_in_a_tilted_plane_with_estimated_normals():
    rng = np.random.default_rng(1)
    n_true = np.array([1.0, 2.0, 2.0]) / 3.0
    a = np.cross(n_true, [1, 0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n_true, a)
    uv = rng.random((2000, 2))
    pos = uv[:, :1] * a + uv[:, 1:] * b
    cloud = PointCloud(pos, colors=np.zeros((2000, 3), np.uint8))  # no normals: PCA
    res = convert_points(cloud, "adaptive")
    assert res.stats.estimated_normals == 2000
    R = quat_to_rotmat(res.gaussians.unit_quats.astype(np.float64))
    thin_axis = R[:, :, 2]
    assert np.abs(thin_axis @ n_true).min() > 0.999  # up to sign
    # the spacing follows the density: 2000 points on a unit square
    assert 0.5 / np.sqrt(2000) < res.stats.median_spacing < 3.0 / np.sqrt(2000)


def test_pca_normals_of_collinear_points_are_unit_and_perpendicular():
    pos = np.c_[np.arange(10.0), np.zeros(10), np.zeros(10)]
    idx = np.array([[j for j in range(10) if j != i][:3] for i in range(10)])
    n = pca_normals(pos, np.arange(10), idx)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(n[:, 0], 0.0, atol=1e-12)


def test_adaptive_opacity_from_views_and_outliers():
    pos = _grid(0.01, 10)
    pos = np.vstack([pos, [[5.0, 5.0, 0.0]]])  # one isolated point far away
    vis = [np.arange(1 + i % 4) for i in range(len(pos))]
    cloud = PointCloud(pos, colors=np.zeros((len(pos), 3), np.uint8), normals=np.tile([0, 0, 1.0], (len(pos), 1)))
    cloud.visibility = vis
    with pytest.warns(ConversionWarning, match="1 of 101"):  # the outlier's opacity hits the floor
        gs = points_to_gaussians(cloud, "adaptive", ConvertOptions(view_saturation=2.0))
    views = np.array([len(v) for v in vis], float)
    expected = 0.98 * (1 - np.exp(-views / 2.0))
    np.testing.assert_allclose(gs.opacities[:-1], expected[:-1], rtol=1e-4)
    assert gs.opacities[-1] < 0.02 * expected[-1]  # the outlier (spacing 500x the median) fades to the floor
    np.testing.assert_allclose(gs.logit_opacities[-1], ConvertOptions().opacity_logit_min)
    # more views -> more opaque
    assert np.all(np.diff([gs.opacities[:-1][views[:-1] == k].mean() for k in (1, 2, 3, 4)]) > 0)


@pytest.mark.parametrize("mode", ["paper", "adaptive"])
@pytest.mark.parametrize(
    "case",
    ["single", "duplicates", "two", "two_coincident", "collinear", "huge", "tiny", "no_colors"],
)
def test_degenerate_clouds_give_finite_clamped_values(mode, case):
    pos = {
        "single": np.zeros((1, 3)),
        "duplicates": np.zeros((6, 3)) + 7.0,
        "two": np.array([[0, 0, 0], [0.3, 0, 0]]),
        "two_coincident": np.zeros((2, 3)),
        "collinear": np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)],
        "huge": np.c_[np.arange(5) * 1e5, np.zeros(5), np.zeros(5)],
        "tiny": np.c_[np.arange(5) * 1e-9, np.zeros(5), np.zeros(5)],
        "no_colors": np.random.default_rng(0).random((30, 3)),
    }[case]
    colors = None if case == "no_colors" else np.full((len(pos), 3), 200, np.uint8)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = convert_points(PointCloud(pos, colors=colors), mode)
    gs = res.gaussians
    gs.validate()
    opts = ConvertOptions()
    assert np.all(gs.logit_opacities >= opts.opacity_logit_min) and np.all(gs.logit_opacities <= opts.opacity_logit_max)
    assert np.all(gs.log_scales >= np.float32(np.log(opts.min_spacing)) - 1e-5)
    assert np.all(gs.log_scales <= np.float32(np.log(opts.max_spacing)) + 1e-5)
    messages = [str(w.message) for w in caught if issubclass(w.category, ConversionWarning)]
    if case in ("single", "duplicates", "two_coincident", "huge", "tiny", "no_colors"):
        assert messages, f"{case}: a clamp or fallback should warn"
        assert any(str(len(pos)) in m for m in messages)  # the count is in the message
    if case in ("two", "collinear"):
        assert not messages


def test_georeferenced_cloud_keeps_local_means_and_origin():
    rng = np.random.default_rng(5)
    world = rng.random((300, 3)) + [612345.25, 5123456.5, 412.0]
    cloud = PointCloud.from_world(world, colors=np.zeros((300, 3), np.uint8))
    gs = points_to_gaussians(cloud, "adaptive")
    assert np.abs(gs.means).max() < 2.0
    np.testing.assert_array_equal(gs.world_means, cloud.world_positions)


def test_bad_input_raises_typed_errors():
    with pytest.raises(DataError, match="empty"):
        points_to_gaussians(PointCloud(np.zeros((0, 3))))
    with pytest.raises(DataError, match="NaN"):
        points_to_gaussians(PointCloud(np.array([[0, 0, np.nan], [1, 1, 1]])))
    with pytest.raises(ConfigError, match="mode"):
        points_to_gaussians(PointCloud(np.zeros((2, 3))), "fancy")
    with pytest.raises(ConfigError, match=r"^option min_spacing must be a float in \(0, inf\), got 0.0$"):
        ConvertOptions(min_spacing=0.0)
    with pytest.raises(ConfigError, match=r"^option tangent_scale must be a float in \(0, inf\), got nan$"):
        ConvertOptions(tangent_scale=float("nan"))
    with pytest.raises(ConfigError, match=r"^option opacity_logit_max must be a float in \(-inf, inf\), got inf$"):
        ConvertOptions(opacity_logit_max=float("inf"))
    with pytest.raises(ConfigError, match="min_spacing must be < max_spacing, got 2.0 >= 1.0"):
        ConvertOptions(min_spacing=2.0, max_spacing=1.0)
    with pytest.raises(ConfigError, match="opacity_logit_min must be < opacity_logit_max"):
        ConvertOptions(opacity_logit_min=1.0, opacity_logit_max=1.0)


def test_quaternions_from_given_normals_equal_quats_z_to_and_flag_missing_normals():
    """The one-pass kernel used for MVS normals gives exactly quats_z_to of the normalised normals; missing normals
    (zero, NaN, inf) are flagged and get PCA normals (or +z with too few neighbours)."""
    from fusion.convert import quats_from_given_normals

    rng = np.random.default_rng(4)
    normals = rng.normal(size=(5000, 3)).astype(np.float32)
    normals[:4] = [[0, 0, -1], [0, 0, 1], [0, 0, -3], [1e-4, 0, -2]]
    bad = np.array([10, 11, 12, 13])
    normals[bad] = [[0, 0, 0], [np.nan, 0, 1], [np.inf, 0, 0], [1e-7, 0, 0]]
    cloud = PointCloud(rng.random((5000, 3)), normals=normals)
    quats, missing = quats_from_given_normals(cloud)
    np.testing.assert_array_equal(np.flatnonzero(missing), bad)
    good = ~missing
    n64 = normals[good].astype(np.float64)
    np.testing.assert_array_equal(quats[good], quats_z_to(n64 / np.linalg.norm(n64, axis=1, keepdims=True)))
    assert quats_from_given_normals(PointCloud(rng.random((5, 3))))[1].all()


@pytest.mark.parametrize("confidence", ["views", "field", "none"])
def test_adaptive_matches_a_numpy_reference_of_the_formulas(confidence):
    """The fused numba passes of the adaptive mode against the module docstring's formulas in plain numpy, with the
    k-d tree for the spacing; duplicates (spacing clamped) and a confidence field with NaN/inf/out-of-range values."""
    rng = np.random.default_rng(11)
    pos = np.c_[rng.random((3000, 2)) * 2.0, 0.01 * rng.random(3000)]
    pos[100:140] = pos[:40]  # exact duplicates
    pos[140:160] = pos[0]  # 21 coincident points: all 8 neighbours at distance 0 -> spacing 0, clamped
    cloud = PointCloud(
        pos, colors=rng.integers(0, 256, (3000, 3), dtype=np.uint8), normals=np.tile([0, 0, 1.0], (3000, 1))
    )
    opts = ConvertOptions(opacity_logit_min=-50.0, opacity_logit_max=50.0)
    if confidence == "views":
        cloud.visibility = [np.arange(i % 5) for i in range(3000)]
        conf = 1.0 - np.exp(-np.array([i % 5 for i in range(3000)], float) / opts.view_saturation)
    elif confidence == "field":
        c = rng.uniform(-0.5, 1.5, 3000).astype(np.float32)
        c[:5] = [np.nan, np.inf, -np.inf, 0.0, 1.0]
        cloud.fields["confidence"] = c
        conf = np.clip(np.nan_to_num(c.astype(np.float64), nan=0.0), 0.0, 1.0)
    else:
        conf = np.ones(3000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConversionWarning)
        res = convert_points(cloud, "adaptive", opts)
    # logits are stored as float32: compared to 2 float32 ulps
    dist, _ = knn_distances(pos, opts.k_neighbors, backend="kdtree")
    nz = [row[row > 0] for row in dist]
    s = np.array([np.median(r) if len(r) else 0.0 for r in nz])
    assert res.stats.clamped_spacing == np.count_nonzero((s < opts.min_spacing) | (s > opts.max_spacing)) > 0
    s = np.clip(s, opts.min_spacing, opts.max_spacing)
    assert res.stats.median_spacing == pytest.approx(np.median(s), rel=1e-12)
    sigma_t = np.maximum(opts.tangent_scale * s, opts.min_spacing)
    sigma_n = np.maximum(opts.thickness_ratio * sigma_t, opts.min_spacing)
    np.testing.assert_allclose(res.gaussians.log_scales, np.log(np.c_[sigma_t, sigma_t, sigma_n]), rtol=1e-6)
    alpha = np.clip(
        opts.max_opacity * conf * np.minimum(1.0, opts.outlier_spacing_factor * np.median(s) / s), 1e-6, 1 - 1e-6
    )
    np.testing.assert_allclose(res.gaussians.logit_opacities, np.log(alpha) - np.log1p(-alpha), rtol=3e-7, atol=1e-7)
    np.testing.assert_array_equal(res.gaussians.sh_dc, ((cloud.colors / 255.0 - 0.5) / SH_C0).astype(np.float32))
