"""A mesh with a triangle budget from a merged Gaussian set: the chain of :mod:`fusion.mesh` in one function.

1. oriented points from the merged Gaussians (:mod:`fusion.mesh.oriented_points`), optionally only the MVS ones,
   and only those whose ``surface`` field (written by the merge stage: splats whose centres pass a geometric test,
   :func:`fusion.clean.surface_splat_options`) is 1 when the set has one — the other splats are floaters, virtual
   images and colour corrections that render well but lie off every surface; or (``MeshSource.SURVEY``) one
   oriented point per point of the survey product (:mod:`fusion.mesh.survey_points`);
2. plus, for transparent / reflective regions, the points of the union of training snapshots with opacity 1
   (:mod:`fusion.mesh.transparent`);
3. screened Poisson, closed at its reconstruction cube (:mod:`fusion.mesh.closing`), cap removal, support and
   density trimming, small-piece removal (:mod:`fusion.mesh.poisson`);
4. decimation to the budget within 1 % (:mod:`fusion.mesh.decimate`);
5. vertex colours from the merged Gaussians' SH DC (:mod:`fusion.mesh.colors`).

Every step's counts and seconds come back in :class:`MeshResult`; the untrimmed and trimmed meshes are kept for
checks (watertight / edge-manifold, boundary edges in :class:`fusion.mesh.quality.MeshQuality`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from core.errors import DataError
from core.gaussians import GaussianSet
from core.pointcloud import PointCloud
from fusion.convert import Source
from fusion.mesh.closing import ClosingStats
from fusion.mesh.colors import vertex_colors_from_gaussians
from fusion.mesh.decimate import DecimationStats, decimate
from fusion.mesh.options import MeshOptions, MeshSource  # noqa: F401 (re-exported)
from fusion.mesh.oriented_points import OrientedPointStats, oriented_points_from_gaussians
from fusion.mesh.poisson import TrimStats, poisson_reconstruct, trim_mesh
from fusion.mesh.quality import MeshQuality, mesh_quality
from fusion.mesh.survey_points import oriented_points_from_survey
from fusion.mesh.transparent import SnapshotStats, snapshot_union
from fusion.mesh.types import OrientedPoints, TriangleMesh


@dataclass
class MeshTimings:
    """Seconds per step."""

    points: float = 0.0
    poisson: float = 0.0
    trim: float = 0.0
    decimate: float = 0.0
    colors: float = 0.0

    @property
    def total(self) -> float:
        return self.points + self.poisson + self.trim + self.decimate + self.colors


@dataclass
class MeshResult:
    """The final mesh (coloured, in the merged set's origin), the intermediate meshes, and every step's numbers."""

    mesh: TriangleMesh
    untrimmed: TriangleMesh
    untrimmed_is_cap: np.ndarray  # (T,) bool: the untrimmed mesh's caps on the Poisson cube (fusion.mesh.closing)
    trimmed: TriangleMesh
    points: OrientedPoints
    point_stats: OrientedPointStats | None  # None for a mesh of the survey product's points
    snapshot_stats: SnapshotStats | None
    snapshot_points: int
    splat_points_dropped_near_mvs: int
    off_surface_gaussians: int
    poisson_depth: int
    closing: ClosingStats | None
    trim_stats: TrimStats
    decimation: DecimationStats | None
    quality_untrimmed: MeshQuality
    quality_trimmed: MeshQuality
    quality: MeshQuality
    timings: MeshTimings

    def summary(self) -> dict[str, object]:
        """Counts for a manifest or a report (JSON-ready)."""
        out: dict[str, object] = {
            "oriented_points": len(self.points),
            "snapshot_points": self.snapshot_points,
            "splat_points_dropped_near_mvs": self.splat_points_dropped_near_mvs,
            "off_surface_gaussians": self.off_surface_gaussians,
            "poisson_depth": self.poisson_depth,
            "triangles_untrimmed": self.quality_untrimmed.triangles,
            "untrimmed_watertight": self.quality_untrimmed.watertight,
            "untrimmed_cap_triangles": self.closing.cap_triangles if self.closing else 0,
            "untrimmed_non_manifold_edges": self.quality_untrimmed.non_manifold_edges,
            "triangles_trimmed": self.quality_trimmed.triangles,
            "trimmed_edge_manifold": self.quality_trimmed.edge_manifold,
            "trimmed_boundary_edges": self.quality_trimmed.boundary_edges,
            "triangles": self.quality.triangles,
            "vertices": self.quality.vertices,
            "boundary_edges": self.quality.boundary_edges,
            "non_manifold_edges": self.quality.non_manifold_edges,
            "degenerate_triangles": self.quality.degenerate_triangles,
            "seconds": round(self.timings.total, 3),
        }
        if self.decimation is not None:
            out["budget"] = self.decimation.budget
            out["within_budget_tolerance"] = self.decimation.within_tolerance
        return out


def drop_splat_points_near_mvs(points: OrientedPoints, spacings: float) -> tuple[OrientedPoints, int]:
    """The points without splat points (source 2) closer to an MVS point (source 1) than ``spacings`` × the median
    nearest-neighbour distance of the MVS points; and how many were dropped. Unchanged without MVS or splat points."""
    from scipy.spatial import cKDTree

    from fusion.mesh.poisson import median_spacing

    is_mvs = points.source == Source.MVS
    is_splat = points.source == Source.SPLAT
    if is_mvs.sum() < 2 or not is_splat.any():
        return points, 0
    mvs = points.positions[is_mvs]
    radius = spacings * median_spacing(mvs)
    d, _ = cKDTree(mvs).query(points.positions[is_splat], k=1, distance_upper_bound=radius)
    near = np.zeros(len(points), dtype=bool)
    near[np.flatnonzero(is_splat)[np.isfinite(d)]] = True
    return points.subset(~near), int(near.sum())


def mesh_from_gaussians(
    merged: GaussianSet,
    options: MeshOptions | None = None,
    snapshots: Sequence[GaussianSet] = (),
    viewpoints: np.ndarray | None = None,
    survey_points: PointCloud | None = None,
) -> MeshResult:
    """A coloured triangle mesh of ``merged`` (see the module docstring), in ``merged``'s local frame and origin.

    merged: the merged Gaussians with a ``source`` field (1 MVS, 2 splat; needed for MeshSource.MVS and snapshots).
    snapshots: early training snapshots (3DGS sets of the same run); only their parts in splat regions are used.
    viewpoints: (M, 3) float64 camera centres relative to ``merged.origin`` (orient splat normals), or None.
    survey_points: the survey point product (``MeshSource.SURVEY`` meshes it instead of the Gaussians; the
    Gaussians still colour the mesh).
    """
    options = options or MeshOptions()
    timings = MeshTimings()
    t = time.perf_counter()
    points, point_stats, off_surface, regions = _oriented_points(merged, options, viewpoints, survey_points)
    snap_stats = None
    n_snap = 0
    if snapshots and options.use_snapshots and options.source is not MeshSource.MVS:
        points, snap_stats, n_snap = _add_snapshot_points(points, snapshots, regions, options, viewpoints)
    dropped_near_mvs = 0
    if options.mvs_priority > 0:
        points, dropped_near_mvs = drop_splat_points_near_mvs(points, options.mvs_priority)
    timings.points = time.perf_counter() - t

    t = time.perf_counter()
    result = poisson_reconstruct(points, options.poisson)
    timings.poisson = time.perf_counter() - t
    t = time.perf_counter()
    trimmed, trim_stats = trim_mesh(result, options.poisson)
    timings.trim = time.perf_counter() - t

    t = time.perf_counter()
    final = trimmed
    dec = None
    if options.budget is not None:
        final, dec = decimate(trimmed, int(options.budget), options.decimate)
    timings.decimate = time.perf_counter() - t

    t = time.perf_counter()
    colors = vertex_colors_from_gaussians(final.vertices, final.origin, merged, k=options.color_neighbors)
    final = TriangleMesh(final.vertices, final.triangles, final.origin, colors)
    timings.colors = time.perf_counter() - t
    return MeshResult(
        mesh=final,
        untrimmed=result.mesh,
        untrimmed_is_cap=result.is_cap,
        trimmed=trimmed,
        points=points,
        point_stats=point_stats,
        snapshot_stats=snap_stats,
        snapshot_points=n_snap,
        splat_points_dropped_near_mvs=dropped_near_mvs,
        off_surface_gaussians=off_surface,
        poisson_depth=result.depth,
        closing=result.closing,
        trim_stats=trim_stats,
        decimation=dec,
        quality_untrimmed=mesh_quality(result.mesh),
        quality_trimmed=mesh_quality(trimmed),
        quality=mesh_quality(final),
        timings=timings,
    )


def _oriented_points(
    merged: GaussianSet, options: MeshOptions, viewpoints: np.ndarray | None, survey_points: PointCloud | None
) -> tuple[OrientedPoints, OrientedPointStats | None, int, GaussianSet]:
    """The oriented points the mesh is made of, their stats (None for survey points), how many Gaussians were off
    every surface, and the Gaussians whose splats (``source`` 2) mark the regions training snapshots may fill."""
    if options.source is MeshSource.SURVEY:
        if survey_points is None:
            raise DataError("a mesh from the survey product needs its points (export/merged_points.ply)")
        cloud = survey_points.with_origin(merged.origin)
        regions, off_surface = _gaussians_to_mesh(merged, replace(options, source=MeshSource.ALL))
        return oriented_points_from_survey(cloud, options.points, viewpoints), None, off_surface, regions
    gs, off_surface = _gaussians_to_mesh(merged, options)
    points, stats = oriented_points_from_gaussians(gs, options.points, viewpoints)
    return points, stats, off_surface, gs


def _gaussians_to_mesh(merged: GaussianSet, options: MeshOptions) -> tuple[GaussianSet, int]:
    """The Gaussians whose geometry is meshed (``surface_only``, ``source``) and how many were off every surface."""
    gs = merged
    off_surface = 0
    if options.surface_only and "surface" in merged.fields:
        on = np.asarray(merged.fields["surface"]) > 0.5
        off_surface = int((~on).sum())
        if not on.any():
            raise DataError(f"no Gaussian of the merged set (of {len(merged)}) has surface = 1: nothing to mesh")
        gs = merged.subset(on)
    if options.source is MeshSource.MVS:
        if "source" not in merged.fields:
            raise DataError("an MVS-only mesh needs the merged set's 'source' field (1 = MVS, 2 = splat)")
        is_mvs = np.asarray(gs.fields["source"]) == Source.MVS
        if not is_mvs.any():
            raise DataError(f"the merged set holds no MVS Gaussians (of {len(merged)}): nothing to mesh MVS-only")
        gs = gs.subset(is_mvs)
    return gs, off_surface


def _add_snapshot_points(
    points: OrientedPoints,
    snapshots: Sequence[GaussianSet],
    gs: GaussianSet,
    options: MeshOptions,
    viewpoints: np.ndarray | None,
) -> tuple[OrientedPoints, SnapshotStats, int]:
    """``points`` plus the oriented points of the snapshot union in splat regions (full weight), its stats and how
    many points it added."""
    union, snap_stats = snapshot_union(snapshots, gs, options.snapshots)
    n_snap = 0
    if len(union):
        extra, _ = oriented_points_from_gaussians(
            union, options.points, viewpoints, weight_override=np.ones(len(union))
        )
        extra.gaussian_index[:] = -1  # indices into the snapshot union, not into ``merged``
        n_snap = len(extra)
        points = OrientedPoints.concatenate([points, extra])
    return points, snap_stats, n_snap
