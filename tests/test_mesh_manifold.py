"""fusion.mesh.manifold: pillows and flat tetrahedra removed, touching sheets split, closed meshes stay closed.

Truth: hand-built cubes (exact volumes, which triangle belongs to which cube) and trimesh's watertight check.
"""

import numpy as np
import pytest

from fusion.mesh.manifold import make_edge_manifold
from fusion.mesh.quality import mesh_quality
from fusion.mesh.types import TriangleMesh

# a unit cube's 12 triangles, anticlockwise seen from outside, vertices indexed by bits (x, y, z)
CUBE = np.array(
    [[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
     [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]]
)  # fmt: skip
CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)


def volume(mesh: TriangleMesh) -> float:
    v = mesh.vertices[mesh.triangles]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def trimesh_watertight(mesh: TriangleMesh) -> bool:
    import trimesh

    return trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False).is_watertight


def test_cube_is_closed_and_left_alone():
    cube = TriangleMesh(CORNERS, CUBE)
    assert mesh_quality(cube).watertight and volume(cube) == pytest.approx(1.0)
    out, sources, stats = make_edge_manifold(cube)
    assert out is cube and (sources[:, 0] == np.arange(8)).all() and stats.edges_split == 0


def test_a_pillow_is_removed_and_the_cube_stays_closed():
    pillow = np.array([[0, 2, 3], [0, 3, 2]])  # the first face again, both ways round: zero volume
    mesh = TriangleMesh(CORNERS, np.concatenate([CUBE, pillow]))
    assert mesh_quality(mesh).non_manifold_edges == 3
    out, _, stats = make_edge_manifold(mesh)
    q = mesh_quality(out)
    assert stats.pillow_triangles == 2 and q.watertight and trimesh_watertight(out)
    assert out.num_triangles == 12 and volume(out) == pytest.approx(1.0)


def test_a_flat_tetrahedron_on_an_edge_is_removed():
    # c, d in the plane z = 0 beyond the cube (y < 0): triangles (0, 1, c), (1, 0, d), (0, c, d), (1, d, c) close
    # into a tetrahedron of zero volume hanging on the cube's edge 0-1
    verts = np.concatenate([CORNERS, [[0.3, -1.0, 0.0], [0.6, -0.5, 0.0]]])
    c, d = 8, 9
    flat = np.array([[0, 1, c], [1, 0, d], [0, c, d], [1, d, c]])
    mesh = TriangleMesh(verts, np.concatenate([CUBE, flat]))
    assert mesh_quality(mesh).non_manifold_edges == 1
    out, _, stats = make_edge_manifold(mesh)
    assert stats.flat_tetrahedron_triangles == 4 and stats.pillow_triangles == 0
    assert mesh_quality(out).watertight and out.num_triangles == 12 and volume(out) == pytest.approx(1.0)


@pytest.mark.parametrize("flip", [False, True])
def test_two_cubes_touching_along_an_edge_are_split_by_their_wedges(flip):
    # cube A = [0, 1]³, cube B = [1, 2] × [1, 2] × [0, 1]: they share the edge x = y = 1 (vertices 3 and 7 of A);
    # the edge has four triangles, two of each cube. Inside-out cubes (flip) enclose the complement
    b_corners = CORNERS + [1.0, 1.0, 0.0]
    shared = {0: 3, 4: 7}  # B's corners (0,0,z) are A's corners (1,1,z)
    b_index = np.array([shared.get(i, 8 + i) for i in range(8)])
    verts = np.concatenate([CORNERS, b_corners])
    tris = np.concatenate([CUBE, b_index[CUBE]])
    if flip:
        tris = tris[:, ::-1]
    mesh = TriangleMesh(verts, tris)
    assert mesh_quality(mesh).non_manifold_edges == 1
    out, sources, stats = make_edge_manifold(mesh)
    q = mesh_quality(out)
    assert stats.edges_split == 1 and stats.vertices_added == 1 and stats.edges_left == 0
    assert q.watertight and q.degenerate_triangles == 0 and trimesh_watertight(out)
    assert volume(out) == pytest.approx(-2.0 if flip else 2.0)
    m = len(verts)
    assert np.allclose(out.vertices[m], [1.0, 1.0, 0.5]) and set(sources[m].tolist()) == {3, 7}
    # each copy of the edge joins the two triangles that bound one wedge of solid: two of the same cube; inside out,
    # the solid is the outside, whose two wedges each lie between a face of A and a face of B
    centroid = out.vertices[out.triangles].mean(axis=1)
    in_cube_a = centroid[:, 0] + centroid[:, 1] < 2.0  # A lies at x + y <= 2, B at x + y >= 2
    for edge in ((3, 7), (3, m), (m, 7)):
        on = np.flatnonzero(np.isin(out.triangles, edge).sum(axis=1) == 2)
        assert len(on) == 2
        in_a = in_cube_a[on]
        assert (in_a[0] == in_a[1]) != flip
