"""Per-point features: the numba kernel and pgeof held to the numpy twin, analytic shapes, registry, multi-view."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from classify.features import FeatureGroup, FeatureOptions, GeometricOptions, ViewData, compute_features
from classify.features.eigen_numba import eigen_numba
from classify.features.geometric import (
    Eigen,
    eigen_features,
    eigen_numpy,
    eigen_pgeof,
    geometric_features,
    point_spacing,
    voxel_downsample,
)
from classify.features.multiview import multiview_features
from classify.features.radiometric import color_variance, rgb_hsv
from classify.features.registry import feature_specs, resolve_names
from core.cameras import Camera, Cameras, View
from core.errors import ConfigError, DataError
from core.pointcloud import PointCloud


def _wavy_plane(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 1, (n, 2))
    return np.c_[xy, 0.03 * np.sin(5 * xy[:, 0]) + rng.normal(0, 1e-4, n)]


def _random_blobs(n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3)) * [1.0, 0.4, 0.1]


@pytest.mark.parametrize("make", [_wavy_plane, _random_blobs])
def test_numba_kernel_matches_numpy_twin(make):
    pts = make(3000)
    _, idx = cKDTree(pts).query(pts, k=16)
    w_ref, n_ref = eigen_numpy(pts, idx)
    w, n = eigen_numba(pts, idx)
    # Closed-form cubic vs LAPACK in float64: relative to the largest eigenvalue, agreement to ~1e-9
    # (the trigonometric solution loses a few digits when two eigenvalues nearly coincide).
    assert np.max(np.abs(w - w_ref) / w_ref[:, :1]) < 1e-8
    # Normals agree up to sign except where λ2 ≈ λ3 (normal ill-defined): require it on well-separated ones.
    separated = (w_ref[:, 1] - w_ref[:, 2]) > 1e-3 * w_ref[:, 0]
    assert separated.mean() > 0.9
    assert np.min(np.abs(np.sum(n[separated] * n_ref[separated], axis=1))) > 1 - 1e-6


def test_pgeof_largest_eigenvalue_and_normal_match_twin():
    pts = _random_blobs(2000)
    _, idx = cKDTree(pts).query(pts, k=16)
    w_ref, n_ref = eigen_numpy(pts, idx)
    w, n = eigen_pgeof(pts, idx)
    # pgeof computes in float32: λ1 to 1e-5 relative; the normal to 1e-4 in |cos|.
    assert np.max(np.abs(w[:, 0] - w_ref[:, 0]) / w_ref[:, 0]) < 1e-5
    sep = (w_ref[:, 1] - w_ref[:, 2]) > 1e-2 * w_ref[:, 0]
    assert np.min(np.abs(np.sum(n[sep] * n_ref[sep], axis=1))) > 1 - 1e-4


def test_eigen_features_analytic_line_plane_blob():
    rng = np.random.default_rng(2)
    t = np.linspace(0, 1, 400)
    line = np.c_[t, 2 * t, 0 * t]
    plane = np.c_[rng.uniform(0, 1, (400, 2)), np.zeros(400)]
    blob = rng.normal(size=(400, 3))
    feats = {}
    for pts, key in ((line, "line"), (plane, "plane"), (blob, "blob")):
        _, idx = cKDTree(pts).query(pts, k=16)
        w, n = eigen_numpy(pts, idx)
        feats[key] = eigen_features(Eigen(w, n, np.full(len(pts), 0.1)), cell=0.01, k=16)
    # A line: e2 = e3 = 0, so linearity = anisotropy = 1 and entropy 0.
    assert np.allclose(feats["line"]["linearity"], 1) and np.allclose(feats["line"]["eigenentropy"], 0, atol=1e-9)
    # A plane: e3 = 0, so scattering = 0, anisotropy = 1 and linearity + planarity = 1.
    p = feats["plane"]
    assert np.allclose(p["scattering"], 0, atol=1e-12) and np.allclose(p["anisotropy"], 1)
    assert np.allclose(p["linearity"] + p["planarity"], 1)
    # A 3D Gaussian blob scatters far more than the plane.
    assert np.median(feats["blob"]["scattering"]) > 0.1
    # A horizontal plane: verticality 0; a vertical one: 1; change of curvature 0 on both.
    _, idx = cKDTree(plane).query(plane, k=16)
    w, n = eigen_numpy(plane, idx)
    f = eigen_features(Eigen(w, n, np.full(400, 0.1)), 0.01, 16)
    assert np.max(f["verticality"]) < 1e-9 and np.max(f["change_of_curvature"]) < 1e-12
    wall = plane[:, [0, 2, 1]]
    w, n = eigen_numpy(wall, idx)
    f = eigen_features(Eigen(w, n, np.full(400, 0.1)), 0.01, 16)
    assert np.min(f["verticality"]) > 1 - 1e-9


def test_degenerate_neighbourhoods_give_zeros_not_nan():
    pts = np.zeros((20, 3))
    w, n = eigen_numpy(pts, np.tile(np.arange(16), (20, 1)))
    f = eigen_features(Eigen(w, n, np.zeros(20)), 0.01, 16)
    for key, v in f.items():
        assert np.isfinite(v).all(), key


def test_point_spacing_on_a_grid_and_errors():
    g = np.stack(np.meshgrid(np.arange(30), np.arange(30), indexing="ij"), -1).reshape(-1, 2) * 0.02
    pts = np.c_[g, np.zeros(len(g))]
    assert point_spacing(pts) == pytest.approx(0.02)
    assert point_spacing(np.r_[pts, pts]) == pytest.approx(0.02)  # duplicates ignored
    with pytest.raises(DataError):
        point_spacing(np.zeros((5, 3)))


def test_voxel_downsample_centroids_brute_force():
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 1, (500, 3))
    cent, inv = voxel_downsample(pts, 0.25)
    for v in range(len(cent)):
        assert np.allclose(cent[v], pts[inv == v].mean(axis=0))
    keys = np.floor((pts - pts.min(0)) / 0.25).astype(int)
    for v in range(len(cent)):
        assert len({tuple(k) for k in keys[inv == v]}) == 1


def test_scale_invariance_of_geometric_features():
    """Neighbourhoods are in units of spacing: scaling the cloud by 1000 leaves every feature unchanged."""
    pts = _wavy_plane(4000)
    a = geometric_features(pts, options=GeometricOptions(backend="numpy"))
    b = geometric_features(pts * 1000.0, options=GeometricOptions(backend="numpy"))
    assert b.spacing == pytest.approx(1000 * a.spacing, rel=1e-9)
    for name in a.features:
        assert np.allclose(a.features[name], b.features[name], atol=1e-4), name


def test_backends_agree_on_every_geometric_feature():
    pts = _wavy_plane(5000)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    a = geometric_features(pts, normals, GeometricOptions(backend="numpy"))
    b = geometric_features(pts, normals, GeometricOptions(backend="numba"))
    for name in a.features:
        assert np.allclose(a.features[name], b.features[name], atol=1e-5), name


def test_rgb_hsv_and_color_variance():
    c = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [128, 128, 128]], dtype=np.uint8)
    f = rgb_hsv(c)
    assert np.allclose(f["hue"], [0, 1 / 3, 2 / 3, 0], atol=1e-6)
    assert np.allclose(f["saturation"], [1, 1, 1, 0]) and np.allclose(f["value"][3], 128 / 255)
    neigh = np.array([[0, 1], [1, 1], [2, 3], [3, 3]])
    v = color_variance(c, neighbours=neigh)
    # Brute force: std over the two neighbours per channel, averaged.
    ref = np.array([np.std(c[n] / 255.0, axis=0).mean() for n in neigh])
    assert np.allclose(v, ref, atol=1e-6)


def test_registry_resolution_and_errors():
    specs = feature_specs(3)
    assert "planarity_s2" in specs and specs["n_views"].group is FeatureGroup.MULTIVIEW
    assert all(s.unit and s.meaning for s in specs.values())
    assert resolve_names(("planarity",), 2, ()) == ("planarity_s0", "planarity_s1")
    assert resolve_names(("radiometric",), 1, ())[0] == "red"
    with pytest.raises(ConfigError, match="unknown feature"):
        resolve_names(("shininess",), 1, ())


def test_removed_groups_and_their_features_are_refused_naming_the_group():
    """The four view-based groups removed in 0.4: their names and their features' names are a ConfigError naming
    the group (not "unknown feature"), through the registry and through FeatureOptions; the default selection is
    the 51 features of the three remaining groups, none of them a removed one's."""
    from classify.features.registry import REMOVED_GROUPS, feature_group

    assert [g.value for g in FeatureGroup] == ["geometric", "radiometric", "multiview"]
    default = FeatureOptions().selected()
    assert len(default) == 51 and list(default) == list(feature_specs(3))
    for group, features in REMOVED_GROUPS.items():
        assert not set(features) & set(default)
        for name in (group, features[0]):
            with pytest.raises(ConfigError, match=f"feature group {group}: removed in 0.4") as err:
                FeatureOptions(names=("planarity", name)).selected()
            assert "docs/migration.md" in err.value.one_line()
        with pytest.raises(ConfigError, match=f"feature group {group}: removed"):
            feature_group(group)
    assert feature_group("multiview") is FeatureGroup.MULTIVIEW
    with pytest.raises(ConfigError, match="unknown feature group 'shininess'; known: geometric, radiometric"):
        feature_group("shininess")


def test_compute_features_table_and_missing_inputs():
    pts = _wavy_plane(2000)
    rng = np.random.default_rng(0)
    cloud = PointCloud(pts, colors=rng.integers(0, 255, (len(pts), 3)).astype(np.uint8))
    opts = FeatureOptions(groups=(FeatureGroup.GEOMETRIC, FeatureGroup.RADIOMETRIC))
    t = compute_features(cloud, opts)
    assert t.values.shape == (2000, len(opts.selected())) and t.values.dtype == np.float32
    assert np.isfinite(t.values).all()
    with pytest.raises(ConfigError, match="colours"):
        compute_features(PointCloud(pts), opts)
    with pytest.raises(ConfigError, match="multi-view"):
        compute_features(cloud, FeatureOptions())


# -- multi-view ---------------------------------------------------------------------------------------------------
def _two_view_rig(depth_scale: float = 1.0):
    """Two pinhole cameras 1 m above a plane z = 0, looking down; the photo is a checkerboard on the plane."""
    cam = Camera.pinhole(50.0, 50.0, 32.0, 24.0, 64, 48)
    down = np.diag([1.0, -1.0, -1.0])  # camera z axis = world −z
    views = {}
    for i, cx in enumerate((-0.1, 0.1)):
        centre = np.array([cx, 0.0, 1.0])
        views[i + 1] = View.from_matrix(i + 1, f"v{i}.png", 1, np.c_[down, -down @ centre])
    cams = Cameras({1: cam}, views)

    def image(name: str) -> np.ndarray:
        v = cams.by_name(name)
        rows, cols = np.mgrid[0:48, 0:64] + 0.5
        rays = np.stack([(cols - 32) / 50, (rows - 24) / 50, np.ones_like(cols)], -1) @ v.rotation
        t = -v.center[2] / rays[..., 2]
        world = v.center + rays * t[..., None]
        board = ((np.floor(world[..., 0] / 0.05) + np.floor(world[..., 1] / 0.05)) % 2).astype(np.uint8)
        return np.repeat((board * 200 + 30)[..., None], 3, axis=2)

    def depth(name: str) -> np.ndarray:
        return np.full((48, 64), 1.0 * depth_scale, dtype=np.float32)

    return cams, ViewData(cams, image, depth)


def test_multiview_on_a_plane_seen_by_two_views():
    cams, views = _two_view_rig()
    pts = np.array([[0.0, 0.0, 0.0], [0.01, 0.02, 0.0], [0.0, 0.0, 0.5], [5.0, 0.0, 0.0]])
    vis = [np.array([1, 2]), np.array([1, 2]), np.array([1, 2]), np.array([], dtype=np.int64)]
    f = multiview_features(pts, vis, views)
    assert list(f["n_views"]) == [2, 2, 2, 0]
    # Rays from (±0.1, 0, 1) to the origin: angle 2·atan(0.1) between them.
    assert f["triangulation_spread_deg"][0] == pytest.approx(np.degrees(2 * np.arctan(0.1)), abs=1e-6)
    # On the plane both depth maps agree; the floating point at z = 0.5 is in front of what both views see.
    assert f["depth_agree"][0] == 1.0 and f["depth_freespace"][0] == 0.0
    assert f["depth_freespace"][2] == 1.0 and f["depth_agree"][2] == 0.0
    # The point outside both frusta: no frustum view, no fusing view.
    assert f["view_ratio"][3] == 0.0 and f["depth_agree"][3] == 0.0
    # A Lambertian plane: the same colour in both views (nearest pixel; away from checker edges).
    assert f["color_std_views"][0] == pytest.approx(0.0, abs=1e-9)


def test_multiview_rejects_mismatched_visibility():
    _, views = _two_view_rig()
    with pytest.raises(DataError):
        multiview_features(np.zeros((2, 3)), [np.array([1])], views)


@pytest.mark.parametrize("make", [_wavy_plane, _random_blobs])
def test_grid_search_gives_the_kdtree_neighbourhoods(make):
    """The column-grid k-NN (core.knn) and the k-d tree find the same neighbourhoods: equal radii and features."""
    from classify.features.geometric import level_neighbours

    pts = make(4000)
    d_grid, i_grid = level_neighbours(pts, 16, GeometricOptions(search="grid"))
    d_tree, i_tree = level_neighbours(pts, 16, GeometricOptions(search="kdtree"))
    assert i_grid.shape == (len(pts), 15) and not (i_grid == np.arange(len(pts))[:, None]).any()
    np.testing.assert_allclose(d_grid, d_tree, rtol=1e-12, atol=0)
    d_ref, _ = cKDTree(pts).query(pts, k=16)
    np.testing.assert_allclose(d_grid, d_ref[:, 1:], rtol=1e-12, atol=0)
    # Continuous random coordinates have no ties: the neighbour sets are identical.
    assert np.array_equal(np.sort(i_grid, axis=1), np.sort(i_tree, axis=1))
    a = geometric_features(pts, options=GeometricOptions(search="grid"))
    b = geometric_features(pts, options=GeometricOptions(search="kdtree"))
    for name in a.features:
        np.testing.assert_allclose(a.features[name], b.features[name], atol=1e-6, err_msg=name)
    with pytest.raises(ConfigError):
        GeometricOptions(search="octree")


def test_spacing_from_the_finest_neighbours_equals_point_spacing():
    """geometric_features takes the spacing from its full-cloud k-NN: the same median as point_spacing (which
    uses every point below its sample size), duplicates ignored."""
    from classify.features.geometric import level_neighbours, spacing_from_neighbours

    pts = _wavy_plane(3000)
    pts = np.r_[pts, pts[:200]]  # duplicates
    dist, _ = level_neighbours(pts, 16, GeometricOptions())
    assert spacing_from_neighbours(dist) == pytest.approx(point_spacing(pts), rel=1e-12)
    assert geometric_features(pts).spacing == pytest.approx(point_spacing(pts), rel=1e-12)
    with pytest.raises(DataError):
        spacing_from_neighbours(np.zeros((5, 4)))


@pytest.mark.parametrize("backend", ["numba", "numpy", "pgeof"])
def test_implicit_self_equals_the_listed_self(backend):
    """with_self (the point itself not listed, at row offset) gives the same eigen analysis as listing it."""
    from classify.features.geometric import eigen_backend

    pts = _wavy_plane(1000)
    _, idx = cKDTree(pts).query(pts, k=16)
    fn = eigen_backend(backend)
    w_ref, n_ref = fn(pts, idx[200:700])
    w, n = fn(pts, idx[200:700, 1:], True, 200)
    np.testing.assert_allclose(w, w_ref, rtol=1e-6, atol=1e-18)
    assert np.min(np.abs(np.sum(n * n_ref, axis=1))) > 1 - 1e-5


def test_features_follow_the_points_whatever_their_order():
    """compute_features works on a spatially sorted copy: permuting the input permutes every feature row."""
    from classify.features.geometric import spatial_order

    rng = np.random.default_rng(4)
    pts = _wavy_plane(3000)
    cloud = PointCloud(pts, colors=rng.integers(0, 255, (len(pts), 3)).astype(np.uint8))
    perm = rng.permutation(len(pts))
    shuffled = PointCloud(pts[perm], colors=cloud.colors[perm])
    opts = FeatureOptions(groups=(FeatureGroup.GEOMETRIC, FeatureGroup.RADIOMETRIC))
    a, b = compute_features(cloud, opts), compute_features(shuffled, opts)
    np.testing.assert_allclose(b.values, a.values[perm], rtol=1e-5, atol=1e-6)
    order = spatial_order(pts)
    assert np.array_equal(np.sort(order), np.arange(len(pts)))
    # Morton order keeps neighbours close in memory: consecutive points are near in space.
    step = np.linalg.norm(np.diff(pts[order], axis=0), axis=1)
    assert np.median(step) < 0.2 * np.median(np.linalg.norm(np.diff(pts, axis=0), axis=1))


def test_height_above_ground_brute_force():
    """Against a brute-force loop: the lowest z of the points whose column (floor of x / cell, y / cell, from the
    cloud's minimum) is one of the 3 × 3 around the point's own; a box on a floor is 'cell' units high."""
    from classify.features.geometric import height_above_ground

    rng = np.random.default_rng(3)
    pts = np.c_[rng.uniform(0, 5, (400, 2)), rng.normal(0, 0.3, 400)]
    cell = 0.7
    h = height_above_ground(pts, cell)
    ij = np.floor((pts[:, :2] - pts[:, :2].min(axis=0)) / cell).astype(int)
    ref = np.array([(p[2] - pts[np.all(np.abs(ij - ij[i]) <= 1, axis=1), 2].min()) / cell for i, p in enumerate(pts)])
    assert np.allclose(h, ref) and (h >= 0).all() and np.isclose(h.min(), 0.0)
    floor = np.c_[rng.uniform(0, 4, (500, 2)), np.zeros(500)]
    box = np.c_[rng.uniform(1.8, 2.2, (50, 2)), np.full(50, 2.0)]
    hb = height_above_ground(np.r_[floor, box], 1.0)
    assert np.allclose(hb[:500], 0.0) and np.allclose(hb[500:], 2.0)
    # Only the coarser scales carry it.
    assert "height_s1" in feature_specs(3) and "height_s0" not in feature_specs(3)
    assert resolve_names(("height",), 3, ()) == ("height_s1", "height_s2")


def test_rgb_hsv_kernel_matches_scikit_image_on_every_kind_of_colour():
    from skimage.color import rgb2hsv

    rng = np.random.default_rng(7)
    c = rng.integers(0, 256, (20000, 3)).astype(np.uint8)
    ties = rng.integers(0, 256, (300, 1)).astype(np.uint8)
    c = np.vstack([c, np.repeat(ties, 3, axis=1),  # greys
                   np.hstack([ties, ties, ties // 2]), np.hstack([ties // 2, ties, ties]),  # two channels tie
                   np.hstack([ties, ties // 3, ties]), [[0, 0, 0], [255, 255, 255]]]).astype(np.uint8)  # fmt: skip
    f = rgb_hsv(c)
    ref = rgb2hsv((c.astype(np.float32) / np.float32(255.0))[None])[0]
    for j, name in enumerate(("hue", "saturation", "value")):
        np.testing.assert_allclose(f[name], ref[:, j], atol=2e-7, err_msg=name)


def test_reorder_kernels_match_their_numpy_twins():
    from classify.features.reorder import gather_rows, morton_codes, renumber_neighbours, scatter_column

    rng = np.random.default_rng(8)
    pts = rng.normal(size=(5000, 3)) * [3.0, 1.0, 0.2] + 1e5  # large coordinates, a flat-ish cloud
    lo = pts.min(axis=0)
    span = (pts.max(axis=0) - lo).max()
    q = np.minimum(((pts - lo) / span * (1 << 16)).astype(np.uint64), np.uint64((1 << 16) - 1))
    code = np.zeros(len(pts), dtype=np.uint64)
    for b in range(16):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b + axis)
    np.testing.assert_array_equal(morton_codes(pts), code)
    order = rng.permutation(len(pts))
    neigh = rng.integers(0, len(pts), (len(pts), 7))
    twin = np.empty_like(neigh)
    twin[order] = order[neigh]
    np.testing.assert_array_equal(renumber_neighbours(neigh, order), twin)
    values = np.zeros((len(pts), 3), np.float32)
    col = rng.normal(size=len(pts)).astype(np.float32)
    scatter_column(values, order, 1, col)
    expected = np.zeros_like(values)
    expected[order, 1] = col
    np.testing.assert_array_equal(values, expected)
    for a in (pts, pts.astype(np.float32), rng.integers(0, 256, (len(pts), 3)).astype(np.uint8)):
        got = gather_rows(a, order)
        assert got.dtype == a.dtype
        np.testing.assert_array_equal(got, a[order])
