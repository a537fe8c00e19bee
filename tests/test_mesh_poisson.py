"""fusion.mesh.poisson and quality: surface accuracy on a sphere, watertightness, trimming, pieces, bad input."""

import numpy as np
import pytest
from mesh_shapes import distance_to_mesh, fibonacci_sphere, mesh_surface_samples, sphere_distance, sphere_gaussians

from core.errors import ConfigError, DataError
from fusion.mesh.graph import triangle_components
from fusion.mesh.oriented_points import oriented_points_from_gaussians
from fusion.mesh.poisson import PoissonOptions, poisson_reconstruct, trim_mesh
from fusion.mesh.quality import mesh_quality
from fusion.mesh.types import OrientedPoints, TriangleMesh

R = 0.5


@pytest.fixture(scope="module")
def sphere_points():
    pts, _ = oriented_points_from_gaussians(sphere_gaussians(3000, R))
    return pts


def open3d_checks(mesh: TriangleMesh) -> tuple[bool, bool, int]:
    """Independent reference: open3d's watertight / edge-manifold verdicts and its boundary-edge count."""
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.triangles.astype(np.int32))
    )
    boundary = len(np.asarray(m.get_non_manifold_edges(allow_boundary_edges=False))) - len(
        np.asarray(m.get_non_manifold_edges(allow_boundary_edges=True))
    )
    return m.is_watertight(), m.is_edge_manifold(allow_boundary_edges=True), boundary


def test_untrimmed_sphere_is_watertight_and_close_to_the_truth(sphere_points):
    result = poisson_reconstruct(sphere_points)
    q = mesh_quality(result.mesh)
    assert q.watertight and q.degenerate_triangles == 0 and q.pieces == 1
    assert open3d_checks(result.mesh) == (True, True, 0)
    samples = mesh_surface_samples(result.mesh.vertices, result.mesh.triangles, 20_000)
    d = sphere_distance(samples, R)
    spacing = R * np.sqrt(4 * np.pi / 3000)  # 0.032 m between input points
    # a depth-5 Poisson surface of noise-free samples: mean error far below the point spacing
    assert d.mean() < 0.05 * spacing and d.max() < 0.25 * spacing
    # completeness: every truth point within a quarter spacing of the mesh
    truth = fibonacci_sphere(20_000, R)
    assert distance_to_mesh(truth, result.mesh.vertices, result.mesh.triangles).max() < 0.25 * spacing
    # sphere area 4πR² within 1 %
    assert q.area_m2 == pytest.approx(4 * np.pi * R**2, rel=0.01)


def test_trimming_keeps_a_well_sampled_closed_surface_and_cuts_a_hemisphere_cap(sphere_points):
    full = poisson_reconstruct(sphere_points)
    trimmed, stats = trim_mesh(full)
    assert stats.removed_unsupported == 0 and mesh_quality(trimmed).watertight  # nothing unsupported on a sphere

    upper = sphere_points.subset(sphere_points.positions[:, 2] > 0)
    half = poisson_reconstruct(upper)
    cut, stats = trim_mesh(half)
    q = mesh_quality(cut)
    assert stats.removed_unsupported > 0
    assert q.edge_manifold and q.boundary_edges > 0 and q.pieces == 1
    wt, manifold, boundary = open3d_checks(cut)
    assert (wt, manifold, boundary) == (False, True, q.boundary_edges)
    # what is left lies on the upper hemisphere: nothing below 2 point spacings under the equator
    spacing = half.point_spacing
    assert cut.vertices[:, 2].min() > -2.5 * spacing
    assert sphere_distance(cut.vertices, R).max() < 2 * spacing


def test_density_quantile_trim_removes_that_share_of_vertices(sphere_points):
    full = poisson_reconstruct(sphere_points)
    _, stats = trim_mesh(full, PoissonOptions(density_quantile=0.2, support_factor=None))
    below = full.densities < np.quantile(full.densities, 0.2)
    expected = int(below[full.mesh.triangles].any(axis=1).sum())
    assert stats.removed_low_density == expected > 0


def test_small_pieces_are_removed():
    big = sphere_gaussians(3000, R)
    small = sphere_gaussians(60, 0.05)
    small.means += [2.0, 0, 0]
    from core.gaussians import GaussianSet

    pts, _ = oriented_points_from_gaussians(GaussianSet.concatenate([big, small]))
    res = poisson_reconstruct(pts, PoissonOptions(depth=7))
    assert mesh_quality(res.mesh).pieces == 2
    out, stats = trim_mesh(res, PoissonOptions(min_component_fraction=0.05))
    assert stats.pieces_dropped == 1 and mesh_quality(out).pieces == 1
    assert np.linalg.norm(out.vertices, axis=1).max() < 0.6


def test_triangle_components_brute_force():
    tris = np.array([[0, 1, 2], [2, 3, 4], [5, 6, 7], [7, 8, 5], [9, 10, 11]])
    labels = triangle_components(tris, 12)
    assert labels[0] == labels[1] and labels[2] == labels[3]
    assert len({labels[0], labels[2], labels[4]}) == 3


def test_bad_input():
    n = np.tile([0, 0, 1.0], (3, 1))
    with pytest.raises(DataError, match="at least 4"):
        poisson_reconstruct(OrientedPoints(np.zeros((3, 3)), n, np.zeros((3, 3)), np.zeros(3), np.zeros(3)))
    same = OrientedPoints(
        np.ones((10, 3)), np.tile([0, 0, 1.0], (10, 1)), np.zeros((10, 3)), np.zeros(10), np.zeros(10)
    )
    with pytest.raises(DataError, match="coincide"):
        poisson_reconstruct(same)
    no_normals = OrientedPoints(
        np.random.default_rng(0).random((10, 3)), np.zeros((10, 3)), np.zeros((10, 3)), np.zeros(10), np.zeros(10)
    )
    with pytest.raises(DataError, match="no normal"):
        poisson_reconstruct(no_normals)
    with pytest.raises(ConfigError):
        PoissonOptions(depth=1)
    with pytest.raises(ConfigError):
        PoissonOptions(density_quantile=1.0)


def test_non_manifold_edge_repair():
    """Three triangles on the edge (0, 1): one goes (the smallest), the other two stay; brute-force edge count."""
    from fusion.mesh.poisson import repair_non_manifold_edges

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -2, 0], [0, 0, 0.5]], float)
    t = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    assert mesh_quality(TriangleMesh(v, t)).non_manifold_edges == 1
    out, removed = repair_non_manifold_edges(TriangleMesh(v, t))
    assert removed == 1 and mesh_quality(out).non_manifold_edges == 0
    kept = {tuple(sorted(map(tuple, out.vertices[tri]))) for tri in out.triangles}
    assert tuple(sorted(map(tuple, v[[0, 1, 4]]))) not in kept  # the smallest (area 0.25) is the one removed


def test_collinear_points_are_refused_and_do_not_crash_orientation():
    from mesh_shapes import surfels

    from fusion.mesh.pipeline import MeshOptions, mesh_from_gaussians

    line = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)]
    for thickness in (0.1, 1.0):  # flat surfels, and spheres (PCA normals + qhull-based orientation)
        g = surfels(line, np.tile([0, 0, 1.0], (50, 1)), 0.01, thickness=thickness)
        with pytest.raises(DataError, match="one line"):
            mesh_from_gaussians(g, MeshOptions(budget=100))


def test_sparse_parts_keep_their_surface_by_local_spacing_and_footprints_are_exact():
    # dense samples below the cap z > 0.25 of a sphere, 1 in 12 there (a hybrid cloud: dense splat samples next to
    # sparse MVS surfels); each sparse sample's footprint covers the gaps to its neighbours (1.2 × their spacing).
    # One global spacing (the dense part's) cut the cap open (under 70 % covered); the local spacing keeps most of it
    # (88 %: near the dense part the median takes in dense neighbours), the footprints all of it.
    pts = fibonacci_sphere(6000, R)
    cap = pts[:, 2] > 0.25
    keep = ~cap | (np.arange(len(pts)) % 12 == 0)
    pos = pts[keep]
    sparse_spacing = R * np.sqrt(4 * np.pi / 6000 * 12)
    footprint = np.where(pos[:, 2] > 0.25, 1.2 * sparse_spacing, 0.0)
    points = OrientedPoints(pos, pos / R, np.full((len(pos), 3), 0.5), np.ones(len(pos)), np.arange(len(pos)),
                            footprint=footprint)  # fmt: skip
    truth = fibonacci_sphere(20_000, R)
    truth = truth[truth[:, 2] > 0.3]
    cap_cover = {}
    for fp in (False, True):
        options = PoissonOptions(depth=6, footprint_support=fp)
        result = poisson_reconstruct(points, options)
        trimmed, _ = trim_mesh(result, options)
        d = distance_to_mesh(truth, trimmed.vertices, trimmed.triangles)
        cap_cover[fp] = float((d < 0.25 * sparse_spacing).mean())
        # brute force on 1500 vertices: marked as in a footprint exactly when within some point's footprint
        some = np.random.default_rng(0).choice(len(result.mesh.vertices), 1500, replace=False)
        dist = np.linalg.norm(result.mesh.vertices[some, None, :] - pos[None, :, :], axis=2)
        expected = (dist <= footprint[None, :]).any(axis=1) if fp else np.zeros(len(dist), dtype=bool)
        assert np.array_equal(result.footprint_supported[some], expected) and (not fp or expected.any())
    assert cap_cover[False] > 0.8 and cap_cover[True] > 0.98, cap_cover
