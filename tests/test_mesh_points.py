"""fusion.mesh.oriented_points: normals from the shortest axis, orientation, opacity weighting, dense sampling."""

import numpy as np
import pytest
from mesh_shapes import fibonacci_sphere, sphere_gaussians, surfels

from core.errors import ConfigError, DataError
from core.gaussians import logit
from fusion.convert import Source
from fusion.mesh.oriented_points import (
    NormalFallback,
    OrientedPointOptions,
    oriented_points_from_gaussians,
    rotation_matrices,
)


def random_quats(n: int, seed: int = 0) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_rotation_matrices_are_orthonormal_and_match_scipy():
    from scipy.spatial.transform import Rotation

    q = random_quats(50)
    r = rotation_matrices(q)
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy: (x, y, z, w)
    assert np.allclose(r, ref, atol=1e-12)
    assert np.allclose(np.einsum("nij,nkj->nik", r, r), np.eye(3), atol=1e-12)


def test_mvs_normals_are_the_shortest_axis_with_the_mvs_sign():
    g = sphere_gaussians(500, radius=0.5)
    pts, stats = oriented_points_from_gaussians(g)
    radial = pts.positions / np.linalg.norm(pts.positions, axis=1, keepdims=True)
    dots = np.einsum("ij,ij->i", pts.normals, radial)
    assert stats.trusted_normals == 500
    assert dots.min() > 0.999  # exactly the MVS normal (outward), sign kept
    assert np.allclose(pts.colors, [0.8, 0.4, 0.2], atol=1e-6)
    assert (pts.source == Source.MVS).all()


def test_shortest_axis_found_whatever_axis_it_is():
    """A splat flattened along its x or y axis: the normal is that axis (up to sign), not z."""
    rng = np.random.default_rng(1)
    n = 200
    q = random_quats(n, 2)
    axis = rng.integers(0, 3, n)
    log_s = np.full((n, 3), np.log(0.01))
    log_s[np.arange(n), axis] = np.log(0.001)
    from core.gaussians import GaussianSet

    g = GaussianSet(
        rng.normal(size=(n, 3)),
        log_s,
        q,
        np.full(n, 3.0),
        np.zeros((n, 3)),
        fields={"source": np.full(n, Source.SPLAT, np.uint8)},
    )
    pts, _ = oriented_points_from_gaussians(
        g, OrientedPointOptions(max_samples_per_gaussian=1), viewpoints=np.array([[100.0, 0, 0]])
    )
    expected = rotation_matrices(q)[np.arange(n), :, axis]
    assert np.allclose(np.abs(np.einsum("ij,ij->i", pts.normals, expected)), 1.0, atol=1e-9)


@pytest.mark.parametrize("how", ["viewpoints", "trusted_neighbours", "propagation"])
def test_splat_normals_with_random_signs_are_oriented_outwards(how):
    radius = 0.5
    pts_s = fibonacci_sphere(800, radius)
    normals = pts_s / radius * np.where(np.random.default_rng(3).random(800) < 0.5, -1.0, 1.0)[:, None]
    g = surfels(pts_s, normals, sigma=0.02, source=Source.SPLAT)
    viewpoints = None
    if how == "viewpoints":
        viewpoints = fibonacci_sphere(20, 3.0)  # cameras all around, outside
    elif how == "trusted_neighbours":
        mvs = sphere_gaussians(300, radius)
        from core.gaussians import GaussianSet

        g = GaussianSet.concatenate([g, mvs])
    out, _ = oriented_points_from_gaussians(g, OrientedPointOptions(max_samples_per_gaussian=1), viewpoints)
    radial = out.positions / np.linalg.norm(out.positions, axis=1, keepdims=True)
    dots = np.einsum("ij,ij->i", out.normals, radial)
    assert (dots > 0.99).mean() == 1.0, f"{(dots < 0).sum()} normals point inwards"


def test_isotropic_gaussians_fallbacks():
    radius = 0.5
    p = fibonacci_sphere(600, radius)
    g = surfels(p, p / radius, sigma=0.02, thickness=1.0)  # spheres: no shortest axis
    est, stats = oriented_points_from_gaussians(g, OrientedPointOptions(max_samples_per_gaussian=1))
    assert stats.estimated_normals == 600 and stats.trusted_normals == 0
    radial = est.positions / radius
    assert np.einsum("ij,ij->i", est.normals, radial).min() > 0.95  # PCA normal of a sphere patch, oriented out
    with pytest.raises(DataError, match="near-isotropic"):
        oriented_points_from_gaussians(g, OrientedPointOptions(normal_fallback=NormalFallback.ERROR))
    with pytest.raises(DataError, match="all 600 Gaussians are near-isotropic"):
        oriented_points_from_gaussians(g, OrientedPointOptions(normal_fallback="drop"))


def test_opacity_weighting_thins_faint_gaussians_and_cuts_below_min():
    p = fibonacci_sphere(4000, 0.5)
    n = len(p)
    g = surfels(p, p / 0.5, sigma=0.01, alpha=0.25)  # weight = 0.25 / 0.5 = 0.5 per Gaussian
    out, stats = oriented_points_from_gaussians(g)
    # Binomial(4000, 0.5): mean 2000, σ ≈ 31.6; ±6σ cannot fail by chance
    assert abs(len(out) - n / 2) < 6 * np.sqrt(n * 0.25)
    assert stats.dropped_faint == 0
    faint = surfels(p, p / 0.5, sigma=0.01, alpha=0.01)
    with pytest.raises(DataError, match="fainter than min_opacity"):
        oriented_points_from_gaussians(faint)
    # same seed, same points
    again, _ = oriented_points_from_gaussians(g)
    assert np.array_equal(again.positions, out.positions)


def test_large_splats_get_more_points_inside_their_ellipse():
    small = surfels(np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]]), np.tile([0, 0, 1.0], (3, 1)), sigma=0.01)
    big = surfels(np.array([[5.0, 0, 0]]), np.array([[0, 0, 1.0]]), sigma=0.04)  # 16× the footprint
    from core.gaussians import GaussianSet

    g = GaussianSet.concatenate([small, big])
    out, stats = oriented_points_from_gaussians(g, OrientedPointOptions(footprint_sigmas=1.5))
    assert stats.sample_spacing == pytest.approx(0.01)
    counts = np.bincount(out.gaussian_index, minlength=4)
    assert list(counts[:3]) == [1, 1, 1] and counts[3] == 16
    mine = out.positions[out.gaussian_index == 3] - [5.0, 0, 0]
    assert np.allclose(mine[:, 2], 0.0, atol=1e-12)  # in the splat's plane
    assert np.linalg.norm(mine[:, :2], axis=1).max() <= 1.5 * 0.04 + 1e-12
    assert np.allclose(out.positions[out.gaussian_index == 3][0], [5.0, 0, 0])  # first point is the mean
    # each point's footprint: its Gaussian's sampled ellipse, 1.5 σ (the long in-surface σ)
    assert np.allclose(out.footprint, np.where(out.gaussian_index == 3, 1.5 * 0.04, 1.5 * 0.01))


def test_bad_input():
    g = sphere_gaussians(100)
    with pytest.raises(DataError, match="empty"):
        oriented_points_from_gaussians(g.subset(np.zeros(100, bool)))
    bad = g.subset(slice(None))
    bad.means[3] = np.nan
    with pytest.raises(DataError, match="NaN"):
        oriented_points_from_gaussians(bad)
    with pytest.raises(ConfigError):
        OrientedPointOptions(min_opacity=1.5)
    with pytest.raises(ConfigError):
        OrientedPointOptions(normal_fallback="guess")
    assert logit(np.array([0.5]))[0] == 0.0
