"""Make a closed triangle mesh edge-manifold without opening it: drop zero-volume pillows, split touching sheets.

Screened Poisson (open3d's PoissonRecon, adaptive octree) emits these defects where its iso-surface is ambiguous
(counts on a demo mesh in docs/experiments/2026-11-27-domain-defaults.md):

- pillows: two triangles with the same three vertices in opposite orders (a zero-volume double layer). Each of
  their edges loses one use in each direction when both go, so a closed mesh stays closed.
- touching sheets: an edge used by 2k triangles (k >= 2), half of them along a → b and half along b → a, where
  pieces of surface meet along a line. Sorted by angle around the edge, the triangles alternate in direction (of two
  coplanar flaps at one angle, the order that alternates is taken), and the solid lies in every second wedge between
  them (a triangle's normal points to the side of increasing angle when it
  runs along a → b). Each wedge of solid keeps its two bounding triangles as a pair.
- flat tetrahedra: two such triangles (a, b, c), (b, a, d) in one half plane that close, with the triangles on
  {a, c, d} and {b, c, d}, into a tetrahedron of zero volume (a sealed flat double layer): all four are removed.

The other pairs of such an edge get a vertex of their own at the edge's midpoint, each of their two triangles split
in two there: the pair's triangles then share the edges (a, m) and (m, b) instead of (a, b). Nothing moves (the
midpoint lies on the edge), every edge is used by at most two triangles, and a closed input stays closed (each edge
used exactly twice: watertight by edge counts). The sheets still touch geometrically, along the split edges.

Written by hand: open3d's ``remove_non_manifold_edges`` deletes triangles (which opens a closed mesh), and neither
open3d nor trimesh splits edges by the wedges of solid around them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fusion.mesh.graph import edge_use_counts
from fusion.mesh.types import TriangleMesh


@dataclass(frozen=True)
class ManifoldStats:
    """Pillow triangles removed, triangles of flat tetrahedra removed, non-manifold edges split, edges left
    non-manifold (directions that do not alternate around them), midpoint vertices added."""

    pillow_triangles: int
    flat_tetrahedron_triangles: int
    edges_split: int
    edges_left: int
    vertices_added: int


def make_edge_manifold(mesh: TriangleMesh) -> tuple[TriangleMesh, np.ndarray, ManifoldStats]:
    """The mesh without pillows and flat tetrahedra and with its other non-manifold edges split (module docstring).

    Returns the mesh (the input's vertices first, unchanged, then one midpoint per split pair; vertex colours follow,
    a midpoint's is the mean of its edge's ends), a (V', 2) int64 array of the two input vertices each vertex is the
    mean of (a vertex of the input: itself twice), and the counts. A mesh that is already edge-manifold comes back
    as it is.
    """
    tris = mesh.triangles
    n_v = len(mesh.vertices)
    same = np.stack([np.arange(n_v), np.arange(n_v)], axis=1)
    if len(tris) == 0:
        return mesh, same, ManifoldStats(0, 0, 0, 0, 0)
    keep = ~_pillows(tris)
    edges, counts = edge_use_counts(tris[keep])
    flat = _flat_tetrahedra(mesh.vertices, tris, keep, edges[counts > 2])
    keep &= ~flat
    tris = tris[keep]
    if flat.any():
        edges, counts = edge_use_counts(tris)
    if keep.all() and not (counts > 2).any():
        return mesh, same, ManifoldStats(0, 0, 0, 0, 0)

    # every directed edge occurrence: its triangle, the corner it starts at, start and end vertex
    t = len(tris)
    corner = np.tile(np.arange(3), t)
    tri_of = np.repeat(np.arange(t), 3)
    start = tris.reshape(-1)
    end = tris[:, [1, 2, 0]].reshape(-1)
    key = np.sort(np.stack([start, end], axis=1), axis=1)
    code = key[:, 0] * n_v + key[:, 1]
    order = np.argsort(code, kind="stable")
    code_sorted = code[order]
    bounds = np.flatnonzero(np.r_[True, code_sorted[1:] != code_sorted[:-1], True])
    size = np.diff(bounds)

    new_tris = [tris]
    drop = np.zeros(t, dtype=bool)
    midpoints: list[tuple[int, int]] = []
    split = left = 0
    for g in np.flatnonzero(size > 2):
        occ = order[bounds[g] : bounds[g + 1]]
        pairs = _wedge_pairs(mesh.vertices, tris, occ, tri_of, start, end)
        if pairs is None or drop[tri_of[occ]].any():
            left += 1
            continue
        split += 1
        for p, q in pairs[1:]:  # the first pair keeps the edge; every other pair gets its own midpoint
            m = n_v + len(midpoints)
            midpoints.append((int(start[p]), int(end[p])))
            for o in (p, q):
                tri = tris[tri_of[o]]
                c0 = corner[o]  # tri[c0] = start(o), tri[c0 + 1] = end(o), tri[c0 + 2] = the third vertex
                s0, e0, x = tri[c0], tri[(c0 + 1) % 3], tri[(c0 + 2) % 3]
                new_tris.append(np.array([[s0, m, x], [m, e0, x]]))
                drop[tri_of[o]] = True
    new_tris[0] = tris[~drop]
    mid = np.asarray(midpoints, dtype=np.int64).reshape(-1, 2)
    vertices = np.concatenate([mesh.vertices, 0.5 * (mesh.vertices[mid[:, 0]] + mesh.vertices[mid[:, 1]])])
    colors = None
    if mesh.vertex_colors is not None:
        mid_colors = 0.5 * (mesh.vertex_colors[mid[:, 0]] + mesh.vertex_colors[mid[:, 1]])
        colors = np.concatenate([mesh.vertex_colors, mid_colors])
    out = TriangleMesh(vertices, np.concatenate(new_tris), mesh.origin.copy(), colors)
    sources = np.concatenate([same, mid])
    stats = ManifoldStats(int(_pillows(mesh.triangles).sum()), int(flat.sum()), split, left, len(mid))
    return out, sources, stats


def _pillows(tris: np.ndarray) -> np.ndarray:
    """(T,) bool: pillows, matched one to one: of the triangles on one vertex set, as many in each cyclic order as
    the other order has (a triangle with no reversed partner, e.g. a plain duplicate, is kept)."""
    if len(tris) == 0:
        return np.zeros(0, dtype=bool)
    srt = np.sort(tris, axis=1)
    # cyclic order: even when the triangle is a rotation of (min, mid, max), odd when of (min, max, mid)
    rot = np.argmin(tris, axis=1)
    idx = np.arange(len(tris))
    odd = tris[idx, (rot + 1) % 3] != srt[:, 1]
    order = np.lexsort((odd, srt[:, 2], srt[:, 1], srt[:, 0]))
    s = srt[order]
    new_group = np.r_[True, (np.diff(s, axis=0) != 0).any(axis=1)]
    group = np.cumsum(new_group) - 1
    odd_sorted = odd[order]
    n_odd = np.bincount(group, weights=odd_sorted).astype(np.int64)
    n_even = np.bincount(group).astype(np.int64) - n_odd
    pairs = np.minimum(n_odd, n_even)
    # rank of each triangle among those of its group and order: the first ``pairs`` of each order are removed
    first_of_group = np.flatnonzero(new_group)
    pos = np.arange(len(s)) - first_of_group[group]
    rank = np.where(odd_sorted, pos - n_even[group], pos)  # evens come first in each group (lexsort on odd)
    out = np.zeros(len(tris), dtype=bool)
    out[order] = rank < pairs[group]
    return out


def _flat_tetrahedra(vertices: np.ndarray, tris: np.ndarray, keep: np.ndarray, bad_edges: np.ndarray) -> np.ndarray:
    """(T,) bool: the four triangles of each flat (zero-volume) closed tetrahedron hanging on a non-manifold edge.

    At a non-manifold edge (a, b), two triangles (a, b, c) and (b, a, d) of opposite directions lying in one half
    plane (coplanar flaps) close into a tetrahedron with the triangles on {a, c, d} and {b, c, d} when the four
    use each of their six edges once in each direction; its volume is zero (all four in one plane), so it is a
    sealed double layer. Removing all four keeps a closed mesh closed.
    """
    out = np.zeros(len(tris), dtype=bool)
    if len(bad_edges) == 0:
        return out
    # only triangles with two vertices among those of the triangles on the bad edges can close such a tetrahedron
    on_bad = np.isin(tris, np.unique(bad_edges)).sum(axis=1) >= 2
    near = np.unique(tris[keep & on_bad])
    rows = np.flatnonzero(keep & (np.isin(tris, near).sum(axis=1) >= 2))
    by_set: dict[tuple[int, ...], list[int]] = {}
    by_edge: dict[tuple[int, int], list[int]] = {}
    bad = {(int(a), int(b)) for a, b in bad_edges}
    for r in rows.tolist():
        t = tris[r]
        by_set.setdefault(tuple(sorted(t.tolist())), []).append(r)
        for i in range(3):
            e = (int(min(t[i], t[(i + 1) % 3])), int(max(t[i], t[(i + 1) % 3])))
            if e in bad:
                by_edge.setdefault(e, []).append(r)
    for (a, b), on_edge in by_edge.items():
        for r1 in on_edge:
            for r2 in on_edge:
                if r1 >= r2 or out[r1] or out[r2]:
                    continue
                c = int(tris[r1][~np.isin(tris[r1], [a, b])][0])
                d = int(tris[r2][~np.isin(tris[r2], [a, b])][0])
                if c == d:
                    continue
                r3 = by_set.get(tuple(sorted((a, c, d))), [])
                r4 = by_set.get(tuple(sorted((b, c, d))), [])
                for x in r3:
                    for y in r4:
                        group = [r1, r2, x, y]
                        if len(set(group)) == 4 and not out[group].any() and _sealed(tris[group], vertices):
                            out[group] = True
                            break
                    if out[r1]:
                        break
    return out


def _sealed(four: np.ndarray, vertices: np.ndarray) -> bool:
    """Four triangles that use each of their edges once in each direction and enclose no volume."""
    directed = np.concatenate([four[:, [0, 1]], four[:, [1, 2]], four[:, [2, 0]]])
    fwd = {tuple(e) for e in directed.tolist()}
    if len(fwd) != 12 or any((b, a) not in fwd for a, b in fwd):
        return False
    v = vertices[four]
    volume = abs(float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum())) / 6.0
    scale = float(np.ptp(v.reshape(-1, 3), axis=0).max())
    return volume <= 1e-9 * scale**3


def _wedge_pairs(vertices, tris, occ, tri_of, start, end) -> list[tuple[int, int]] | None:
    """Pairs of occurrences (along a → b, along b → a) that bound one wedge of solid around the edge, or None when
    the directions do not alternate around it."""
    a, b = int(min(start[occ[0]], end[occ[0]])), int(max(start[occ[0]], end[occ[0]]))
    pa, pb = vertices[a], vertices[b]
    u = pb - pa
    u = u / np.linalg.norm(u)
    helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    angles, forward = [], []
    for o in occ:
        tri = tris[tri_of[o]]
        c = int(tri[(~np.isin(tri, [a, b]))][0]) if np.isin(tri, [a, b]).sum() == 2 else -1
        if c < 0:
            return None
        w = vertices[c] - pa
        w = w - (w @ u) * u
        angles.append(np.arctan2(w @ e2, w @ e1))
        forward.append(start[o] == a)
    angles = np.round(np.asarray(angles), 9)  # coplanar flaps (a flat double layer) tie exactly
    forward = np.asarray(forward)
    n = len(occ)
    for ties_first in (True, False):  # of two triangles at one angle, either order may be the alternating one
        order = np.lexsort((forward if ties_first else ~forward, angles))
        fwd_sorted = [bool(forward[i]) for i in order]
        if n % 2 == 0 and all(fwd_sorted[i] != fwd_sorted[(i + 1) % n] for i in range(n)):
            break
    else:
        return None
    occ_sorted = [int(occ[i]) for i in order]
    # a triangle along a -> b has its normal towards increasing angle: the solid lies just below its angle, so it
    # pairs with the triangle before it (along b -> a)
    pairs = []
    for i in range(n):
        if fwd_sorted[i]:
            pairs.append((occ_sorted[i], occ_sorted[i - 1]))
    return pairs
