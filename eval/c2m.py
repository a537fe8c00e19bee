"""Cloud-to-mesh (C2M) distances: for each compared point, the unsigned distance to the nearest triangle.

open3d's ``RaycastingScene`` works in float32, so the mesh and the points are first moved to one float64
local origin (the mesh's rounded bounding-box centre) and only then cast; georeferenced meshes keep
millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import DataError, FormatError, InputFileError
from core.pointcloud import PointCloud, choose_origin
from eval.c2c import DistanceStats, distance_stats, per_class_stats

MESH_SUFFIXES = (".ply", ".obj", ".stl", ".off", ".glb", ".gltf")


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh: vertices (V, 3) float64 metres relative to ``origin`` (3,) float64; triangles (T, 3) int64."""

    vertices: np.ndarray
    triangles: np.ndarray
    origin: np.ndarray

    @property
    def world_vertices(self) -> np.ndarray:
        return self.vertices + self.origin


@dataclass(frozen=True)
class C2MResult:
    """distances: (N,) float64 metres (clamped to ``max_dist`` when set); stats and per-class stats as for C2C."""

    distances: np.ndarray
    stats: DistanceStats
    per_class: dict[int, DistanceStats]


def is_mesh_file(path: str | PathLike[str]) -> bool:
    """True for mesh formats, and for PLY files that hold a non-empty ``face`` element."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix != ".ply":
        return suffix in MESH_SUFFIXES
    try:
        with p.open("rb") as f:
            header = b""
            while b"end_header" not in header and len(header) < 65536:
                chunk = f.readline()
                if not chunk:
                    break
                header += chunk
    except OSError:
        return False
    for line in header.decode("ascii", errors="replace").splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0] == "element" and parts[1] == "face":
            return parts[2].isdigit() and int(parts[2]) > 0
    return False


def read_mesh(path: str | PathLike[str]) -> Mesh:
    """Read a triangle mesh (PLY/OBJ/STL/OFF/glTF) through open3d; vertices are shifted to a local origin."""
    import open3d as o3d

    p = Path(path)
    if not p.is_file():
        raise InputFileError("mesh file does not exist", p)
    mesh = o3d.io.read_triangle_mesh(str(p))
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = np.asarray(mesh.triangles, dtype=np.int64)
    if len(vertices) == 0 or len(triangles) == 0:
        raise FormatError("no triangles could be read from this file (not a mesh, or an unsupported variant)", p)
    if not np.isfinite(vertices).all():
        raise DataError("mesh vertices contain NaN or infinite values", p)
    if triangles.min() < 0 or triangles.max() >= len(vertices):
        bad = int(np.flatnonzero((triangles < 0).any(axis=1) | (triangles >= len(vertices)).any(axis=1))[0])
        raise FormatError(
            f"face {bad} refers to vertex {triangles[bad].tolist()}, but the mesh has {len(vertices)} vertices", p
        )
    origin = choose_origin(vertices)
    return Mesh(vertices - origin, triangles, origin)


def mesh_distances(points: np.ndarray, mesh: Mesh, chunk_size: int = 1_000_000) -> np.ndarray:
    """(N,) float64 unsigned distances in metres from points (N, 3) float64, given relative to ``mesh.origin``,
    to the nearest point of the mesh surface (queried in chunks of ``chunk_size``)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.triangles.astype(np.uint32))
    )
    pts = np.asarray(points, dtype=np.float64)
    out = np.empty(len(pts), dtype=np.float64)
    for start in range(0, len(pts), chunk_size):
        chunk = pts[start : start + chunk_size].astype(np.float32)
        out[start : start + len(chunk)] = scene.compute_distance(o3d.core.Tensor(chunk)).numpy()
    return out


def compare_cloud_to_mesh(
    compared: PointCloud, mesh: Mesh, max_dist: float | None = None, class_field: str = "classification"
) -> C2MResult:
    """C2M of a :class:`PointCloud` against a :class:`Mesh` (any origins), with statistics as for C2C."""
    compared.validate("compared cloud")
    if len(compared) == 0:
        raise DataError("the compared cloud is empty; C2M needs at least one compared point")
    local = compared.with_origin(mesh.origin).positions
    d = mesh_distances(local, mesh)
    if max_dist is not None:
        d = np.minimum(d, max_dist)
    per_class = per_class_stats(d, compared.fields[class_field], max_dist) if class_field in compared.fields else {}
    return C2MResult(d, distance_stats(d, max_dist), per_class)
