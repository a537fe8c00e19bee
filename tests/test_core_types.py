"""PointCloud and GaussianSet: origins, chunking, activations, validation."""

import numpy as np
import pytest

from core import SH_C0, DataError, GaussianSet, PointCloud
from core.gaussians import logit, sigmoid


def _cloud(n=100, origin=(500_000.0, 5_000_000.0, 300.0), seed=0):
    rng = np.random.default_rng(seed)
    world = rng.uniform(0, 50, (n, 3)) + np.array(origin)
    return world, PointCloud.from_world(
        world,
        colors=rng.integers(0, 256, (n, 3)),
        normals=rng.normal(size=(n, 3)),
        fields={"classification": rng.integers(0, 5, n).astype(np.uint8)},
        visibility=[rng.integers(0, 10, 3) for _ in range(n)],
    )


def test_from_world_uses_local_origin_and_keeps_float64():
    world, pc = _cloud()
    assert np.abs(pc.positions).max() < 100
    assert pc.positions.dtype == np.float64
    np.testing.assert_array_equal(pc.world_positions, pc.positions + pc.origin)
    np.testing.assert_allclose(pc.world_positions, world, atol=1e-9, rtol=0)
    moved = pc.with_origin(np.zeros(3))
    np.testing.assert_allclose(moved.positions, world, atol=1e-9, rtol=0)


def test_small_clouds_keep_their_frame():
    pc = PointCloud.from_world(np.random.default_rng(0).normal(size=(10, 3)))
    np.testing.assert_array_equal(pc.origin, 0)


def test_chunks_cover_every_point_once_with_all_attributes():
    _, pc = _cloud(1003)
    chunks = list(pc.chunks(100))
    assert len(chunks) == 11
    joined = PointCloud.concatenate(chunks)
    np.testing.assert_array_equal(joined.positions, pc.positions)
    np.testing.assert_array_equal(joined.colors, pc.colors)
    np.testing.assert_array_equal(joined.fields["classification"], pc.fields["classification"])
    assert all((a == b).all() for a, b in zip(joined.visibility, pc.visibility, strict=True))


def test_validation_names_nan_points():
    pc = PointCloud(np.array([[0.0, 0, 0], [np.nan, 1, 1]]))
    with pytest.raises(DataError, match="1 points have NaN"):
        pc.validate()
    with pytest.raises(DataError, match="field 'c2c' has 1 entries but the cloud has 2"):
        PointCloud(np.zeros((2, 3)), fields={"c2c": np.zeros(1)})


def test_float_colours_are_unit_range():
    pc = PointCloud(np.zeros((2, 3)), colors=np.array([[0.0, 0.5, 1.0], [1.0, 1.0, 1.0]]))
    np.testing.assert_array_equal(pc.colors, [[0, 128, 255], [255, 255, 255]])


def _gaussians(n=20, degree=2, seed=0):
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1
    return GaussianSet(
        rng.normal(size=(n, 3)),
        rng.normal(size=(n, 3)) - 3,
        rng.normal(size=(n, 4)),
        rng.normal(size=n),
        rng.normal(size=(n, 3)),
        rng.normal(size=(n, k, 3)),
        origin=[1000.0, 2000.0, 3.0],
    )


def test_gaussian_activations():
    gs = _gaussians()
    np.testing.assert_allclose(gs.scales, np.exp(gs.log_scales), rtol=1e-6)
    np.testing.assert_allclose(gs.opacities, 1 / (1 + np.exp(-gs.logit_opacities.astype(np.float64))), rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(gs.unit_quats, axis=1), 1, rtol=1e-6)
    np.testing.assert_allclose(gs.base_colors, np.clip(0.5 + SH_C0 * gs.sh_dc, 0, 1), rtol=1e-6)
    assert gs.sh_degree == 2 and gs.sh_coeffs.shape == (20, 9, 3)
    assert np.isfinite(sigmoid(np.array([-1000.0, 1000.0]))).all()
    assert np.isfinite(logit(np.array([0.0, 1.0]))).all()


def test_gaussian_sh_degree_change_and_concatenate():
    a, b = _gaussians(5, 1), _gaussians(7, 3, seed=1)
    assert a.with_sh_degree(3).sh_rest.shape == (5, 15, 3)
    np.testing.assert_array_equal(a.with_sh_degree(3).sh_rest[:, :3], a.sh_rest)
    assert b.with_sh_degree(0).sh_degree == 0
    b.origin = np.array([0.0, 0.0, 0.0])
    both = GaussianSet.concatenate([a, b])
    assert len(both) == 12 and both.sh_degree == 3
    np.testing.assert_allclose(both.world_means[5:], b.world_means, atol=1e-9)


def test_gaussian_validation():
    gs = _gaussians()
    gs.validate()
    gs.quats[3] = 0
    with pytest.raises(DataError, match="zero quaternion"):
        gs.validate()
    gs = _gaussians()
    gs.log_scales[2, 1] = np.inf
    with pytest.raises(DataError, match="log_scales"):
        gs.validate()
    with pytest.raises(DataError, match="degree"):
        GaussianSet(np.zeros((1, 3)), np.zeros((1, 3)), [[1, 0, 0, 0]], [0], np.zeros((1, 3)), np.zeros((1, 5, 3)))
