"""core.knn: the column-grid k-NN is exact (brute force on small clouds, cKDTree on larger ones)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from core.errors import DataError
from core.knn import grid as knn_grid_module
from core.knn import knn_grid, knn_grid_summary, knn_kdtree
from core.knn import search as knn_search
from core.pointcloud import PointCloud
from fusion.convert import ConvertOptions, _robust_spacing, knn_distances, points_to_gaussians

_rng = np.random.default_rng(0)
CASES = {
    "plane": np.c_[_rng.random((600, 2)), np.zeros(600)],
    "cube": _rng.random((600, 3)),
    "vertical_line": np.c_[np.zeros(200), np.zeros(200), _rng.random(200)],
    "diagonal_line": np.outer(_rng.random(200), [1.0, 2.0, -0.5]),
    "outliers": np.r_[np.c_[_rng.random((500, 2)), 0.01 * _rng.random(500)], _rng.random((15, 3)) * 100],
    "duplicates": np.repeat(_rng.random((80, 3)), 3, axis=0),
    "wall": np.c_[_rng.random(500) * 10, 0.001 * _rng.random(500), _rng.random(500) * 3],
    "two_clusters": np.r_[_rng.random((200, 3)) * 0.01, _rng.random((200, 3)) * 0.01 + 1000],
    "tiny": _rng.random((60, 3)) * 1e-9,
    "utm_offset_local": _rng.random((300, 3)) * 50 - 25,
    "utm_world_not_shifted": _rng.random((400, 3)) * [0.5, 0.5, 0.001] + [512345.0, 5412345.0, 300.0],
    "grid_ties": np.stack(np.meshgrid(np.arange(8.0), np.arange(8.0), np.arange(3.0)), -1).reshape(-1, 3),
}


def _brute(p: np.ndarray, k: int) -> np.ndarray:
    d = np.sqrt(((p[:, None] - p[None]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    return np.sort(d, axis=1)[:, :k]


@pytest.mark.parametrize("k", [1, 3, 8])
@pytest.mark.parametrize("name", sorted(CASES))
def test_grid_knn_equals_brute_force(name, k):
    p = CASES[name]
    dist, idx = knn_grid(p, k)
    np.testing.assert_allclose(dist, _brute(p, k), rtol=1e-12, atol=1e-15)
    # the indices point at neighbours at exactly those distances, never at the point itself
    np.testing.assert_allclose(np.linalg.norm(p[idx] - p[:, None], axis=2), dist, rtol=1e-12, atol=1e-15)
    assert not (idx == np.arange(len(p))[:, None]).any()


def test_grid_knn_equals_kdtree_on_a_larger_surface():
    rng = np.random.default_rng(1)
    n = 60_000
    uv = rng.random((n, 2)) * 30
    p = np.c_[uv, np.sin(uv[:, 0]) + 0.01 * rng.normal(size=n)]
    p[:100] = rng.random((100, 3)) * [30, 30, 10]
    for k in (1, 8):
        d_grid, _ = knn_grid(p, k)
        d_tree, _ = knn_kdtree(p, k)
        np.testing.assert_array_equal(d_grid, d_tree)
        d_conv, _ = knn_distances(p, k, backend="kdtree", chunk_size=7_000)
        np.testing.assert_array_equal(d_conv, d_tree)


def test_kdtree_reference_never_returns_the_point_itself():
    p = np.repeat(np.random.default_rng(2).random((50, 3)), 4, axis=0)  # every point has 3 duplicates
    for k in (2, 5):
        d, i = knn_kdtree(p, k)
        assert not (i == np.arange(len(p))[:, None]).any()
        np.testing.assert_allclose(np.linalg.norm(p[i] - p[:, None], axis=2), d, atol=1e-15)
        _, i2 = knn_distances(p, k, backend="kdtree", chunk_size=33, return_index=True)
        assert not (i2 == np.arange(len(p))[:, None]).any()


def test_knn_rejects_bad_input():
    with pytest.raises(DataError):
        knn_grid(np.zeros((2, 3)), 2)
    with pytest.raises(DataError):
        knn_grid(np.array([[0.0, 0, 0], [np.nan, 0, 0]]), 1)


@pytest.mark.parametrize("name", ["duplicates", "outliers", "plane", "grid_ties"])
def test_summary_equals_full_search_statistics(name):
    p = CASES[name]
    for k in (1, 4, 8):
        dist, _ = knn_grid(p, k)
        nearest, robust = knn_grid_summary(p, k)
        np.testing.assert_array_equal(nearest, dist[:, 0])
        np.testing.assert_allclose(robust, _robust_spacing(dist), rtol=1e-15, atol=0)
    # all-duplicate neighbourhoods give 0 (the converter clamps and warns)
    _, robust = knn_grid_summary(np.zeros((5, 3)), 3)
    np.testing.assert_array_equal(robust, 0.0)


def test_conversion_is_backend_independent():
    rng = np.random.default_rng(3)
    p = np.c_[rng.random((3000, 2)), 0.02 * rng.random(3000)]
    p[5] = p[6]
    normals = np.tile([0.0, 0.0, 1.0], (3000, 1))
    for cloud in (PointCloud(p, normals=normals), PointCloud(p)):  # summary path and full path + PCA
        for mode in ("paper", "adaptive"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                a = points_to_gaussians(cloud, mode, ConvertOptions(neighbor_backend="grid"))
                b = points_to_gaussians(cloud, mode, ConvertOptions(neighbor_backend="kdtree"))
            np.testing.assert_array_equal(a.log_scales, b.log_scales)
            np.testing.assert_array_equal(a.logit_opacities, b.logit_opacities)
            np.testing.assert_allclose(np.abs(a.quats), np.abs(b.quats), atol=1e-6)


def test_far_outliers_and_separate_clusters_stay_exact_and_fast():
    """Far outliers are clamped into border columns and resolved by the block search; far-apart dense clusters make
    the grid hand the whole cloud to the k-d tree. Both exact (compared with cKDTree), both quick."""
    rng = np.random.default_rng(5)
    n = 20_000
    plane = np.c_[rng.random((n, 2)) * 10, 0.01 * rng.random(n)]
    far = np.r_[plane, rng.random((5, 3)) * 1e4 - 5e3]  # 5 points up to 5 km away
    clusters = np.r_[plane, plane[:5000] + [1e5, 0, 0]]
    grid = knn_grid_module.build_grid(far, 8, 4.0)
    assert grid is not None and grid.nx * grid.ny < 4 * len(far)
    _, _, _, n_far = knn_search._query(grid, 8, False)
    assert 1 <= n_far < 50  # the outliers (and maybe a few neighbours) take the block search
    assert knn_grid_module.build_grid(clusters, 8, 4.0) is None
    for p in (far, clusters):
        for k in (1, 8):
            d_grid, i_grid = knn_grid(p, k)
            d_tree, _ = knn_kdtree(p, k)
            np.testing.assert_array_equal(d_grid, d_tree)
            np.testing.assert_allclose(np.linalg.norm(p[i_grid] - p[:, None], axis=2), d_tree, rtol=1e-12)
            nearest, robust = knn_grid_summary(p, k)
            np.testing.assert_array_equal(nearest, d_tree[:, 0])
            np.testing.assert_allclose(robust, _robust_spacing(d_tree), rtol=1e-15)


@pytest.mark.parametrize("k", [1, 3, 8])
def test_block_search_alone_equals_brute_force(monkeypatch, k):
    """With no ring budget every point not settled by its first ring of columns takes the block search (the outliers'
    path): still exact on every case, including ties, duplicates, border clamping and huge coordinates."""
    monkeypatch.setattr(knn_search, "_RING_BUDGET", 0)
    total_far = 0
    for name, p in sorted(CASES.items()):
        grid = knn_grid_module.build_grid(np.ascontiguousarray(p, dtype=np.float64), k, 4.0)
        if grid is not None:
            total_far += knn_search._query(grid, k, False)[3]
        dist, idx = knn_grid(p, k)
        np.testing.assert_allclose(dist, _brute(p, k), rtol=1e-12, atol=1e-15, err_msg=name)
        np.testing.assert_allclose(np.linalg.norm(p[idx] - p[:, None], axis=2), dist, rtol=1e-12, atol=1e-15)
        assert not (idx == np.arange(len(p))[:, None]).any()
        nearest, robust = knn_grid_summary(p, k)
        np.testing.assert_array_equal(nearest, dist[:, 0])
        np.testing.assert_allclose(robust, _robust_spacing(dist), rtol=1e-15, atol=0)
    assert total_far > 100  # the block search really ran


def test_many_outliers_above_a_terrain_equal_kdtree():
    """3 % outliers up to 4 m above and below a wavy terrain (the bench's cloud, denser in outliers): block search."""
    rng = np.random.default_rng(7)
    n = 40_000
    uv = rng.random((n, 2)) * 8
    p = np.c_[uv, 2 * np.sin(uv[:, 0] / 2) + 0.002 * rng.normal(size=n)]
    m = n * 3 // 100
    p[:m] = rng.random((m, 3)) * [8, 8, 8] - [0, 0, 4]
    grid = knn_grid_module.build_grid(p, 8, 4.0)
    assert grid is not None and grid.nx * grid.ny < 4 * n  # columns over (x, y): same sums as the k-d tree
    assert knn_search._query(grid, 8, False)[3] > m // 2
    for k in (1, 8):
        d_grid, i_grid = knn_grid(p, k)
        d_tree, _ = knn_kdtree(p, k)
        np.testing.assert_array_equal(d_grid, d_tree)
        np.testing.assert_allclose(np.linalg.norm(p[i_grid] - p[:, None], axis=2), d_tree, rtol=1e-12)
        nearest, robust = knn_grid_summary(p, k)
        np.testing.assert_array_equal(nearest, d_tree[:, 0])
        np.testing.assert_allclose(robust, _robust_spacing(d_tree), rtol=1e-15)


def test_gathered_and_per_point_scans_agree_on_steep_and_mixed_surfaces():
    """Terrain (most columns take the gathered 3×3 pass), a vertical wall and a dense clump (columns over the
    gather cap take the z-windowed per-point scan), and points on column edges: identical to the k-d tree."""
    rng = np.random.default_rng(5)
    terrain = np.c_[rng.random((20_000, 2)) * 10, 0.01 * rng.normal(size=20_000)]
    wall = np.c_[np.full(5_000, 5.0) + 1e-4 * rng.normal(size=5_000), rng.random(5_000) * 10, rng.random(5_000) * 4]
    clump = np.array([2.0, 2.0, 0.5]) + 1e-3 * rng.normal(size=(2_000, 3))
    edges = np.c_[np.round(rng.random((1_000, 2)) * 100) / 10, np.zeros(1_000)]  # on multiples of 0.1
    p = np.vstack([terrain, wall, clump, edges])
    for k in (1, 8):
        d_grid, idx = knn_grid(p, k)
        np.testing.assert_array_equal(d_grid, knn_kdtree(p, k)[0])
        np.testing.assert_allclose(np.linalg.norm(p[idx] - p[:, None], axis=2), d_grid, rtol=1e-12, atol=1e-15)
        assert not (idx == np.arange(len(p))[:, None]).any()
