"""Geometry evaluation of one product: read, (optionally) register, measure C2C or C2M, write the outputs.

Outputs in ``out_dir`` (the project's ``eval/``): ``c2c_<name>.ply`` and ``.las`` (the compared cloud with a
``c2c`` scalar field, metres), ``plots/c2c_<name>_hist.svg`` and ``plots/c2c_<name>_preview.png``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import ConfigError
from core.io import read_point_cloud, write_point_cloud
from core.io.atomic import write_text_atomic
from core.io.images import write_image
from core.pointcloud import PointCloud
from eval.c2c import C2CResult, compare_clouds
from eval.c2m import Mesh, compare_cloud_to_mesh, is_mesh_file, read_mesh
from eval.metrics_io import C2CSummary
from eval.plots import preview_image, svg_histogram
from eval.registration import icp_point_to_plane


@dataclass(frozen=True)
class GeometryOptions:
    """C2C options. Distances in metres.

    max_dist: points farther than this are outliers (counted, excluded from the statistics).
    tau: threshold for completeness / precision / recall / F-score (C2C only).
    icp_max_correspondence: run point-to-plane ICP first with this correspondence distance (off when None).
    write_las: also write the LAS copy of the compared cloud with its ``c2c`` field.
    memory_limit_mb: with a reference cloud given as a file, read it in chunks and measure within about this peak
    memory (MiB; :mod:`eval.geometry_stream`, the same figures); None reads it whole. Not with ICP.
    """

    max_dist: float | None = None
    tau: float | None = None
    icp_max_correspondence: float | None = None
    write_las: bool = True
    class_field: str = "classification"
    memory_limit_mb: float | None = None

    def __post_init__(self) -> None:
        if self.memory_limit_mb is not None:
            from eval.c2c_stream import plan_c2c_memory

            plan_c2c_memory(self.memory_limit_mb)  # a ConfigError naming the value
            if self.icp_max_correspondence is not None:
                raise ConfigError("ICP registration needs the reference in memory: leave memory_limit_mb unset")


def load_reference(path: str | PathLike[str]) -> PointCloud | Mesh:
    """A reference: :class:`eval.c2m.Mesh` for mesh files, :class:`PointCloud` otherwise."""
    return read_mesh(path) if is_mesh_file(path) else read_point_cloud(path)


@dataclass(frozen=True)
class Measurement:
    """What :func:`measure` did.

    result: distances and statistics; measured: the compared cloud as measured (moved by ICP when enabled);
    registration: the ICP record (:meth:`ICPResult.as_dict`) or None; method: ``"c2c"`` or ``"c2m"``.
    """

    result: C2CResult
    measured: PointCloud
    registration: dict | None
    method: str


def measure(
    compared: PointCloud, reference: PointCloud | Mesh, options: GeometryOptions = GeometryOptions()
) -> Measurement:
    """Distances of ``compared`` to ``reference`` (a cloud: C2C, a mesh: C2M), after optional ICP."""
    registration = None
    if options.icp_max_correspondence is not None:
        if not isinstance(reference, PointCloud):
            raise ConfigError("ICP registration needs a reference point cloud, not a mesh")
        icp = icp_point_to_plane(compared, reference, options.icp_max_correspondence)
        compared = icp.apply(compared)
        registration = icp.as_dict()
    if isinstance(reference, PointCloud):
        result = compare_clouds(compared, reference, options.max_dist, options.tau, options.class_field)
        method = "c2c"
    else:
        if options.tau is not None:
            raise ConfigError("completeness / F-score (--tau) need a reference point cloud, not a mesh")
        m = compare_cloud_to_mesh(compared, reference, options.max_dist, options.class_field)
        result = C2CResult(distances=m.distances, stats=m.stats, per_class=m.per_class)
        method = "c2m"
    if len(result.per_class) == 1:  # a single class repeats the overall statistics
        result = C2CResult(result.distances, result.stats, result.reverse, result.scores, {})
    return Measurement(result, compared, registration, method)


def _measure_streamed(
    compared: PointCloud, reference: Any, options: GeometryOptions, work_dir: str | PathLike[str] | None
) -> Measurement:
    """:func:`measure` (C2C) with the reference (a file, or a :class:`core.io.point_stream.PointSource`) read in
    chunks within ``options.memory_limit_mb`` (:func:`eval.geometry_stream.compare_clouds_streamed`); temporary
    files in ``work_dir``."""
    from core.io.point_stream import PointSource
    from eval.c2c_stream import plan_c2c_memory
    from eval.geometry_stream import compare_clouds_streamed, reference_source

    plan = plan_c2c_memory(options.memory_limit_mb)  # type: ignore[arg-type]
    if work_dir is not None:
        Path(work_dir).mkdir(parents=True, exist_ok=True)
    source = reference if isinstance(reference, PointSource) else reference_source(reference, plan.chunk)
    result = compare_clouds_streamed(
        compared, source, plan, options.max_dist, options.tau, options.class_field, work_dir=work_dir
    )
    if len(result.per_class) == 1:  # a single class repeats the overall statistics, as measure() drops it
        result = C2CResult(result.distances, result.stats, result.reverse, result.scores, {})
    return Measurement(result, compared, None, "c2c")


def with_distance_field(cloud: PointCloud, distances: np.ndarray, name: str = "c2c") -> PointCloud:
    """A copy of ``cloud`` with a float64 scalar field ``name`` (metres)."""
    fields = dict(cloud.fields)
    fields[name] = np.asarray(distances, dtype=np.float64)
    return PointCloud(cloud.positions, cloud.origin, cloud.colors, cloud.normals, fields, cloud.visibility)


def evaluate_geometry(
    compared: PointCloud | str | PathLike[str],
    reference: PointCloud | Mesh | str | PathLike[str] | Any,
    out_dir: str | PathLike[str] | None,
    name: str,
    options: GeometryOptions = GeometryOptions(),
) -> C2CSummary:
    """Measure one product and write its outputs under ``out_dir`` (nothing written when None).

    ``compared``/``reference`` are clouds or paths (a mesh path makes it C2M); with ``options.memory_limit_mb`` the
    reference may also be a :class:`core.io.point_stream.PointSource` (read in chunks). File paths in the summary
    are relative to ``out_dir``.
    """
    from core.io.point_stream import PointSource

    ref_name = str(reference) if isinstance(reference, (str, PathLike)) else None
    if isinstance(reference, PointSource):  # a reference read in chunks (the eval stage's, spooled once)
        ref_name = str(reference.path) if reference.path is not None else None
    cloud = read_point_cloud(compared) if isinstance(compared, (str, PathLike)) else compared
    streamed = isinstance(reference, PointSource) or (
        isinstance(reference, (str, PathLike)) and not is_mesh_file(reference)
    )
    if options.memory_limit_mb is not None and streamed:
        m = _measure_streamed(cloud, reference, options, out_dir)  # type: ignore[arg-type]
    else:
        ref = load_reference(reference) if isinstance(reference, (str, PathLike)) else reference
        m = measure(cloud, ref, options)
    result, measured, registration, method = m.result, m.measured, m.registration, m.method
    files: dict[str, str] = {}
    if out_dir is not None:
        out = Path(out_dir)
        out_cloud = with_distance_field(measured, result.distances)
        write_point_cloud(out / f"c2c_{name}.ply", out_cloud)
        files["cloud_ply"] = f"c2c_{name}.ply"
        if options.write_las:
            write_point_cloud(out / f"c2c_{name}.las", out_cloud)
            files["cloud_las"] = f"c2c_{name}.las"
    summary = C2CSummary.from_result(result, method, ref_name, registration, files)
    if out_dir is not None:
        out = Path(out_dir)
        hist = svg_histogram(summary.histogram_edges, summary.histogram_counts, f"{method.upper()} distances: {name}")
        write_text_atomic(out / "plots" / f"c2c_{name}_hist.svg", hist)
        vmax = options.max_dist if options.max_dist is not None else max(result.stats.p95, 1e-9)
        write_image(
            out / "plots" / f"c2c_{name}_preview.png", preview_image(measured.positions, result.distances, vmax=vmax)
        )
        files.update(histogram=f"plots/c2c_{name}_hist.svg", preview=f"plots/c2c_{name}_preview.png")
        summary = replace(summary, files=files)
    return summary
