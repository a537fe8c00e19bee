"""Close a screened-Poisson mesh where it runs into its reconstruction cube: caps on the cube's faces.

open3d's screened Poisson (PoissonRecon with Neumann boundary conditions, not configurable in open3d) extracts the
iso-surface of the indicator function inside a cube (the points' bounding box × ``scale``). A closed sampling gives
a closed surface, but an open scene (a ground plane, a terrain) has an iso-surface that runs into the cube and is
cut there: its boundary edges all lie on the cube's faces. ``scale``, ``width`` and ``linear_fit`` move the cube or
the function, never this cut. The solid the mesh describes is then {indicator inside} ∩ cube, and its boundary is the
mesh plus, on each face of the cube, the part of the face that lies inside. This module adds those parts ("caps"),
so the result is the closed boundary of that solid (watertight, every edge used by exactly two triangles).

Per cube face F (2D frame (u, v) with u × v = the outward normal of F):

- the mesh's boundary edges on F, reversed (the cap is on the other side of the mesh's boundary: it runs the other
  way round), form chains that start and end on the border of F (on the cube's edges) or closed loops. The mesh's
  triangles are oriented with normals pointing out of the solid (open3d: towards the side the point normals face),
  so the inside part of F lies to the left of each reversed edge in the (u, v) frame;
- walking the border of F counter-clockwise, a chain that ends on the border leaves the walk inside, one that
  starts there leaves it outside: the border segments between consecutive points (chain ends, chain starts, cube
  corners) are thereby inside or outside. A face with no chain end takes the state of its corners from the
  neighbouring faces (a cube edge no chain crosses has one state along its length); with no chain end anywhere, the
  largest closed loop on a face decides (anticlockwise: it bounds an inside island, the corners are outside);
- the reversed chain edges and the inside border segments make closed rings (traced keeping the region on their
  left, the smallest left turn at a vertex shared by several rings); anticlockwise rings are outer boundaries,
  clockwise ones are holes and go to the smallest outer ring containing them;
- each outer ring with its holes is triangulated by ``mapbox-earcut`` (the ear-clipping triangulator trimesh uses),
  which adds no vertex (:func:`triangulate_rings`). Along collinear ring vertices (a straight chain along a flat
  ground) earcut drops vertices or clips flat ears, and either would leave a T-junction: runs of straight vertices
  are therefore bowed slightly into the region for earcut only, the flat triangles that remain where vertices of
  different runs share a line are removed by edge flips, and a ring edge still missing is restored by splitting the
  triangle over it into a fan. Cap triangles are anticlockwise in (u, v): their normals point out of the cube, i.e.
  out of the solid.

Cap vertices are the mesh's own boundary vertices (snapped exactly onto the cube's planes: open3d's float32 round-off
leaves them ~1e-7 m off) and the cube corners that lie inside; a vertex on a cube edge is a chain end on both faces
that meet there, so both faces' caps use it and the caps meet without a gap.

Written by hand because no maintained library closes an open mesh against its clipping box: hole fillers
(trimesh ``fill_holes``, PyMeshFix) triangulate each boundary loop on its own, which is neither flat on the cube nor
correct for loops that cross several faces; a boolean with the cube (manifold3d) needs a closed mesh to begin with.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from core.errors import DataError
from fusion.mesh.graph import edge_use_counts
from fusion.mesh.types import TriangleMesh

# (u axis, v axis) per face (axis k, side s): u × v = outward normal (+e_k for s = 1, −e_k for s = 0)
_FACE_AXES = {(0, 1): (1, 2), (0, 0): (2, 1), (1, 1): (2, 0), (1, 0): (0, 2), (2, 1): (0, 1), (2, 0): (1, 0)}


@dataclass
class ClosingStats:
    """Outcome of :func:`close_at_cube`.

    closed: the caps were built and every boundary edge of the input got its partner (the result's edge counts are
    checked afterwards by :func:`fusion.mesh.quality.mesh_quality`). boundary_edges_in: boundary edges of the
    input. cap_triangles / cap_corners: triangles and cube corners added. snapped_vertices: boundary vertices moved
    onto the cube's planes (by at most ``snap_tolerance`` metres). problem: why nothing was added ("" when closed).
    """

    closed: bool
    boundary_edges_in: int
    cap_triangles: int
    cap_corners: int
    snapped_vertices: int
    snap_tolerance: float
    problem: str = ""


class _CannotClose(Exception):
    pass


def poisson_cube(positions: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The reconstruction cube of open3d's screened Poisson for (N, 3) float64 points: the bounding box's centre
    ± ``scale`` × its largest side / 2 (PoissonRecon's ``GetPointXForm``). Returns (lo, hi), each (3,) float64."""
    pmin, pmax = positions.min(axis=0), positions.max(axis=0)
    centre = 0.5 * (pmin + pmax)
    half = 0.5 * float(np.max(pmax - pmin)) * scale
    return centre - half, centre + half


def close_at_cube(
    mesh: TriangleMesh, lo: np.ndarray, hi: np.ndarray, snap_tolerance: float
) -> tuple[TriangleMesh, np.ndarray, ClosingStats]:
    """The mesh closed by caps on the faces of the cube [lo, hi] (local frame of ``mesh``; see the module docstring).

    Returns the closed mesh (the input's vertices first, in order, boundary vertices snapped onto the cube; then the
    corners used; vertex colours, if any, continue with grey corners), a (T,) bool mask of the cap triangles (the
    input's triangles come first), and the stats. A mesh without boundary edges comes back unchanged. When the
    boundary is not where a cube cut would put it (an edge off the cube's faces, states that contradict each other),
    the input comes back unchanged with ``closed`` False and the reason in ``problem``.
    """
    lo = np.asarray(lo, dtype=np.float64).reshape(3)
    hi = np.asarray(hi, dtype=np.float64).reshape(3)
    if not (hi > lo).all():
        raise DataError(f"the closing cube is empty: lo {lo}, hi {hi}")
    tris = mesh.triangles
    no_caps = np.zeros(len(tris), dtype=bool)
    if len(tris) == 0:
        return mesh, no_caps, ClosingStats(False, 0, 0, 0, 0, snap_tolerance, "the mesh has no triangles")
    directed = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    third = np.concatenate([tris[:, 2], tris[:, 0], tris[:, 1]])
    edges, counts = edge_use_counts(tris)
    key = np.sort(directed, axis=1)
    # directed edges whose undirected edge is used once: the boundary, as the triangles run along it
    boundary_keys = edges[counts == 1]
    if len(boundary_keys) == 0:
        return mesh, no_caps, ClosingStats(True, 0, 0, 0, 0, snap_tolerance)
    n_v = len(mesh.vertices)
    code = key[:, 0] * n_v + key[:, 1]
    is_b = np.isin(code, boundary_keys[:, 0] * n_v + boundary_keys[:, 1])
    b_dir, b_third = directed[is_b], third[is_b]
    try:
        vertices, snapped, caps, corners = _caps(mesh.vertices, b_dir, b_third, lo, hi, snap_tolerance)
    except _CannotClose as why:
        return mesh, no_caps, ClosingStats(False, len(b_dir), 0, 0, 0, snap_tolerance, str(why))
    colors = mesh.vertex_colors
    if colors is not None:
        colors = np.concatenate([colors, np.full((len(vertices) - n_v, 3), 0.5, dtype=np.float32)])
    out = TriangleMesh(vertices, np.concatenate([tris, caps]), mesh.origin.copy(), colors)
    is_cap = np.concatenate([no_caps, np.ones(len(caps), dtype=bool)])
    return out, is_cap, ClosingStats(True, len(b_dir), len(caps), corners, snapped, snap_tolerance)


def _caps(
    vertices: np.ndarray, b_dir: np.ndarray, b_third: np.ndarray, lo: np.ndarray, hi: np.ndarray, tol: float
) -> tuple[np.ndarray, int, np.ndarray, int]:
    """(vertices with snapped boundary vertices and the used corners appended, number snapped, (C, 3) cap
    triangles, corners added); :class:`_CannotClose` when the boundary does not fit a cube cut."""
    verts = vertices.copy()
    planes, snapped = _snap_to_cube(verts, np.unique(b_dir), lo, hi, tol)
    face_of = _face_of_edges(planes, b_dir, b_third)
    faces = [_FaceCut(f, lo, hi, verts, b_dir[face_of == f][:, ::-1], planes) for f in range(6)]
    corner_state = _corner_states(faces)
    return _assemble_caps(faces, corner_state, verts, lo, hi, snapped)


def _snap_to_cube(
    verts: np.ndarray, bv: np.ndarray, lo: np.ndarray, hi: np.ndarray, tol: float
) -> tuple[np.ndarray, int]:
    """Snap the boundary vertices ``bv`` of ``verts`` (V, 3), in place, exactly onto the cube faces within ``tol``
    metres; returns the (V, 6) bool "vertex on face 2k + s" table and the number of coordinates moved."""
    planes = np.zeros((len(verts), 6), dtype=bool)  # vertex on face 2k + s
    for k in range(3):
        for s, value in ((0, lo[k]), (1, hi[k])):
            near = np.abs(verts[bv, k] - value) <= tol
            planes[bv[near], 2 * k + s] = True
    off_cube = bv[~planes[bv].any(axis=1)]
    if len(off_cube):
        raise _CannotClose(f"{len(off_cube)} boundary vertices lie off the cube's faces (holes in the surface)")
    snapped = 0
    for f in range(6):
        k, s = divmod(f, 2)
        on = np.flatnonzero(planes[:, f])
        snapped += int((verts[on, k] != (hi[k] if s else lo[k])).sum())
        verts[on, k] = hi[k] if s else lo[k]
    return planes, snapped


def _face_of_edges(planes: np.ndarray, b_dir: np.ndarray, b_third: np.ndarray) -> np.ndarray:
    """(E,) int64 cube face of each boundary edge: the one face both ends share (two shared: an edge along a cube
    edge, where the face is the one its triangle's third vertex also lies on, else ambiguous)."""
    shared = planes[b_dir[:, 0]] & planes[b_dir[:, 1]]
    n_shared = shared.sum(axis=1)
    if (n_shared == 0).any():
        raise _CannotClose(f"{int((n_shared == 0).sum())} boundary edges cross the inside of the cube")
    two = np.flatnonzero(n_shared > 1)
    if len(two):
        third_on = planes[b_third[two]] & shared[two]
        if (third_on.sum(axis=1) != 1).any():
            raise _CannotClose("a boundary edge runs along a cube edge and its face cannot be told")
        shared[two] = third_on
    return np.argmax(shared, axis=1)


def _corner_states(faces: list[_FaceCut]) -> dict[int, bool]:
    """Inside (True) or outside of each of the 8 cube corners, from the faces' chain ends, else from the largest
    loop, spread over faces without chain ends; :class:`_CannotClose` when they contradict or stay unknown."""
    corner_state: dict[int, bool] = {}
    for face in faces:
        for c, state in face.corner_states().items():
            if corner_state.setdefault(c, state) != state:
                raise _CannotClose(f"cube corner {c} is inside on one face and outside on another")
    if not corner_state and any(face.edges.size for face in faces):
        # no chain crosses a cube edge: one state for all corners, from the largest loop of some face
        state = max((face for face in faces if face.edges.size), key=lambda fc: fc.largest_loop_area()[0])
        inside = state.largest_loop_area()[1] < 0  # a clockwise outermost loop is a hole in an inside face
        corner_state = {c: inside for c in range(8)}
    changed = True
    while changed:  # faces without chain ends: all four corners share one state; spread it
        changed = False
        for face in faces:
            if face.has_chain_ends:
                continue
            known = {corner_state[c] for c in face.corners if c in corner_state}
            if len(known) > 1:
                raise _CannotClose(f"face {face.face} has corners inside and outside but no chain crosses it")
            if known:
                state = known.pop()
                for c in face.corners:
                    if c not in corner_state:
                        corner_state[c] = state
                        changed = True
    if len(corner_state) < 8:
        raise _CannotClose("the inside of the cube's corners cannot be told")
    return corner_state


def _assemble_caps(
    faces: list[_FaceCut],
    corner_state: dict[int, bool],
    verts: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    snapped: int,
) -> tuple[np.ndarray, int, np.ndarray, int]:
    """Triangulate every face's cap and give the cube corners they use vertex ids after ``verts`` (in order of first
    use); returns what :func:`_caps` returns."""
    # cube corners: index by bits (x hi?, y hi?, z hi?)
    corner_pos = np.array([[hi[0] if c & 1 else lo[0], hi[1] if c & 2 else lo[1], hi[2] if c & 4 else lo[2]]
                           for c in range(8)])  # fmt: skip
    corner_vertex: dict[int, int] = {}
    caps: list[np.ndarray] = []
    for face in faces:
        tri = face.triangulate(corner_state)
        if len(tri) == 0:
            continue
        ids = np.empty(tri.shape, dtype=np.int64)
        neg = tri < 0
        ids[~neg] = tri[~neg]
        for c in np.unique(-tri[neg] - 1):
            if c not in corner_vertex:
                corner_vertex[int(c)] = len(verts) + len(corner_vertex)
        ids[neg] = [corner_vertex[int(c)] for c in (-tri[neg] - 1)]
        caps.append(ids)
    extra = corner_pos[sorted(corner_vertex, key=corner_vertex.get)] if corner_vertex else np.zeros((0, 3))
    cap = np.concatenate(caps) if caps else np.zeros((0, 3), dtype=np.int64)
    return np.concatenate([verts, extra]), snapped, cap, len(corner_vertex)


class _FaceCut:
    """The cap of one cube face: its chains (reversed boundary edges), border points and their inside states.

    Vertex ids: mesh vertex ids >= 0, cube corner c as −c − 1.
    """

    def __init__(self, face: int, lo, hi, verts: np.ndarray, edges: np.ndarray, planes: np.ndarray) -> None:
        self.face = face
        k, s = divmod(face, 2)
        self.u_axis, self.v_axis = _FACE_AXES[(k, s)]
        self.lo, self.hi = lo, hi
        self.verts = verts
        self.edges = edges.astype(np.int64)  # (E, 2) directed, region on the left
        self.width = hi[self.u_axis] - lo[self.u_axis]
        self.height = hi[self.v_axis] - lo[self.v_axis]
        # the 4 corners of the face, anticlockwise in (u, v) from (u0, v0)
        corners = []
        for cu, cv in ((0, 0), (1, 0), (1, 1), (0, 1)):
            bits = [0, 0, 0]
            bits[k] = s
            bits[self.u_axis], bits[self.v_axis] = cu, cv
            corners.append(bits[0] | bits[1] << 1 | bits[2] << 2)
        self.corners = corners
        ids = np.unique(self.edges) if len(self.edges) else np.zeros(0, np.int64)
        on_other = planes[ids].sum(axis=1) > 1  # on the face's border (a cube edge)
        self.border_ids = ids[on_other]
        out_deg = defaultdict(int)
        in_deg = defaultdict(int)
        for a, b in self.edges.tolist():
            out_deg[a] += 1
            in_deg[b] += 1
        self.net = {int(v): out_deg[int(v)] - in_deg[int(v)] for v in self.border_ids}
        if any(abs(n) > 1 for n in self.net.values()):
            raise _CannotClose(f"face {face}: a border vertex starts or ends more than one chain")
        interior = set(ids.tolist()) - set(self.border_ids.tolist())
        if any(out_deg[v] != in_deg[v] for v in interior):
            raise _CannotClose(f"face {face}: a chain ends inside the face (a boundary that is not a cube cut)")
        self.has_chain_ends = any(n != 0 for n in self.net.values())
        self._segments = self._border_segments()

    def uv(self, vid: int) -> np.ndarray:
        if vid >= 0:
            p = self.verts[vid]
        else:
            c = -vid - 1
            p = np.array([self.hi[i] if c >> i & 1 else self.lo[i] for i in range(3)])
        return np.array([p[self.u_axis], p[self.v_axis]])

    def _perimeter(self, uv: np.ndarray) -> float:
        """Anticlockwise arc length from (u0, v0) of a point on the face's border."""
        du, dv = uv[0] - self.lo[self.u_axis], uv[1] - self.lo[self.v_axis]
        w, h = self.width, self.height
        eps = 1e-12 * max(w, h)
        if dv <= eps and du < w - eps:
            return du
        if du >= w - eps and dv < h - eps:
            return w + dv
        if dv >= h - eps and du > eps:
            return w + h + (w - du)
        return 2 * w + h + (h - dv)

    def _border_segments(self) -> list[tuple[int, int, bool | None]]:
        """Consecutive border points (anticlockwise) as (from, to, inside?) with inside None where unknown."""
        pts = [(self._perimeter(self.uv(int(v))), int(v)) for v in self.border_ids]
        pts += [(self._perimeter(self.uv(-c - 1)), -c - 1) for c in self.corners]
        pts.sort()
        n = len(pts)
        states: list[bool | None] = [None] * n  # state of the segment after point i
        starts = [i for i, (_, v) in enumerate(pts) if v >= 0 and self.net[v] != 0]
        if starts:
            first = starts[0]
            state = None
            for j in range(n):
                i = (first + j) % n
                v = pts[i][1]
                net = self.net.get(v, 0) if v >= 0 else 0
                if net == -1:  # a chain ends here: the border walk goes on inside
                    if state is True:
                        raise _CannotClose(f"face {self.face}: two chain ends follow each other on the border")
                    state = True
                elif net == 1:
                    if state is False:
                        raise _CannotClose(f"face {self.face}: two chain starts follow each other on the border")
                    state = False
                states[i] = state
            # the segment before the first point must agree with it
            v0 = pts[first][1]
            if (self.net[v0] == -1) == states[(first - 1) % n]:
                raise _CannotClose(f"face {self.face}: chain starts and ends do not alternate on the border")
        return [(pts[i][1], pts[(i + 1) % n][1], states[i]) for i in range(n)]

    def corner_states(self) -> dict[int, bool]:
        """Inside state of this face's corners, known where chains cross its border."""
        out: dict[int, bool] = {}
        for a, _, state in self._segments:
            if a < 0 and state is not None:
                out[-a - 1] = state
        return out

    def largest_loop_area(self) -> tuple[float, float]:
        """(|area|, signed area) of the largest closed ring of the chains alone (faces without chain ends)."""
        rings = self._rings([tuple(e) for e in self.edges.tolist()])
        areas = [self._signed_area(r) for r in rings]
        best = max(areas, key=abs, default=0.0)
        return abs(best), best

    def _signed_area(self, ring: list[int]) -> float:
        p = np.array([self.uv(v) for v in ring])
        q = np.roll(p, -1, axis=0)
        return 0.5 * float((p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]).sum())

    def _rings(self, edges: list[tuple[int, int]]) -> list[list[int]]:
        """Closed rings of directed edges, keeping the region on the left (smallest left turn at shared vertices)."""
        outgoing: dict[int, list[int]] = defaultdict(list)
        for i, (a, _) in enumerate(edges):
            outgoing[a].append(i)
        used = np.zeros(len(edges), dtype=bool)
        rings = []
        for start in range(len(edges)):
            if used[start]:
                continue
            ring, e = [], start
            while True:
                used[e] = True
                a, b = edges[e]
                ring.append(a)
                cands = [i for i in outgoing[b] if not used[i] or i == start]
                if not cands:
                    raise _CannotClose(f"face {self.face}: a ring does not close")
                if len(cands) > 1:
                    back = self.uv(a) - self.uv(b)
                    ang_back = np.arctan2(back[1], back[0])

                    def clockwise_from_back(i: int, ang_back=ang_back, b=b) -> float:
                        d = self.uv(edges[i][1]) - self.uv(b)
                        return (ang_back - np.arctan2(d[1], d[0])) % (2 * np.pi) or 2 * np.pi

                    cands.sort(key=clockwise_from_back)
                e = cands[0]
                if e == start:
                    break
                if len(ring) > len(edges):
                    raise _CannotClose(f"face {self.face}: ring tracing does not terminate")
            rings.append(ring)
        return rings

    def triangulate(self, corner_state: dict[int, bool]) -> np.ndarray:
        """(C, 3) cap triangles (vertex ids as in the class docstring), anticlockwise in (u, v)."""
        segs = []
        for a, b, state in self._segments:
            if state is None:  # no chain end on this face: the corners' common state
                c = next(-v - 1 for v in (a, b) if v < 0) if (a < 0 or b < 0) else self.corners[0]
                state = corner_state[c]
            if state and a != b:
                segs.append((a, b))
        edges = [tuple(e) for e in self.edges.tolist()] + segs
        if not edges:
            return np.zeros((0, 3), dtype=np.int64)
        rings = self._rings(edges)
        areas = [self._signed_area(r) for r in rings]
        outers = [i for i, a in enumerate(areas) if a > 0]
        holes = [i for i, a in enumerate(areas) if a < 0]
        members: dict[int, list[int]] = {i: [] for i in outers}
        for h in holes:
            probe = self._inner_probe(rings[h])
            owners = [o for o in outers if _inside(probe, np.array([self.uv(v) for v in rings[o]]))]
            if not owners:
                raise _CannotClose(f"face {self.face}: a hole lies in no inside region")
            members[min(owners, key=lambda o: areas[o])].append(h)
        out = []
        for o, hs in members.items():
            ring_ids = [rings[o]] + [rings[h] for h in hs]
            flat = np.concatenate(ring_ids)
            local = triangulate_rings([np.array([self.uv(int(v)) for v in r]) for r in ring_ids])
            out.append(flat[local])
        return np.concatenate(out) if out else np.zeros((0, 3), dtype=np.int64)

    def _inner_probe(self, ring: list[int]) -> np.ndarray:
        """A point just off the first edge of a hole ring, on the side of the region around it (its left)."""
        a, b = self.uv(ring[0]), self.uv(ring[1])
        d = b - a
        left = np.array([-d[1], d[0]])
        return 0.5 * (a + b) + 1e-6 * left


def triangulate_rings(rings: list[np.ndarray]) -> np.ndarray:
    """(T, 3) int64 anticlockwise triangles of a polygon region: ``rings[0]`` (P0, 2) its outer boundary,
    anticlockwise, the others its holes, clockwise; indices into the rings concatenated in order. Every ring vertex
    is used and every ring edge is an edge of exactly one triangle, collinear runs of vertices included (earcut
    would skip them or clip flat ears: see :func:`_nudge_straight_vertices`); no Steiner point is added."""
    import mapbox_earcut

    uv = np.concatenate([np.asarray(r, dtype=np.float64).reshape(-1, 2) for r in rings])
    ends = np.cumsum([len(r) for r in rings]).astype(np.uint32)
    nudged = _nudge_straight_vertices(uv, ends)
    local = np.asarray(mapbox_earcut.triangulate_float64(nudged, ends), dtype=np.int64).reshape(-1, 3)
    local = _flip_flat(_orient_anticlockwise(local, nudged), uv)
    positions = np.split(np.arange(len(uv)), ends[:-1].astype(np.int64))
    return _fan_skipped(local, [list(p) for p in positions])


def _nudge_straight_vertices(uv: np.ndarray, ends: np.ndarray, fraction: float = 1e-4) -> np.ndarray:
    """A copy of the ring vertices (P, 2) where every run of vertices that lie straight between their ring neighbours
    is bowed into the region (the ring's left): a vertex at arc length t ∈ (0, 1) along a run of length L moves by
    ``fraction`` · L · 4t(1 − t). ``ends``: cumulative ring lengths. On the strictly concave bow every such vertex is
    reflex, so earcut can neither drop it as collinear, skip it, nor clip it as a flat ear: it is joined to a vertex
    across the region (triangles that are not flat at the true positions). Only the triangulation sees the moved
    positions; the cap's vertices stay where they are."""
    out = uv.copy()
    start = 0
    for end in np.asarray(ends, dtype=np.int64):
        ring = uv[start:end]
        n = len(ring)
        if n >= 3:
            d_in = ring - np.roll(ring, 1, axis=0)
            d_out = np.roll(ring, -1, axis=0) - ring
            len_in = np.linalg.norm(d_in, axis=1)
            len_out = np.linalg.norm(d_out, axis=1)
            cross = d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0]
            dot = np.einsum("ij,ij->i", d_in, d_out)
            straight = (np.abs(cross) <= 1e-9 * len_in * len_out) & (dot > 0)
            if straight.any() and not straight.all():
                for j, k in _cyclic_runs(straight.tolist()):
                    run = [m % n for m in range(j - 1, k + 1)]  # a corner, the straight vertices, a corner
                    arc = np.concatenate([[0.0], np.cumsum(len_out[run[:-1]])])
                    length = arc[-1]
                    t = arc[1:-1] / length
                    chord = ring[run[-1]] - ring[run[0]]
                    left = np.array([-chord[1], chord[0]]) / max(float(np.linalg.norm(chord)), 1e-300)
                    out[start + np.array(run[1:-1])] += np.outer(fraction * length * 4 * t * (1 - t), left)
        start = end
    return out


def _cyclic_runs(flags: list[bool]) -> list[tuple[int, int]]:
    """The runs of True in a cyclic sequence that holds at least one False: (j, k) per run, its items j .. k − 1
    taken modulo the length (0 < j < k)."""
    n = len(flags)
    first = next(i for i in range(n) if not flags[i])
    runs = []
    j = first + 1
    while j < first + n:
        if not flags[j % n]:
            j += 1
            continue
        k = j
        while flags[k % n]:
            k += 1
        runs.append((j, k))
        j = k
    return runs


def _orient_anticlockwise(tri: np.ndarray, uv: np.ndarray) -> np.ndarray:
    p = uv[tri]
    area = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1])
    tri = tri.copy()
    tri[area < 0] = tri[area < 0][:, [0, 2, 1]]
    return tri


def _flat(p: np.ndarray) -> np.ndarray:
    """(T,) bool: triangles (T, 3, 2) whose corners are collinear (area below 1e-9 × their longest edge²)."""
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    cross = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    longest = np.max(np.linalg.norm(np.stack([e1, e2, p[:, 2] - p[:, 1]], axis=1), axis=2), axis=1)
    return cross <= 1e-9 * longest**2


def _flip_flat(tri: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The triangulation without flat triangles: a flat (a, b, c), b on the segment c → a, and its neighbour
    (a, c, d) across that segment become (a, b, d) and (b, c, d) (an edge flip, which keeps every edge of the
    region's boundary), repeated while flat triangles remain. Earcut makes them where vertices of different rings or
    runs lie on one line (seen through the nudged positions they are thin, not flat)."""
    tris = [list(t) for t in tri.tolist()]
    edge_of = {}
    for i, (p, q, r) in enumerate(tris):
        edge_of[(p, q)], edge_of[(q, r)], edge_of[(r, p)] = i, i, i
    todo = list(np.flatnonzero(_flat(uv[tri])))
    for _ in range(10 * len(tris) + 10):
        if not todo:
            return np.asarray(tris, dtype=np.int64).reshape(-1, 3)
        i = todo.pop()
        p = uv[tris[i]]
        if not _flat(p[None])[0]:
            continue
        lengths = [np.linalg.norm(p[(k + 1) % 3] - p[k]) for k in range(3)]  # edge k runs from corner k to k + 1
        k = int(np.argmax(lengths))
        c, a = tris[i][k], tris[i][(k + 1) % 3]  # the longest edge c → a
        b = tris[i][(k + 2) % 3]
        j = edge_of.get((a, c))
        if j is None:
            raise _CannotClose("a flat cap triangle lies on the region's boundary")
        d = next(v for v in tris[j] if v not in (a, c))
        for t in (i, j):
            q, r, s = tris[t]
            for e in ((q, r), (r, s), (s, q)):
                edge_of.pop(e, None)
        tris[i], tris[j] = [a, b, d], [b, c, d]
        for t in (i, j):
            q, r, s = tris[t]
            edge_of[(q, r)], edge_of[(r, s)], edge_of[(s, q)] = t, t, t
        todo += [i, j]
    raise _CannotClose("flat cap triangles remain after edge flips")


def _fan_skipped(tri: np.ndarray, rings: list[list[int]]) -> np.ndarray:
    """Restore the ring edges the triangles miss: a run of them from a to c (collinear vertices earcut skipped, or
    covered only by flat triangles that were dropped) lies on the segment a → c, an edge of exactly one
    anticlockwise triangle (a, c, x), which is split into a fan through the run's vertices.

    ``tri`` indexes the concatenated rings (anticlockwise triangles)."""
    tri_list = [list(t) for t in tri.tolist()]
    edge_of = {}
    for i, (p, q, r) in enumerate(tri_list):
        edge_of[(p, q)], edge_of[(q, r)], edge_of[(r, p)] = i, i, i
    offset = 0
    replaced: dict[int, list[list[int]]] = {}
    for ring in rings:
        n = len(ring)
        idx = list(range(offset, offset + n))
        offset += n
        missing = [(idx[j], idx[(j + 1) % n]) not in edge_of for j in range(n)]
        if not any(missing):
            continue
        if all(missing):
            raise _CannotClose("the triangulation misses a whole ring")
        for j, k in _cyclic_runs(missing):
            chain = [idx[m % n] for m in range(j, k + 1)]  # run of missing edges j .. k-1: vertices j .. k
            a, c = chain[0], chain[-1]
            t = edge_of.get((a, c))
            if t is None or t in replaced:
                raise _CannotClose("ring vertices left out of the triangulation have no triangle to split")
            x = set(tri_list[t]) - {a, c}
            if len(x) != 1:
                raise _CannotClose("a flat triangle where a skipped ring vertex goes")
            xv = x.pop()
            replaced[t] = [[chain[m], chain[m + 1], xv] for m in range(len(chain) - 1)]
    if not replaced:
        return tri
    out = []
    for i, t in enumerate(tri_list):
        out.extend(replaced.get(i, [t]))
    return np.asarray(out, dtype=np.int64)


def _inside(point: np.ndarray, polygon: np.ndarray) -> bool:
    """Even-odd test of a 2D point against a closed polygon (P, 2)."""
    x, y = point
    p, q = polygon, np.roll(polygon, -1, axis=0)
    crosses = (p[:, 1] > y) != (q[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = p[:, 0] + (y - p[:, 1]) * (q[:, 0] - p[:, 0]) / (q[:, 1] - p[:, 1])
    return bool((crosses & (x < xs)).sum() % 2)
