"""C2C distances, statistics, threshold scores, C2M and ICP against independent truth.

Truth: brute-force nearest neighbours on small clouds (numpy, exact), hand-counted precision/recall on
tiny clouds, analytic point-to-plane distances for C2M, a known rigid motion for ICP.
"""

import numpy as np
import pytest

from core.errors import ConfigError, DataError
from core.io import read_point_cloud
from core.pointcloud import PointCloud
from eval.c2c import (
    compare_clouds,
    distance_stats,
    histogram,
    morton_order,
    nearest_distances,
    per_class_stats,
    threshold_scores,
)
from eval.c2m import Mesh, compare_cloud_to_mesh, is_mesh_file, read_mesh
from eval.geometry import GeometryOptions, evaluate_geometry
from eval.registration import icp_point_to_plane


def brute_force(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)).min(axis=1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_nearest_distances_equal_brute_force(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(700, 3))
    b = rng.normal(size=(900, 3)) * [2.0, 1.0, 0.5]
    expected = brute_force(a, b)
    for chunk, sort in ((1000, False), (97, True), (1, False)):
        got = nearest_distances(a, b, chunk_size=chunk, sort_queries=sort)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)


def test_sorted_queries_on_large_input_keep_input_order():
    rng = np.random.default_rng(3)
    a = rng.uniform(0, 50, size=(300_000, 3))
    b = rng.uniform(0, 50, size=(20_000, 3))
    plain = nearest_distances(a, b, sort_queries=False)
    sorted_ = nearest_distances(a, b, sort_queries=True, chunk_size=65_536)
    np.testing.assert_array_equal(plain, sorted_)
    order = morton_order(a)
    assert np.array_equal(np.sort(order), np.arange(len(a)))


def test_stats_match_numpy():
    rng = np.random.default_rng(4)
    d = rng.gamma(2.0, 0.01, size=5001)
    s = distance_stats(d)
    assert s.count == 5001
    assert s.mean == pytest.approx(d.mean(), abs=1e-15)
    assert s.std == pytest.approx(d.std(ddof=0), abs=1e-15)
    assert s.median == pytest.approx(np.sort(d)[2500], abs=1e-15)
    assert s.rmse == pytest.approx(np.sqrt((d**2).mean()), abs=1e-15)
    for q, v in ((90, s.p90), (95, s.p95), (99, s.p99)):
        assert v == pytest.approx(np.percentile(d, q), abs=1e-15)
    assert s.max == d.max() and s.min == d.min()
    assert s.outlier_count == 0 and s.max_dist is None


def test_max_dist_outliers_counted_and_excluded():
    d = np.array([0.01, 0.02, 0.03, 0.5, 0.7])
    s = distance_stats(d, max_dist=0.1)
    assert s.count == 3 and s.outlier_count == 2 and s.outlier_share == pytest.approx(0.4)
    assert s.mean == pytest.approx(0.02) and s.max == pytest.approx(0.03)
    empty = distance_stats(np.array([0.5]), max_dist=0.1)
    assert empty.count == 0 and empty.mean == 0.0 and empty.outlier_share == 1.0
    assert np.isfinite(list(empty.as_dict().values())[1:10]).all()


def test_max_dist_in_compare_clamps_field_and_counts():
    ref = PointCloud(np.zeros((1, 3)))
    cmp = PointCloud(np.array([[0.05, 0, 0], [0, 0.2, 0], [0, 0, 3.0]]))
    r = compare_clouds(cmp, ref, max_dist=0.5)
    np.testing.assert_allclose(r.distances, [0.05, 0.2, 0.5])
    assert r.stats.count == 2 and r.stats.outlier_count == 1


def test_threshold_scores_hand_computed():
    # Reference: 4 points on a line at x = 0, 1, 2, 3. Compared: x = 0.05, 1.3, 10.
    ref = PointCloud(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]))
    cmp = PointCloud(np.array([[0.05, 0, 0], [1.3, 0, 0], [10.0, 0, 0]]))
    r = compare_clouds(cmp, ref, tau=0.2)
    # compared -> reference: 0.05, 0.3, 7  -> 1 of 3 within 0.2
    np.testing.assert_allclose(r.distances, [0.05, 0.3, 7.0])
    assert r.scores.precision == pytest.approx(1 / 3)
    # reference -> compared: 0.05, 0.3, 0.7, 1.7 -> 1 of 4 within 0.2
    assert r.scores.recall == pytest.approx(1 / 4) and r.scores.completeness == r.scores.recall
    assert r.scores.fscore == pytest.approx(2 * (1 / 3) * (1 / 4) / (1 / 3 + 1 / 4))
    assert r.reverse.mean == pytest.approx((0.05 + 0.3 + 0.7 + 1.7) / 4)
    r2 = compare_clouds(cmp, ref, tau=0.5)  # 2 of 3 and 2 of 4
    assert (r2.scores.precision, r2.scores.recall) == pytest.approx((2 / 3, 2 / 4))
    # tau > max_dist: precision stays exact although distances are clamped at max_dist
    r3 = compare_clouds(cmp, ref, tau=0.5, max_dist=0.1)
    assert r3.scores.precision == pytest.approx(2 / 3) and r3.stats.outlier_count == 2
    assert threshold_scores(np.array([1.0]), np.array([1.0]), 0.5).fscore == 0.0
    with pytest.raises(ConfigError):
        threshold_scores(np.array([1.0]), np.array([1.0]), 0.0)


def test_per_class_stats_brute_force():
    rng = np.random.default_rng(5)
    d = rng.random(300)
    classes = rng.integers(0, 3, 300)
    pc = per_class_stats(d, classes)
    assert sorted(pc) == [0, 1, 2]
    for k, s in pc.items():
        assert s.count == int((classes == k).sum())
        assert s.mean == pytest.approx(d[classes == k].mean())
    ref = PointCloud(rng.normal(size=(200, 3)))
    cmp = PointCloud(rng.normal(size=(300, 3)), fields={"classification": classes.astype(np.uint8)})
    r = compare_clouds(cmp, ref)
    expected = brute_force(cmp.positions, ref.positions)
    for k, s in r.per_class.items():
        assert s.mean == pytest.approx(expected[classes == k].mean(), abs=1e-12)


def test_utm_coordinates_match_shifted_copies():
    """Same geometry at UTM-like coordinates (stored with and without an origin) and near zero: same stats."""
    rng = np.random.default_rng(6)
    local_ref = rng.uniform(0, 30, size=(20_000, 3)) * [1, 1, 0.2]
    local_cmp = local_ref[::3] + rng.normal(0, 0.02, size=(len(local_ref[::3]), 3))
    utm = np.array([693_512.25, 5_334_871.5, 412.75])
    near = compare_clouds(PointCloud(local_cmp), PointCloud(local_ref), tau=0.03, max_dist=0.1)
    # 1) world coordinates in `positions`, zero origins
    far_raw = compare_clouds(PointCloud(local_cmp + utm), PointCloud(local_ref + utm), tau=0.03, max_dist=0.1)
    # 2) different origins for the two clouds
    far_origin = compare_clouds(
        PointCloud.from_world(local_cmp + utm, origin=utm + [13.0, -7.0, 1.0]),
        PointCloud.from_world(local_ref + utm, origin=utm - [100.0, 50.0, 0.0]),
        tau=0.03,
        max_dist=0.1,
    )
    for far in (far_raw, far_origin):
        np.testing.assert_allclose(far.distances, near.distances, rtol=0, atol=1e-6)
        for key, v in near.stats.as_dict().items():
            if isinstance(v, float):
                assert getattr(far.stats, key) == pytest.approx(v, abs=1e-6), key
        assert far.scores.fscore == pytest.approx(near.scores.fscore, abs=1e-9)


def test_bad_inputs_raise_typed_errors():
    ok = PointCloud(np.zeros((2, 3)))
    with pytest.raises(DataError, match="empty"):
        compare_clouds(PointCloud(np.zeros((0, 3))), ok)
    with pytest.raises(DataError, match="empty"):
        compare_clouds(ok, PointCloud(np.zeros((0, 3))))
    with pytest.raises(DataError, match="NaN"):
        compare_clouds(PointCloud(np.array([[np.nan, 0, 0]])), ok)
    with pytest.raises(ConfigError):
        nearest_distances(np.zeros((2, 3)), np.zeros((2, 3)), max_dist=-1.0)


def test_histogram_counts_everything():
    d = np.array([0.05, 0.15, 0.25, 0.35, 5.0])
    edges, counts = histogram(d, bins=4, upper=0.4)
    assert len(edges) == 5 and counts.tolist() == [1, 1, 1, 2]  # 5.0 is clamped into the last bin


def _plane_mesh(origin=np.zeros(3)) -> Mesh:
    v = np.array([[-10.0, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]])
    return Mesh(v, np.array([[0, 1, 2], [0, 2, 3]]), np.asarray(origin, dtype=np.float64))


def test_c2m_analytic_plane_with_large_origin():
    rng = np.random.default_rng(7)
    origin = np.array([500_000.0, 4_000_000.0, 250.0])
    local = np.c_[rng.uniform(-5, 5, (1000, 2)), rng.uniform(-0.5, 0.5, 1000)]
    cloud = PointCloud.from_world(local + origin, origin=origin + [3.0, 2.0, 0.0])
    r = compare_cloud_to_mesh(cloud, _plane_mesh(origin))
    # float32 ray casting in the mesh's local frame: |z| <= 0.5 m, float32 resolution ~3e-8 m there
    np.testing.assert_allclose(r.distances, np.abs(local[:, 2]), atol=1e-6)
    # beyond the plane's border the distance is to the edge
    side = compare_cloud_to_mesh(PointCloud(np.array([[13.0, 0, 4.0]]), origin=origin), _plane_mesh(origin))
    assert side.distances[0] == pytest.approx(5.0, abs=1e-5)


def test_mesh_file_detection_and_reading(tmp_path):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_box(1.0, 2.0, 3.0)
    path = tmp_path / "box.ply"
    o3d.io.write_triangle_mesh(str(path), m)
    assert is_mesh_file(path)
    mesh = read_mesh(path)
    assert len(mesh.triangles) == 12
    pts = PointCloud(np.array([[0.5, 1.0, 4.0], [0.5, 1.0, 1.5], [2.0, 1.0, 1.5]]))
    r = compare_cloud_to_mesh(pts, mesh)
    np.testing.assert_allclose(r.distances, [1.0, 0.5, 1.0], atol=1e-6)
    cloud_path = tmp_path / "cloud.ply"
    from core.io import write_point_cloud

    write_point_cloud(cloud_path, pts)
    assert not is_mesh_file(cloud_path)


def test_icp_recovers_small_rigid_motion():
    rng = np.random.default_rng(8)
    # a non-degenerate surface: three orthogonal planes (a corner)
    n = 4000
    u = rng.uniform(0, 5, size=(3, n, 2))
    ref_pts = np.concatenate(
        [np.c_[u[0], np.zeros(n)], np.c_[u[1][:, 0], np.zeros(n), u[1][:, 1]], np.c_[np.zeros(n), u[2]]]
    )
    angle = np.deg2rad(0.8)
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    shift = np.array([0.03, -0.02, 0.01])
    origin = np.array([300_000.0, 6_000_000.0, 50.0])
    moved = ref_pts @ rot.T + shift
    res = icp_point_to_plane(PointCloud(moved, origin), PointCloud(ref_pts, origin), max_correspondence=0.2)
    back = res.apply(PointCloud(moved, origin)).with_origin(origin).positions
    assert np.abs(back - ref_pts).max() < 1e-4
    assert res.fitness > 0.99 and res.inlier_rmse < 1e-4
    # the world transform maps world points the same way
    w = np.c_[moved + origin, np.ones(len(moved))] @ res.world_transform.T
    assert np.abs(w[:, :3] - (ref_pts + origin)).max() < 1e-4


def test_evaluate_geometry_writes_fields_and_plots(tmp_path):
    rng = np.random.default_rng(9)
    origin = np.array([400_000.0, 5_000_000.0, 100.0])
    ref = PointCloud(rng.uniform(0, 10, (5000, 3)) * [1, 1, 0.1], origin)
    cmp = PointCloud(ref.positions[:2000] + rng.normal(0, 0.01, (2000, 3)), origin)
    summary = evaluate_geometry(cmp, ref, tmp_path, "mvs", GeometryOptions(tau=0.02))
    expected = brute_force(cmp.positions, ref.positions)
    assert summary.stats.mean == pytest.approx(expected.mean(), abs=1e-12)
    for suffix in ("ply", "las"):
        back = read_point_cloud(tmp_path / f"c2c_mvs.{suffix}")
        assert "c2c" in back.fields
        # PLY keeps the float64 field; LAS extra bytes too; positions are mm (LAS) or float32-local (PLY)
        np.testing.assert_allclose(back.fields["c2c"], expected, atol=1e-9)
        np.testing.assert_allclose(back.world_positions, cmp.world_positions, atol=1e-3)
    assert (tmp_path / "plots" / "c2c_mvs_hist.svg").read_text().startswith("<svg")
    assert (tmp_path / "plots" / "c2c_mvs_preview.png").stat().st_size > 100
    d = summary.as_dict()
    for key in ("count", "mean", "std", "median", "rmse", "p95", "max", "completeness", "fscore"):
        assert d[key] is not None
    assert sum(d["histogram"]["counts"]) == 2000


def test_agrees_with_open3d_on_a_larger_cloud():
    """A second, independent nearest-neighbour implementation (open3d's KDTreeFlann) on 100 k points."""
    import open3d as o3d

    rng = np.random.default_rng(10)
    a = rng.uniform(0, 10, size=(100_000, 3)) * [1, 1, 0.05]
    b = rng.uniform(0, 10, size=(120_000, 3)) * [1, 1, 0.05]
    pa = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(a))
    pb = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(b))
    expected = np.asarray(pa.compute_point_cloud_distance(pb))
    np.testing.assert_allclose(nearest_distances(a, b, chunk_size=30_000), expected, rtol=0, atol=1e-12)


def test_degenerate_clouds():
    one = PointCloud(np.array([[1.0, 2.0, 3.0]]))
    r = compare_clouds(PointCloud(np.array([[1.0, 2.0, 7.0], [1.0, 2.0, 3.0]])), one, tau=0.5)
    np.testing.assert_allclose(r.distances, [4.0, 0.0])
    assert r.scores.recall == 1.0 and r.scores.precision == 0.5
    dup = PointCloud(np.zeros((50, 3)))  # duplicate points: zero distances, finite statistics
    s = compare_clouds(dup, dup).stats
    assert s.mean == 0.0 and s.std == 0.0 and s.max == 0.0


def test_preview_orientation():
    from eval.plots import preview_image

    # a horizontal patch: map view with north (+y) up; the far north-east corner is hot
    xy = np.stack(np.meshgrid(np.linspace(0, 10, 60), np.linspace(0, 5, 30)), -1).reshape(-1, 2)
    values = ((xy[:, 0] > 9) & (xy[:, 1] > 4.5)).astype(float)
    img = preview_image(np.c_[xy, np.zeros(len(xy))], values, width=100, vmax=1.0)
    assert img.shape == (50, 100, 3)
    hot = np.argwhere((img == [253, 231, 37]).all(-1))  # viridis top colour
    assert hot[:, 0].max() < 10 and hot[:, 1].min() > 85  # top-right corner
