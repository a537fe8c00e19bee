"""Quadric-error decimation to a triangle budget, within a tolerance (default 1 %).

Two maintained decimators, both Garland–Heckbert quadric edge collapse: ``fast-simplification`` (Fast Quadric Mesh
Simplification, C++) and open3d's ``simplify_quadric_decimation``. Neither promises the exact count (an edge collapse
removes two triangles, some collapses are refused to keep the mesh valid, and open3d may stop early), so the target is
corrected from the count obtained, up to ``max_attempts`` runs, until the count lies within ``tolerance`` of the budget.
Degenerate triangles (repeated vertex, zero area), unused vertices and the few edges that collapses leave shared by more
than two triangles (fast-simplification leaves a few) are removed afterwards
(:func:`fusion.mesh.poisson.repair_non_manifold_edges`), before the count is judged.

``fast-simplification`` is several times faster, but on meshes with many boundary edges it can stall above the budget,
while open3d hits every budget. The default ``auto`` therefore runs fast-simplification and, when the count is still
outside the tolerance, goes on with open3d from fast-simplification's result (faster than open3d alone; figures in
docs/experiments/2026-11-27-domain-defaults.md); ``DecimationStats.method`` says which made the result
("fast-simplification+open3d" for the chain).

Documented behaviour at the edges: a budget < 1 is a :class:`ConfigError`; a budget at or above the input's
triangle count returns the input unchanged (no subdivision) with a :class:`MeshWarning`, and
``DecimationStats.decimated`` False.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from core.errors import ConfigError, DataError
from fusion.mesh.options import DecimateOptions, Decimator  # noqa: F401 (re-exported)
from fusion.mesh.poisson import repair_non_manifold_edges
from fusion.mesh.types import MeshWarning, TriangleMesh


@dataclass
class DecimationStats:
    """The decimator that made the result (``method``), budget, triangles before and after, attempts (over both
    decimators with ``auto``), triangles removed after decimation (degenerate or on non-manifold edges), seconds,
    and the verdict."""

    method: str
    budget: int
    triangles_in: int
    triangles_out: int
    attempts: int
    degenerate_removed: int
    seconds: float
    decimated: bool
    within_tolerance: bool


def remove_degenerate(mesh: TriangleMesh, min_area: float = 0.0) -> tuple[TriangleMesh, int]:
    """The mesh without triangles that repeat a vertex or have area <= ``min_area`` (m²), and unused vertices."""
    t = mesh.triangles
    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 0] == t[:, 2])
    bad = repeated | (mesh.triangle_areas() <= min_area)
    if not bad.any():
        return mesh, 0
    out = TriangleMesh(mesh.vertices, t[~bad], mesh.origin, mesh.vertex_colors).compact()
    return out, int(bad.sum())


def _run(mesh: TriangleMesh, target: int, method: Decimator, options: DecimateOptions) -> TriangleMesh:
    if method is Decimator.FAST_SIMPLIFICATION:
        import fast_simplification

        target = min(max(target, 1), mesh.num_triangles)
        pts, tris = fast_simplification.simplify(
            mesh.vertices, mesh.triangles.astype(np.int32), target_count=target, agg=options.aggressiveness
        )
        return TriangleMesh(pts, tris, mesh.origin.copy())
    import open3d as o3d

    o3m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.triangles.astype(np.int32))
    )
    out = o3m.simplify_quadric_decimation(target_number_of_triangles=int(max(target, 1)))
    return TriangleMesh(np.asarray(out.vertices), np.asarray(out.triangles), mesh.origin.copy())


def decimate(
    mesh: TriangleMesh, budget: int, options: DecimateOptions | None = None
) -> tuple[TriangleMesh, DecimationStats]:
    """Decimate ``mesh`` (local frame, any origin) to ``budget`` triangles within ``options.tolerance``.

    Vertex colours are dropped (decimation moves vertices; re-colour from the Gaussians afterwards). A result
    outside the tolerance after ``max_attempts`` runs is returned with a :class:`MeshWarning` giving the numbers.
    """
    options = options or DecimateOptions()
    if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) or budget < 1:
        raise ConfigError(f"the triangle budget must be a positive integer, got {budget!r}")
    budget = int(budget)
    t_in = mesh.num_triangles
    if t_in == 0:
        raise DataError("cannot decimate a mesh without triangles")
    start = time.perf_counter()
    if budget >= t_in:
        warnings.warn(
            f"the triangle budget {budget} is not below the mesh's {t_in} triangles: the mesh is kept as it is "
            "(decimation never adds triangles)",
            MeshWarning,
            stacklevel=2,
        )
        clean, degenerate = remove_degenerate(mesh)
        return clean, DecimationStats(
            options.method.value, budget, t_in, clean.num_triangles, 0, degenerate,
            time.perf_counter() - start, False, True,
        )  # fmt: skip
    lo, hi = budget * (1 - options.tolerance), budget * (1 + options.tolerance)
    methods = (
        [Decimator.FAST_SIMPLIFICATION, Decimator.OPEN3D] if options.method is Decimator.AUTO else [options.method]
    )
    best: tuple[float, TriangleMesh, int, str] | None = None
    attempts = 0
    for method in methods:
        target, previous = budget, -1
        source, label, carried = mesh, method.value, 0
        if best is not None and best[1].num_triangles > hi:
            # open3d goes on from where fast-simplification stalled: the same quadric collapse, on a far smaller mesh
            source, label, carried = best[1], f"{best[3]}+{method.value}", best[2]
        for _ in range(options.max_attempts):
            attempts += 1
            out, degenerate = remove_degenerate(_run(source, target, method, options))
            out, non_manifold = repair_non_manifold_edges(out)
            degenerate += non_manifold + carried
            count = out.num_triangles
            miss = abs(count - budget)
            if best is None or miss < best[0]:
                best = (miss, out, degenerate, label)
            if lo <= count <= hi:
                break
            new_target = int(min(source.num_triangles, max(1, target + (budget - count))))
            if new_target == target or count == previous:
                break  # the decimator does not move any further
            target, previous = new_target, count
        if lo <= best[1].num_triangles <= hi:  # type: ignore[index]
            break
    _, out, degenerate, used = best  # type: ignore[misc]  (the loops run at least once)
    ok = lo <= out.num_triangles <= hi
    if not ok:
        warnings.warn(
            f"{'/'.join(m.value for m in methods)} reached {out.num_triangles} triangles for a budget of {budget} "
            f"(tolerance {options.tolerance:.1%}) after {attempts} attempts",
            MeshWarning,
            stacklevel=2,
        )
    seconds = time.perf_counter() - start
    return out, DecimationStats(used, budget, t_in, out.num_triangles, attempts, degenerate, seconds, True, ok)
