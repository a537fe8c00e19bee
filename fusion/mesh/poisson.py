"""Screened Poisson reconstruction (open3d, Kazhdan & Hoppe 2013), low-density trimming, small-piece removal.

The untrimmed Poisson surface is the zero set of an implicit function over the whole octree: closed (watertight)
around closed samplings, but it bulges over regions no point supports, and around open scenes (a ground plane) it
runs into the reconstruction cube and is cut open there (open3d's PoissonRecon uses Neumann boundary conditions; no
option of open3d changes that). With ``close`` (default) the cut is closed by caps on the cube's faces
(:mod:`fusion.mesh.closing`): the untrimmed mesh is then the watertight boundary of the solid {inside} ∩ cube (after
the non-manifold edges PoissonRecon emits are repaired without opening it, :mod:`fusion.mesh.manifold`).
Trimming removes the caps, then two kinds of vertices, and the triangles that use them: those whose Poisson density
(the kernel density of the samples at the vertex, open3d's second return value) is below the ``density_quantile`` of
all vertex densities (the usual low-density trim), and those farther than ``support_factor`` × the spacing at their
nearest oriented point from it (surface that no sample supports: Poisson's bridges over holes; a quantile alone
cannot tell a hole from a well-sampled closed surface, where it would cut the lowest few percent regardless). The
spacing at a point is the larger of its local spacing (the median nearest-neighbour distance over the point and
its ``support_neighbors`` nearest others) and that median over all points: a hybrid cloud mixes sparse MVS surfels
with dense splat and snapshot samples, and one global spacing from the dense part trimmed away most of the MVS
surface (see docs/experiments/2026-11-27-domain-defaults.md). Edges
shared by more than two triangles (PoissonRecon's iso-surface extraction emits a few at fine depths) are repaired
with open3d's ``remove_non_manifold_edges`` (drops the smallest of the triangles on such an edge until two are
left), so the trimmed mesh is edge-manifold. Pieces that are left with fewer triangles than
``min_component_fraction`` of the whole are then dropped (floaters, extrapolated blobs).

Depth: the octree depth follows the sampling (``depth`` None): the finest cell is ``cell_factor`` × the median
nearest-neighbour distance of the points, so depth = ceil(log2(1.1 · extent / cell)), clamped to
[``min_depth``, ``max_depth``] (depth 10 ≈ 1024³ cells at most, memory grows about 4× per level on surfaces).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from core.errors import DataError
from fusion.mesh.closing import ClosingStats, close_at_cube, poisson_cube
from fusion.mesh.graph import edge_use_counts, triangle_components
from fusion.mesh.manifold import ManifoldStats, make_edge_manifold
from fusion.mesh.options import PoissonOptions  # noqa: F401 (re-exported)
from fusion.mesh.types import OrientedPoints, TriangleMesh


@dataclass
class PoissonResult:
    """The untrimmed mesh (vertex colours interpolated by open3d from the points' colours; closed with caps when
    ``PoissonOptions.close``), its per-vertex densities (V,) float64 (0 at added cube corners), the depth used, the
    distance (V,) float64 metres from each vertex to the nearest oriented point, the median point spacing (metres),
    the spacing (V,) float64 metres at each vertex's nearest point (its local spacing, at least the median),
    a (T,) bool mask of the cap triangles, the (S, 3) int64 triangles open3d returned (indices into ``mesh.vertices``:
    before the manifold repair, whose pillows and flat tetrahedra can be thin real surface, and without caps; what
    trimming starts from), the closing's stats (None without ``close``), the manifold repair's stats
    (None without ``manifold``), a (V,) bool mask of the
    vertices within the footprint of some point (all False without ``footprint_support``), and the
    reconstruction cube's corners lo, hi (3,) float64 in the mesh's local frame."""

    mesh: TriangleMesh
    densities: np.ndarray
    depth: int
    support_distance: np.ndarray
    point_spacing: float
    support_spacing: np.ndarray
    is_cap: np.ndarray
    surface_triangles: np.ndarray
    closing: ClosingStats | None
    manifold: ManifoldStats | None
    footprint_supported: np.ndarray
    cube_lo: np.ndarray
    cube_hi: np.ndarray


@dataclass
class TrimStats:
    """Triangles open3d returned (what trimming starts from), the closed mesh's caps left out (see
    :mod:`fusion.mesh.closing`), triangles removed by the density cut, by the support cut, on non-manifold edges, as
    small pieces, after; pieces kept / dropped; the density threshold and the
    median support distance (metres) used."""

    triangles_in: int
    removed_caps: int
    removed_low_density: int
    removed_unsupported: int
    removed_non_manifold: int
    removed_small_pieces: int
    triangles_out: int
    pieces_kept: int
    pieces_dropped: int
    density_threshold: float
    support_distance: float


def median_spacing(points: np.ndarray, max_sample: int = 200_000) -> float:
    """Median nearest-neighbour distance (metres) of (N, 3) points, from a regular subsample of at most
    ``max_sample`` points (thinning by f on a surface widens spacings by about √f, which is divided out)."""
    sample = points if len(points) <= max_sample else points[:: len(points) // max_sample + 1]
    d, _ = cKDTree(sample).query(sample, k=2)
    spacing = float(np.median(d[:, 1]))
    if len(sample) < len(points):
        spacing /= math.sqrt(len(points) / len(sample))
    return spacing


def auto_depth(points: np.ndarray, options: PoissonOptions, spacing: float | None = None) -> int:
    """Octree depth for (N, 3) points: finest cell = cell_factor × median nearest-neighbour distance."""
    extent = float(np.max(points.max(axis=0) - points.min(axis=0)))
    spacing = median_spacing(points) if spacing is None else spacing
    if not (spacing > 0 and extent > 0):
        return options.min_depth
    depth = math.ceil(math.log2(options.scale * extent / (options.cell_factor * spacing)))
    return int(min(max(depth, options.min_depth), options.max_depth))


def poisson_reconstruct(points: OrientedPoints, options: PoissonOptions | None = None) -> PoissonResult:
    """Screened Poisson surface of oriented points (local frame; the mesh keeps ``points.origin``).

    Raises :class:`DataError` for fewer than 4 points, non-finite values, or points spanning no volume-worthy extent
    (all coincident), and when open3d returns no triangle.
    """
    import open3d as o3d

    options = options or PoissonOptions()
    n = len(points)
    if n < 4:
        raise DataError(f"screened Poisson needs at least 4 oriented points, got {n}")
    if not (np.isfinite(points.positions).all() and np.isfinite(points.normals).all()):
        raise DataError("oriented points hold NaN or infinite positions or normals")
    lengths = np.linalg.norm(points.normals, axis=1)
    if (lengths < 1e-6).any():
        raise DataError(f"{int((lengths < 1e-6).sum())} oriented points have no normal (zero length)")
    extent = points.positions.max(axis=0) - points.positions.min(axis=0)
    if float(extent.max()) <= 0:
        raise DataError(f"all {n} points coincide: there is no surface to reconstruct")
    spread = np.linalg.svd(points.positions - points.positions.mean(axis=0), compute_uv=False)
    if spread[1] <= 1e-9 * spread[0]:
        raise DataError(f"all {n} points lie on one line: there is no surface to reconstruct")
    spacing = median_spacing(points.positions)
    depth = options.depth if options.depth is not None else auto_depth(points.positions, options, spacing)
    # centre before open3d: it works in float32 internally, so coordinates must be small
    centre = points.positions.mean(axis=0)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.positions - centre))
    pcd.normals = o3d.utility.Vector3dVector(points.normals / lengths[:, None])
    pcd.colors = o3d.utility.Vector3dVector(points.colors.astype(np.float64))
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            pcd,
            depth=int(depth),
            scale=float(options.scale),
            linear_fit=bool(options.linear_fit),
            n_threads=int(options.threads),
            point_weight=float(options.point_weight),
        )
    tris = np.asarray(mesh.triangles, dtype=np.int64)
    if len(tris) == 0:
        raise DataError(f"screened Poisson returned no surface from {n} points (depth {depth})")
    verts = np.asarray(mesh.vertices, dtype=np.float64) + centre
    colors = np.clip(np.asarray(mesh.vertex_colors, dtype=np.float64), 0.0, 1.0) if mesh.has_vertex_colors() else None
    out = TriangleMesh(verts, tris, points.origin.copy(), colors)
    densities = np.asarray(dens, dtype=np.float64)
    surface_triangles = tris.copy()  # repair and closing only append vertices: these indices stay valid
    manifold = None
    if options.manifold:
        out, sources, manifold = make_edge_manifold(out)
        densities = densities[sources].mean(axis=1)
    lo, hi = poisson_cube(points.positions, options.scale)
    is_cap = np.zeros(len(tris), dtype=bool)
    closing = None
    if options.close:
        # open3d's vertices are float32 round-off (~1e-7 of the cube) off the cube: snap within a hundredth of the
        # finest cell, far below any vertex spacing
        side = float(hi[0] - lo[0])
        out, is_cap, closing = close_at_cube(out, lo, hi, snap_tolerance=min(1e-5, 0.01 / 2**depth) * side)
        densities = np.concatenate([densities, np.zeros(len(out.vertices) - len(densities))])
    tree = cKDTree(points.positions)
    support, nearest = tree.query(out.vertices, k=1)
    k = min(options.support_neighbors, n - 1)
    d, idx = tree.query(points.positions, k=k + 1)
    nearest_other = np.asarray(d).reshape(n, k + 1)[:, 1]
    local = np.maximum(np.median(nearest_other[np.asarray(idx).reshape(n, k + 1)], axis=1), spacing)
    in_footprint = np.zeros(len(out.vertices), dtype=bool)
    if options.footprint_support:
        in_footprint = within_footprints(out.vertices, points.positions, points.footprint)
    return PoissonResult(
        out, densities, int(depth), support, spacing, local[nearest], is_cap, surface_triangles, closing, manifold,
        in_footprint, lo, hi,
    )  # fmt: skip


def within_footprints(vertices: np.ndarray, centres: np.ndarray, radii: np.ndarray, chunk: int = 50_000) -> np.ndarray:
    """(V,) bool: vertex v lies within radius r_j of some centre c_j (|v − c_j| <= r_j). vertices (V, 3), centres
    (N, 3) float64 metres in one frame, radii (N,) metres (<= 0: none); exact (a ball query per centre)."""
    out = np.zeros(len(vertices), dtype=bool)
    has = np.flatnonzero(radii > 0)
    if len(has) == 0 or len(vertices) == 0:
        return out
    tree = cKDTree(vertices)
    for start in range(0, len(has), chunk):
        rows = has[start : start + chunk]
        hits = tree.query_ball_point(centres[rows], r=radii[rows], return_sorted=False)
        flat = [h for h in hits if h]
        if flat:
            out[np.concatenate(flat).astype(np.int64)] = True
    return out


def trim_mesh(result: PoissonResult, options: PoissonOptions | None = None) -> tuple[TriangleMesh, TrimStats]:
    """Density and support trimming of open3d's surface (``result.surface_triangles``: no caps, pillows kept),
    non-manifold edge repair, then small-piece removal (module docstring); unused vertices are removed."""
    options = options or PoissonOptions()
    mesh = TriangleMesh(result.mesh.vertices, result.surface_triangles, result.mesh.origin, result.mesh.vertex_colors)
    t0 = mesh.num_triangles
    keep_tri = np.ones(mesh.num_triangles, dtype=bool)
    removed_caps = int(result.is_cap.sum())
    # the quantile over the surface's own vertices (cap corners carry no density)
    surface_vertices = np.unique(mesh.triangles[keep_tri])
    threshold = (
        float(np.quantile(result.densities[surface_vertices], options.density_quantile))
        if options.density_quantile
        else -np.inf
    )
    low = result.densities < threshold
    removed_low = int((keep_tri & low[mesh.triangles].any(axis=1)).sum())
    keep_tri &= ~low[mesh.triangles].any(axis=1)
    max_support = options.support_factor * result.support_spacing if options.support_factor else np.inf
    far = (result.support_distance > max_support) & ~result.footprint_supported
    keep_support = ~far[mesh.triangles].any(axis=1)
    removed_far = int((keep_tri & ~keep_support).sum())
    keep_tri &= keep_support
    if not keep_tri.any():
        raise DataError(
            f"trimming (density quantile {options.density_quantile}, support {options.support_factor} spacings) "
            "removed every triangle"
        )
    trimmed = TriangleMesh(mesh.vertices, mesh.triangles[keep_tri], mesh.origin, mesh.vertex_colors).compact()
    trimmed, removed_nm = repair_non_manifold_edges(trimmed)
    labels = triangle_components(trimmed.triangles, len(trimmed.vertices))
    sizes = np.bincount(labels)
    small = sizes < options.min_component_fraction * len(labels)
    keep = ~small[labels]
    out = TriangleMesh(trimmed.vertices, trimmed.triangles[keep], trimmed.origin, trimmed.vertex_colors).compact()
    stats = TrimStats(
        triangles_in=t0,
        removed_caps=removed_caps,
        removed_low_density=removed_low,
        removed_unsupported=removed_far,
        removed_non_manifold=removed_nm,
        removed_small_pieces=int((~keep).sum()),
        triangles_out=out.num_triangles,
        pieces_kept=int((~small).sum()),
        pieces_dropped=int(small.sum()),
        density_threshold=threshold,
        support_distance=float(np.median(max_support)),
    )
    return out, stats


def repair_non_manifold_edges(mesh: TriangleMesh) -> tuple[TriangleMesh, int]:
    """The mesh with no edge used by more than two triangles (open3d's repair; see the module docstring) and the
    number of triangles removed; the mesh itself when it is already edge-manifold."""
    import open3d as o3d

    _, counts = edge_use_counts(mesh.triangles)
    if not (counts > 2).any():
        return mesh, 0
    o3m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.triangles.astype(np.int32))
    )
    if mesh.vertex_colors is not None:
        o3m.vertex_colors = o3d.utility.Vector3dVector(mesh.vertex_colors.astype(np.float64))
    o3m.remove_non_manifold_edges()
    tris = np.asarray(o3m.triangles, dtype=np.int64)
    # open3d keeps the vertex array as it is: same indices, so colours still line up
    out = TriangleMesh(mesh.vertices, tris, mesh.origin, mesh.vertex_colors).compact()
    return out, mesh.num_triangles - len(tris)
