"""fusion.mesh.closing: the screened-Poisson mesh of an open scene, cut by its reconstruction cube, closed with caps.

Truth: exact volumes of hand-built meshes, the volume under an open surface by ray parity (open3d's ray casting of
the uncapped surface), π r² h for a tube, complementary solids (normals flipped) that fill the cube together.
"""

import numpy as np
import pytest

from fusion.mesh.closing import close_at_cube
from fusion.mesh.poisson import PoissonOptions, poisson_reconstruct, trim_mesh
from fusion.mesh.quality import mesh_quality
from fusion.mesh.types import OrientedPoints, TriangleMesh


def grid_mesh(n: int, height, flip: bool = False) -> TriangleMesh:
    """A height field z = height(x, y) on an n × n grid over [-1, 1]², normals up (down with ``flip``)."""
    x, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n), indexing="xy")
    verts = np.stack([x.ravel(), y.ravel(), height(x, y).ravel()], axis=1)
    i = np.arange(n - 1)
    a = (i[:, None] * n + i[None, :]).ravel()  # lower-left corner of each cell (row = y)
    tris = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    return TriangleMesh(verts, tris[:, ::-1] if flip else tris)


def o3d_watertight(mesh: TriangleMesh) -> bool:
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.triangles.astype(np.int32))
    )
    return m.is_watertight()


def volume(mesh: TriangleMesh) -> float:
    """Signed volume by the divergence theorem (positive for outward normals)."""
    v = mesh.vertices[mesh.triangles]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def check_caps_on_cube(mesh: TriangleMesh, is_cap: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
    """Every cap triangle lies in one face plane of the cube and its normal points out of the cube."""
    v = mesh.vertices[mesh.triangles[is_cap]]
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    for t in range(len(v)):
        k = int(np.argmax(np.abs(normal[t])))
        on_lo, on_hi = (v[t, :, k] == lo[k]).all(), (v[t, :, k] == hi[k]).all()
        assert on_lo != on_hi  # exactly on one plane of the cube
        assert np.sign(normal[t, k]) == (1 if on_hi else -1)


@pytest.mark.parametrize("flip", [False, True])
def test_hand_built_plane_with_collinear_borders_closes_to_the_exact_volume(flip):
    # z = 0.3 x + 0.2 y + 0.25 over the whole top of the cube [-1, 1]³: its boundary vertices are collinear along
    # each side (earcut skips them; the fan must put them back); volume under it = ∫∫ (z + 1) = 4 · 1.25 = 5
    open_mesh = grid_mesh(9, lambda x, y: 0.3 * x + 0.2 * y + 0.25, flip)
    lo, hi = -np.ones(3), np.ones(3)
    closed, is_cap, stats = close_at_cube(open_mesh, lo, hi, snap_tolerance=1e-9)
    q = mesh_quality(closed)
    assert stats.closed and stats.problem == "" and stats.boundary_edges_in == 32
    assert q.watertight and q.degenerate_triangles == 0 and o3d_watertight(closed)
    assert stats.cap_corners == 4  # the four corners on the inside side
    assert volume(closed) == pytest.approx(3.0 if flip else 5.0, abs=1e-12)
    check_caps_on_cube(closed, is_cap, lo, hi)
    # the input's triangles come first and are unchanged
    assert np.array_equal(closed.triangles[: open_mesh.num_triangles], open_mesh.triangles)


def test_closed_mesh_comes_back_unchanged_and_a_real_hole_is_refused():
    grid = grid_mesh(5, lambda x, y: 0 * x)
    lo, hi = -np.ones(3), np.ones(3)
    closed, _, _ = close_at_cube(grid, lo, hi, 1e-9)
    again, is_cap, stats = close_at_cube(closed, lo, hi, 1e-9)
    assert stats.closed and stats.cap_triangles == 0 and again is closed and not is_cap.any()
    # a hole in the middle of the plane: boundary vertices off the cube's faces, nothing added
    centre = np.flatnonzero((np.abs(grid.vertices[:, :2]) < 1e-9).all(axis=1))[0]
    holed = TriangleMesh(grid.vertices, grid.triangles[~(grid.triangles == centre).any(axis=1)])
    out, is_cap, stats = close_at_cube(holed, lo, hi, 1e-9)
    assert not stats.closed and "off the cube" in stats.problem and out is holed and not is_cap.any()


def ground_points(n: int, normal_sign: float = 1.0, seed: int = 0) -> OrientedPoints:
    """A wavy ground z = 0.05 sin(3x) cos(2y) over [-1, 1]² with its analytic normals."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-1, 1, (2, n))
    z = 0.05 * np.sin(3 * x) * np.cos(2 * y)
    grad = np.stack([-0.15 * np.cos(3 * x) * np.cos(2 * y), 0.1 * np.sin(3 * x) * np.sin(2 * y), np.ones(n)], 1)
    normals = normal_sign * grad / np.linalg.norm(grad, axis=1, keepdims=True)
    return OrientedPoints(np.stack([x, y, z], 1), normals, np.full((n, 3), 0.5), np.ones(n), np.arange(n))


def test_poisson_mesh_of_an_open_ground_is_watertight_and_encloses_what_lies_below_it():
    import open3d as o3d

    pts = ground_points(4000)
    options = PoissonOptions(depth=6)
    raw = poisson_reconstruct(pts, PoissonOptions(depth=6, close=False))
    assert mesh_quality(raw.mesh).boundary_edges > 0  # open3d's surface is cut open by its cube
    result = poisson_reconstruct(pts, options)
    q = mesh_quality(result.mesh)
    assert result.closing.closed and q.watertight and o3d_watertight(result.mesh)
    assert np.array_equal(result.mesh.triangles[~result.is_cap], raw.mesh.triangles)
    lo, hi = result.cube_lo, result.cube_hi
    # the cube is open3d's: its cut surface reaches the cube's side faces (to float32 round-off)
    side = float(hi[0] - lo[0])
    assert side == pytest.approx(1.1 * np.ptp(pts.positions, axis=0).max())
    assert np.allclose(raw.mesh.vertices[:, :2].min(axis=0), lo[:2], atol=1e-6 * side)
    assert np.allclose(raw.mesh.vertices[:, :2].max(axis=0), hi[:2], atol=1e-6 * side)
    check_caps_on_cube(result.mesh, result.is_cap, lo, hi)
    # truth: the share of the cube below the open surface, by ray parity (rays straight up, the surface is a height
    # field inside the cube), from 40 000 random points: σ of the share ≈ 0.0025
    rng = np.random.default_rng(1)
    probes = rng.uniform(lo, hi, (40_000, 3))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(raw.mesh.vertices.astype(np.float32)), o3d.core.Tensor(raw.mesh.triangles.astype(np.uint32))
    )
    rays = np.concatenate([probes, np.tile([1e-4, 2e-4, 1.0], (len(probes), 1))], axis=1).astype(np.float32)
    below = scene.count_intersections(o3d.core.Tensor(rays)).numpy() % 2 == 1
    cube = float(np.prod(hi - lo))
    assert volume(result.mesh) / cube == pytest.approx(below.mean(), abs=0.01)
    # the same ground with normals down encloses the rest of the cube
    other = poisson_reconstruct(ground_points(4000, -1.0), options)
    assert mesh_quality(other.mesh).watertight
    assert volume(result.mesh) + volume(other.mesh) == pytest.approx(cube, rel=0.005)
    # trimming removes every cap
    trimmed, stats = trim_mesh(result, options)
    assert stats.removed_caps == int(result.is_cap.sum()) > 0
    assert (trimmed.vertices[:, :2] < hi[:2] - 1e-9).all() and (trimmed.vertices[:, :2] > lo[:2] + 1e-9).all()


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_tube_through_the_cube_is_capped_by_discs(sign):
    # a vertical tube of radius r: the surface meets only the top and bottom faces, in closed loops (no chain ends
    # on any face border); outward normals enclose π r² h, inward ones the rest of the cube
    n, r = 4000, 0.3
    rng = np.random.default_rng(0)
    a, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(-1, 1, n)
    pos = np.stack([r * np.cos(a), r * np.sin(a), z], 1)
    normal = sign * np.stack([np.cos(a), np.sin(a), np.zeros(n)], 1)
    result = poisson_reconstruct(OrientedPoints(pos, normal, np.full((n, 3), 0.5), np.ones(n), np.arange(n)),
                                 PoissonOptions(depth=6))  # fmt: skip
    assert result.closing.closed and mesh_quality(result.mesh).watertight
    lo, hi = result.cube_lo, result.cube_hi
    cube, tube = float(np.prod(hi - lo)), np.pi * r**2 * (hi[2] - lo[2])
    assert volume(result.mesh) == pytest.approx(tube if sign > 0 else cube - tube, rel=0.03)


def _staircase_with_hole(rng: np.random.Generator, subdivide: int) -> list[np.ndarray]:
    """A rectilinear outer ring (anticlockwise) of random steps and a square hole (clockwise), each edge split into
    ``subdivide`` collinear pieces: the runs of straight vertices a cube cap along a flat ground has."""
    steps = rng.integers(1, 4, size=6)
    outer = [(0.0, 0.0), (20.0, 0.0)]
    y = 0.0
    for i, h in enumerate(steps):  # right side climbs in steps, alternating inwards and outwards
        y += h
        x = 20.0 - (i % 2)
        outer += [(outer[-1][0], y), (x, y)]
    outer += [(outer[-1][0], y + 1.0), (0.0, y + 1.0)]
    hole = [(5.0, 3.0), (5.0, 6.0), (8.0, 6.0), (8.0, 3.0)]  # clockwise

    def split(ring: list[tuple[float, float]]) -> np.ndarray:
        pts = []
        for a, b in zip(ring, ring[1:] + ring[:1], strict=True):
            a, b = np.array(a), np.array(b)
            if np.allclose(a, b):
                continue
            pts += [a + (b - a) * t for t in np.arange(subdivide) / subdivide]
        return np.array(pts)

    return [split(outer), split(hole)]


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("subdivide", [1, 3, 7])
def test_cap_triangulation_uses_every_ring_vertex_and_edge_exactly_once(seed, subdivide):
    from fusion.mesh.closing import triangulate_rings

    rings = _staircase_with_hole(np.random.default_rng(seed), subdivide)
    uv = np.concatenate(rings)
    tri = triangulate_rings(rings)
    p = uv[tri]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area = 0.5 * (e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1])
    assert (area > 1e-9).all(), "flat or clockwise triangles"

    def shoelace(r: np.ndarray) -> float:
        return 0.5 * float(np.sum(r[:, 0] * np.roll(r[:, 1], -1) - np.roll(r[:, 0], -1) * r[:, 1]))

    assert area.sum() == pytest.approx(shoelace(rings[0]) + shoelace(rings[1]), rel=1e-12)  # the hole's is negative
    directed = {tuple(e) for e in np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]).tolist()}
    assert len(directed) == 3 * len(tri)  # no directed edge twice: the triangles do not overlap
    offset = 0
    ring_edges = set()
    for r in rings:
        idx = np.arange(offset, offset + len(r))
        ring_edges |= set(zip(idx.tolist(), np.roll(idx, -1).tolist(), strict=True))
        offset += len(r)
    assert ring_edges <= directed  # every boundary edge is a triangle's edge, in the ring's direction
    inner = directed - ring_edges
    assert all((b, a) in inner for a, b in inner)  # every other edge is shared by two triangles: no gap, no T-junction
    assert set(tri.ravel().tolist()) == set(range(len(uv)))
