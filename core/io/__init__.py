"""File formats: PLY / LAS / LAZ / E57 point clouds, 3DGS PLY, COLMAP models, images; atomic writes.

:func:`read_point_cloud` and :func:`write_point_cloud` choose the format from the file suffix.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

from core.errors import FormatError
from core.pointcloud import PointCloud

POINT_CLOUD_SUFFIXES = (".ply", ".las", ".laz", ".e57")


def read_point_cloud(path: str | PathLike[str]) -> PointCloud:
    """Read a point cloud from .ply, .las, .laz or .e57."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".ply":
        from core.io.ply import read_ply

        return read_ply(path)
    if suffix in (".las", ".laz"):
        from core.io.las import read_las

        return read_las(path)
    if suffix == ".e57":
        from core.io.e57 import read_e57

        return read_e57(path)
    raise FormatError(f"unknown point cloud format {suffix!r}; expected one of {', '.join(POINT_CLOUD_SUFFIXES)}", path)


def write_point_cloud(path: str | PathLike[str], cloud: PointCloud) -> Path:
    """Write a point cloud to .ply (local float32 + origin sidecar) or .las/.laz (1 mm scale)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".ply":
        from core.io.ply import write_ply

        return write_ply(path, cloud)
    if suffix in (".las", ".laz"):
        from core.io.las import write_las

        return write_las(path, cloud)
    raise FormatError(f"cannot write point clouds as {suffix!r}; use .ply, .las or .laz", path)
