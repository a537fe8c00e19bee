"""Stage ``mesh``: a triangle mesh with a polygon budget from the merged product (export/mesh.ply|obj|glb).

Reads export/merged.ply (the ``source`` field from export/merged_points.ply when the 3DGS PLY carries none), the
training snapshots in splats/snapshots/ (for transparent and reflective regions) and the cameras in sparse/ (a local
frame at the origin recorded in logs/sfm.json; to orient splat normals); calls
:func:`fusion.mesh.pipeline.mesh_from_gaussians` (or TSDF fusion of rendered depth with ``method = "tsdf"``) and writes
each format through :func:`fusion.mesh.export.write_mesh`, with the origin sidecar export/mesh.origin.json (always
written, zeros included). Skipped unless a budget is set (``run --mesh N``, ``hybridsplat mesh PROJECT --budget N``).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from enum import Enum
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from core.constraints import Choice, Constrained, Constraints, Interval, SequenceOf
from core.errors import DataError
from fusion.mesh.options import MeshOptions, MeshSource
from hybridsplat.layout import MESH_FORMATS
from hybridsplat.project_io import sparse_model
from hybridsplat.stages import sizes
from hybridsplat.stages.base import CliOption, Stage, StageContext, StageResult, omitted_if_none

_MESH_BYTES = {"ply": (16, 13), "obj": (128, 38), "glb": (28, 12)}  # upper bytes per (vertex, triangle), per format


class MeshMethod(str, Enum):
    """How the mesh is made: screened Poisson of oriented points from the Gaussians, or TSDF fusion of depth rendered
    from the merged Gaussians at the project's cameras."""

    POISSON = "poisson"
    TSDF = "tsdf"


@dataclass(frozen=True)
class MeshStageOptions(Constrained):
    """Options of the ``mesh`` stage.

    budget: triangles of the mesh (0: no mesh, the stage is skipped); within 1 % unless the raw mesh is smaller.
    formats: files written under export/ (any of ply, obj, glb). method: :class:`MeshMethod`.
    mesh: the meshing options (:class:`fusion.mesh.MeshOptions`, ``[mesh.mesh]``: which Gaussians, training
    snapshots for the splat regions, decimator...); its budget is the one above.
    """

    budget: int = 0
    formats: tuple[str, ...] = MESH_FORMATS
    method: MeshMethod = MeshMethod.POISSON
    mesh: MeshOptions = field(default_factory=MeshOptions, metadata={"runtime": ("budget",)})

    constraints: ClassVar[Constraints] = {
        "budget": Interval(int, 0, None),
        "formats": SequenceOf(Choice(MESH_FORMATS), min_length=1),
        "method": Choice(MeshMethod),
    }


@dataclass(frozen=True)
class MeshResult(StageResult):
    """What the mesh stage made: a mesh of ``triangles`` triangles and ``vertices`` vertices, its boundary,
    non-manifold and degenerate edges / triangles, the ``budget`` asked for and whether it is within the
    decimation's tolerance of it, the ``method``, the training ``snapshots`` read, the ``formats`` written and the
    meshing's ``warnings`` (one line each).

    Poisson (the counts of :meth:`fusion.mesh.pipeline.MeshResult.summary`): the oriented points and those from the
    snapshots, the splat points dropped near MVS points, the off-surface Gaussians, the Poisson depth, the
    untrimmed mesh (triangles, watertight, cap triangles, non-manifold edges) and the trimmed one (triangles,
    edge-manifold, boundary edges), and its seconds. TSDF: the triangles before decimation (``triangles_raw``)."""

    oriented_points: int | None = omitted_if_none()
    snapshot_points: int | None = omitted_if_none()
    splat_points_dropped_near_mvs: int | None = omitted_if_none()
    off_surface_gaussians: int | None = omitted_if_none()
    poisson_depth: int | None = omitted_if_none()
    triangles_untrimmed: int | None = omitted_if_none()
    untrimmed_watertight: bool | None = omitted_if_none()
    untrimmed_cap_triangles: int | None = omitted_if_none()
    untrimmed_non_manifold_edges: int | None = omitted_if_none()
    triangles_trimmed: int | None = omitted_if_none()
    trimmed_edge_manifold: bool | None = omitted_if_none()
    trimmed_boundary_edges: int | None = omitted_if_none()
    triangles_raw: int | None = omitted_if_none()
    triangles: int = 0
    vertices: int = 0
    boundary_edges: int = 0
    non_manifold_edges: int = 0
    degenerate_triangles: int = 0
    seconds: float | None = omitted_if_none()
    budget: int | None = omitted_if_none()
    within_budget_tolerance: bool | None = omitted_if_none()
    method: str = ""
    snapshots: int = 0
    formats: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()


class MeshStage(Stage):
    name = "mesh"
    Options = MeshStageOptions
    Result = MeshResult
    title = "mesh with a polygon budget"
    command = "mesh"
    command_help = "A triangle mesh with a polygon budget from the merged product: PROJECT/export/mesh.ply, .obj, .glb."
    command_options = (
        CliOption("budget", help="Triangles of the mesh (within 1 %)."),
        CliOption("formats", "--format", help="ply | obj | glb (repeatable; default: all three)."),
        CliOption("method", help="poisson (default) | tsdf (fusion of rendered depth)."),
        CliOption(
            "mesh.source",
            help="all (hybrid Gaussians, default) | mvs (MVS Gaussians only) | survey (the survey "
            "points: MVS, trustworthy splats).",
        ),
        CliOption(
            "mesh.use_snapshots", "--snapshots/--no-snapshots", help="Use training snapshots for transparent regions."
        ),
        CliOption("mesh.decimate.method", "--decimator", help="auto (default) | fast-simplification | open3d."),
    )
    run_options = (CliOption("budget", "--mesh", help="Also write a mesh with this many triangles (0: no mesh)."),)

    def inputs(self, ctx: StageContext) -> list[Path]:
        layout = ctx.layout
        layers = [p for p in (layout.cleaned_splats, layout.background_splats) if p.is_file()]  # as trained
        return [layout.merged_ply, layout.merged_points_ply, layout.mvs_gaussians, *layers, layout.snapshots_dir,
                sparse_model(layout), layout.record("sfm")]  # fmt: skip

    def outputs(self, ctx: StageContext) -> list[Path]:
        from core.io.origin import sidecar_path

        opts: MeshStageOptions = ctx.options(self)
        paths = [ctx.layout.mesh_path(f) for f in opts.formats]
        return [*paths, sidecar_path(ctx.layout.mesh_path("ply"))]

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of the mesh files for T = ``budget`` × (1 + the decimation tolerance) triangles and at most 3T
        vertices: PLY 16 bytes a vertex (xyz float32, RGBA) and 13 a triangle; OBJ 128 characters a vertex (6
        ``%.8f`` numbers) and 38 a triangle; GLB 28 bytes a vertex (position, normal, RGBA) and 12 a triangle; each
        with 4 KiB of header; the origin sidecar and the log (64 KiB)."""
        opts: MeshStageOptions = ctx.options(self)
        triangles = math.ceil(opts.budget * (1 + opts.mesh.decimate.tolerance))
        per_format = [_MESH_BYTES[f] for f in opts.formats]
        files = sum(triangles * (3 * vertex + face) + 4 * sizes.KIB for vertex, face in per_format)
        return files + sizes.SIDECAR_BYTES + sizes.LOG_BYTES

    def needs(self, ctx: StageContext) -> str | None:
        opts: MeshStageOptions = ctx.options(self)
        if opts.budget == 0:
            return "no mesh asked for (run --mesh BUDGET, or hybridsplat mesh PROJECT --budget N)"
        return None

    def run(self, ctx: StageContext) -> MeshResult:
        from core.io.gaussian_ply import read_gaussian_ply
        from core.io.origin import write_origin
        from fusion.mesh import MeshWarning, mesh_from_gaussians, write_mesh
        from hybridsplat.project_io import read_project_model

        opts: MeshStageOptions = ctx.options(self)
        layout = ctx.layout
        merged = load_merged_with_source(layout.merged_ply, layout.merged_points_ply)
        if layout.mvs_gaussians.is_file():  # every layer as before the appearance stage: that is for viewers
            from hybridsplat.project_io import unrefined_layers

            merged = unrefined_layers(layout, merged)
        cameras = None
        if sparse_model(layout).is_dir():
            cameras = read_project_model(layout, sparse_model(layout))[0]
        snapshots = []
        if opts.mesh.use_snapshots and layout.snapshots_dir.is_dir():
            snapshots = [read_gaussian_ply(p) for p in sorted(layout.snapshots_dir.glob("*.ply"))]
        ctx.progress("mesh", 0, 1)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MeshWarning)
            if opts.method is MeshMethod.TSDF:
                mesh, made = _tsdf(merged, cameras, opts)
            else:
                viewpoints = None
                if cameras is not None and len(cameras):
                    viewpoints = np.array([v.center for v in cameras]) + cameras.origin - merged.origin
                options = replace(opts.mesh, budget=opts.budget)
                survey = None
                if options.source is MeshSource.SURVEY:
                    from core.io.ply import read_ply

                    survey = read_ply(layout.merged_points_ply)
                result = mesh_from_gaussians(merged, options, snapshots=snapshots, viewpoints=viewpoints,
                                             survey_points=survey)  # fmt: skip
                mesh, made = result.mesh, MeshResult(**result.summary())
        for fmt in opts.formats:
            write_mesh(layout.mesh_path(fmt), mesh)
        # the sidecar is written even for a zero origin (an output of the stage, and it carries the CRS)
        write_origin(layout.mesh_path("ply"), mesh.origin, ctx.config.input.crs or None)
        ctx.progress("mesh", 1, 1)
        return replace(
            made,
            method=opts.method.value,
            snapshots=len(snapshots),
            formats=opts.formats,
            warnings=tuple(" ".join(str(w.message).split()) for w in caught),
        )

    def summary(self, result: MeshResult) -> str:
        return f"{result.triangles} triangles ({result.method}), {', '.join(result.formats)}"


def load_merged_with_source(merged_ply: Path, points_ply: Path):  # -> GaussianSet
    """The merged Gaussians of the survey and fill layers with their ``source`` field (the background layer is no
    surface to mesh): from the 3DGS PLY's extra fields, else from the points file the merge stage writes next to it
    (same Gaussians, same order: checked by count and position)."""
    from core.io.gaussian_ply import read_gaussian_ply
    from core.io.ply import read_ply
    from fusion.convert_options import Source

    merged = read_gaussian_ply(merged_ply)
    if "source" in merged.fields:
        merged.fields["source"] = np.asarray(merged.fields["source"]).astype(np.uint8)
        return merged.subset(merged.fields["source"] != Source.BACKGROUND)
    if not points_ply.is_file():
        raise DataError("the merged Gaussians carry no 'source' field and there is no points file next to them",
                        merged_ply)  # fmt: skip
    points = read_ply(points_ply)
    same = len(points) == len(merged) and (
        len(points) == 0 or float(np.abs(points.world_positions - merged.world_means).max()) < 1e-4
    )
    if not same or "source" not in points.fields:
        raise DataError(f"does not match {merged_ply.name} point for point, or has no 'source' field", points_ply)
    merged.fields["source"] = np.asarray(points.fields["source"]).astype(np.uint8)
    return merged


def _tsdf(merged, cameras, opts: MeshStageOptions) -> tuple[Any, MeshResult]:  # (TriangleMesh, its counts)
    from fusion.convert import Source
    from fusion.mesh import mesh_quality
    from fusion.mesh.colors import vertex_colors_from_gaussians
    from fusion.mesh.decimate import decimate
    from fusion.mesh.tsdf import tsdf_mesh
    from fusion.mesh.types import TriangleMesh

    if cameras is None or len(cameras) == 0:
        raise DataError("TSDF meshing renders at the project's cameras, and sparse/ holds none")
    gs = merged if opts.mesh.source is MeshSource.ALL else merged.subset(merged.fields["source"] == Source.MVS)
    raw = tsdf_mesh(gs, cameras)
    mesh, st = decimate(raw, opts.budget, opts.mesh.decimate)
    mesh = TriangleMesh(mesh.vertices, mesh.triangles, mesh.origin,
                        vertex_colors_from_gaussians(mesh.vertices, mesh.origin, merged))  # fmt: skip
    q = mesh_quality(mesh)
    return mesh, MeshResult(
        triangles_raw=raw.num_triangles,
        triangles=q.triangles,
        vertices=q.vertices,
        boundary_edges=q.boundary_edges,
        non_manifold_edges=q.non_manifold_edges,
        degenerate_triangles=q.degenerate_triangles,
        budget=opts.budget,
        within_budget_tolerance=st.within_tolerance,
    )
