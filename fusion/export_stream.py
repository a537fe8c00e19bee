"""Survey point exports in chunks (issue 34): :func:`export_points_chunked` writes the file
:func:`fusion.export.export_points` writes (PLY with its origin sidecar, LAS/LAZ at 1 mm), byte for byte, one chunk
of Gaussians at a time: :class:`core.io.las.LasChunkWriter` for LAS/LAZ, the rows and header of
:func:`core.io.ply.write_ply` (:func:`core.io.ply.ply_vertex_rows`, :func:`core.io.ply.ply_vertex_header`) for PLY.

The Gaussian set itself is in memory (the command and the merge stage hold it); what the chunks bound is what the
export adds on top: the point cloud of :func:`fusion.export.gaussians_to_points` and the file's records, a chunk's
worth instead of the whole cloud's (about 200 bytes a point).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import ConfigError, FormatError
from core.gaussians import GaussianSet
from core.io.atomic import atomic_path
from core.pointcloud import PointCloud
from eval.c2c_stream import memory_work_mb

BASE_MB = 512.0
"""Memory (MiB) the export holds besides its chunks: interpreter, libraries and the Gaussian set of a small project."""
MIN_WORK_MB = 64.0
"""The least memory beyond :data:`BASE_MB` the chunked export works in (MiB)."""
_POINT_BYTES = 200  # a point of a chunk: positions 24, colours 3, fields ~16, the file's row or record ~40, copies


def export_chunk_points(memory_limit_mb: float) -> int:
    """Points a chunk for a peak memory of about ``memory_limit_mb`` (MiB): a quarter of what is left above
    :data:`BASE_MB`. Raises :class:`ConfigError` naming the value when less than :data:`MIN_WORK_MB` is left."""
    work = memory_work_mb(
        memory_limit_mb,
        BASE_MB,
        MIN_WORK_MB,
        "the chunked point export",
        "the interpreter, libraries and the Gaussians",
        "a chunk",
    )
    return max(1000, int(0.25 * work * 2**20 / _POINT_BYTES))


def point_chunks(gaussians: GaussianSet, chunk: int) -> Callable[[], Iterator[PointCloud]]:
    """The survey points of ``gaussians`` (:func:`fusion.export.gaussians_to_points`), ``chunk`` at a time, per call."""
    from fusion.export import gaussians_to_points

    n = len(gaussians)
    return lambda: (gaussians_to_points(gaussians.subset(slice(a, min(a + chunk, n)))) for a in range(0, n, chunk))


def write_las_points(path: Path, chunks: Callable[[], Iterator[PointCloud]], crs: str | None) -> Path:
    """The LAS/LAZ file :func:`core.io.las.write_las` writes for the concatenated chunks, atomically."""
    from core.io.las import LasChunkWriter

    with atomic_path(path) as tmp:
        writer = LasChunkWriter(Path(tmp), crs=crs, target=path)
        try:
            for cloud in chunks():
                cloud.validate(str(path))
                writer.write(cloud)
        finally:
            writer.close()
    return path


def write_ply_points(path: Path, chunks: Callable[[], Iterator[PointCloud]], crs: str | None = None) -> Path:
    """The PLY file (and origin sidecar) :func:`core.io.ply.write_ply` writes for the concatenated chunks,
    atomically. Two passes: the first settles the row layout of the whole cloud (an int64 field is written as
    int32 only when every chunk fits) and the count, the second writes the rows."""
    from core.io.origin import remove_origin, write_origin
    from core.io.ply import ply_vertex_header, ply_vertex_rows

    layouts, count, origin = [], 0, np.zeros(3)
    for cloud in chunks():
        layouts.append(ply_vertex_rows(cloud).dtype)
        count, origin = count + len(cloud), cloud.origin
    dtype = _whole_layout(layouts)
    with atomic_path(path) as tmp, open(tmp, "wb") as out:
        out.write(ply_vertex_header(dtype, count))
        for cloud in chunks():
            out.write(ply_vertex_rows(cloud).astype(dtype).tobytes())
    if crs:
        write_origin(path, origin, crs)
    elif np.any(origin != 0):
        write_origin(path, origin)
    else:
        remove_origin(path)
    return path


def _whole_layout(layouts: list[np.dtype]) -> np.dtype:
    """The row dtype of the whole cloud from its chunks': a field any chunk writes as float64 (an int64 field out
    of the int32 range there) is float64 for all, as :func:`core.io.ply.write_ply` decides on the whole cloud."""
    first = layouts[0]
    if all(d == first for d in layouts):
        return first
    fields = []
    for name in first.names or ():
        kinds = [d.fields[name][0] for d in layouts]
        wide = next((k for k in kinds if k.kind == "f" and k.itemsize == 8), kinds[0])
        fields.append((name, wide))
    return np.dtype(fields)


def export_points_chunked(
    path: str | PathLike[str], gaussians: GaussianSet, options: object | None = None, *, chunk: int
) -> object:
    """:func:`fusion.export.export_points` (same filters, same file and sidecar, same report) written ``chunk``
    Gaussians at a time. ``options``: a :class:`fusion.export.ExportOptions` or None."""
    from fusion.export import _report, prepare

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".ply", ".las", ".laz"):
        raise FormatError(f"point export needs .ply, .las or .laz, got {path.suffix!r}", path)
    if chunk < 1:
        raise ConfigError(f"chunk must be >= 1 point, got {chunk}")
    prep = prepare(gaussians, options)  # type: ignore[arg-type]
    crs = getattr(options, "crs", None)
    chunks = point_chunks(prep.gaussians, chunk)
    if suffix == ".ply":
        out = write_ply_points(path, chunks, crs)
    else:
        out = write_las_points(path, chunks, crs)
    return _report(out, suffix.lstrip("."), prep)
