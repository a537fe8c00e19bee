"""A point cloud as a re-iterable stream of :class:`core.pointcloud.PointCloud` chunks, read with bounded memory.

A :class:`PointSource` yields the same points in the same order, in one local frame, every time it is iterated, so
that an out-of-core algorithm (:mod:`fusion.convert_stream`) can make several passes over a cloud larger than memory.
Sources: :func:`cloud_source` over an in-memory cloud, :func:`las_source` over a LAS/LAZ file (as
:func:`core.io.las.read_las` reads it), :func:`ply_source` over a binary PLY such as COLMAP's ``fused.ply`` with its
``fused.ply.vis`` (as :func:`core.io.ply.read_ply` + :func:`core.io.colmap_vis.read_vis` read them).
:func:`rechunk` cuts one pass into chunks of at most a given size. Units: metres; positions float64 relative to the
chunk's ``origin`` (world = origin + local).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numba
import numpy as np

from core.errors import DataError, FormatError, HybridSplatError, InputFileError
from core.pointcloud import PointCloud, choose_origin

PointChunks = Callable[[], Iterable[PointCloud]]
"""Called once per pass: yields the cloud as consecutive :class:`PointCloud` chunks (same origin, same attributes)."""


@dataclass(frozen=True)
class PointSource:
    """A cloud as a stream of chunks; ``path`` (the file behind it, if any) is named in every error."""

    chunks: PointChunks
    path: Path | None = None

    @property
    def name(self) -> str:
        return str(self.path) if self.path is not None else "point source"


def rechunk(source: PointSource, chunk_size: int) -> Iterator[tuple[int, PointCloud]]:
    """(index of the first point, chunk of at most ``chunk_size`` points) over one pass of the source."""
    start = 0
    for chunk in source.chunks():
        for piece in chunk.chunks(chunk_size) if len(chunk) > chunk_size else (chunk,):
            yield start, piece
            start += len(piece)


def cloud_source(cloud: PointCloud, chunk: int = 1_000_000) -> PointSource:
    """A source over an in-memory cloud (tests, small clouds): its :meth:`PointCloud.chunks`."""
    return PointSource(lambda: cloud.chunks(chunk))


def las_source(
    path: str | PathLike[str],
    origin: np.ndarray | None = None,
    chunk: int = 2_000_000,
    *,
    colors_16bit: bool | None = None,
    keep_intensity: bool | None = None,
) -> PointSource:
    """A source over a LAS/LAZ file, read ``chunk`` points at a time, as :func:`core.io.las.read_las` reads it:
    positions relative to ``origin`` (world metres; default: :func:`choose_origin` of the header's bounds), the
    large offset cancelled first; RGB, normals (extra dims ``nx, ny, nz``), ``classification``, the other extra dims.

    ``read_las`` decides on the whole file whether RGB is 16-bit (any value > 255: divided by 257) and whether to
    keep ``intensity`` (any value ≠ 0); a stream decides on its first chunk unless told (``colors_16bit``,
    ``keep_intensity``), and raises :class:`DataError` naming the file when a later chunk contradicts it.
    """
    from core.io.las import scan_las_header

    path = Path(path)
    scan_las_header(path)
    if origin is None:
        origin = _las_header_origin(path)
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    decided: dict[str, bool | None] = {"rgb16": colors_16bit, "intensity": keep_intensity}

    def chunks() -> Iterator[PointCloud]:
        import laspy

        try:
            with laspy.open(path) as reader:
                scales = np.asarray(reader.header.scales, dtype=np.float64)
                offsets = np.asarray(reader.header.offsets, dtype=np.float64)
                fmt = reader.header.point_format
                for points in reader.chunk_iterator(chunk):
                    yield _las_chunk(points, fmt, scales, offsets, origin, decided, path)
        except HybridSplatError:
            raise
        except Exception as err:  # laspy / lazrs errors on truncated or corrupt data
            raise InputFileError(f"LAS/LAZ data is truncated or corrupt ({type(err).__name__}: {err})", path) from err

    return PointSource(chunks, path)


def _las_header_origin(path: Path) -> np.ndarray:
    import laspy

    with laspy.open(path) as reader:
        box = np.array([reader.header.mins, reader.header.maxs], dtype=np.float64)
    return choose_origin(box)


def _las_chunk(points, fmt, scales, offsets, origin, decided: dict, path: Path) -> PointCloud:  # noqa: ANN001
    """One laspy chunk as a PointCloud (see :func:`las_source`); ``decided`` holds the 16-bit / intensity choices."""
    ints = np.stack([np.asarray(points.X), np.asarray(points.Y), np.asarray(points.Z)], axis=1)
    positions = ints.astype(np.float64) * scales + (offsets - origin)
    dims = set(fmt.dimension_names)
    colors = None
    if {"red", "green", "blue"} <= dims:
        rgb = np.stack([np.asarray(points.red), np.asarray(points.green), np.asarray(points.blue)], axis=1)
        big = bool(rgb.size and rgb.max() > 255)
        if decided["rgb16"] is None:
            decided["rgb16"] = big
        elif big and not decided["rgb16"]:
            raise DataError("RGB is 8-bit in the first chunk but 16-bit later; pass colors_16bit=True", path)
        colors = np.round(rgb / 257.0).astype(np.uint8) if decided["rgb16"] else rgb.astype(np.uint8)
    fields: dict[str, np.ndarray] = {"classification": np.asarray(points.classification, dtype=np.uint8)}
    intensity = np.asarray(points.intensity)
    nonzero = bool(intensity.size and intensity.any())
    if decided["intensity"] is None:
        decided["intensity"] = nonzero
    elif nonzero and not decided["intensity"]:
        raise DataError("intensity is zero in the first chunk but not later; pass keep_intensity=True", path)
    if decided["intensity"]:
        fields["intensity"] = intensity.copy()
    extra = list(fmt.extra_dimension_names)
    normals = None
    if {"nx", "ny", "nz"} <= set(extra):
        normals = np.stack([np.asarray(points[n], dtype=np.float32) for n in ("nx", "ny", "nz")], axis=1)
    for name in extra:
        if not (name in ("nx", "ny", "nz") and normals is not None):
            fields[name] = np.asarray(points[name]).copy()
    return PointCloud(positions, origin, colors, normals, fields)


_PLY_NUMPY = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2", "ushort": "u2",
    "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4",
    "double": "f8", "float64": "f8",
}  # fmt: skip


def ply_source(
    path: str | PathLike[str], vis_path: str | PathLike[str] | None = None, chunk: int = 2_000_000
) -> PointSource:
    """A source over a binary PLY point cloud (e.g. COLMAP's ``fused.ply``) and optionally its ``fused.ply.vis``,
    as :func:`core.io.ply.read_ply` + :func:`core.io.colmap_vis.read_vis` read them, ``chunk`` vertex rows at a
    time (read with ``np.fromfile``, not mapped, so that resident memory stays one chunk). One pass at creation
    takes what ``read_ply`` decides on the whole file (the local origin: sidecar + :func:`choose_origin` of the
    coordinates; whether integer RGB is 16-bit) and checks the ``.vis`` file's counts, keeping the word offset of
    each chunk's first record. Needs the vertex element first and without list properties (:class:`FormatError`).
    """
    from core.io.origin import read_origin
    from core.io.ply import COLOR_NAMES, NORMAL_NAMES, colors_from_ply, scan_ply_header

    path = Path(path)
    header = scan_ply_header(path)
    vertex = header.elements[0] if header.elements else None
    if header.format == "ascii" or vertex is None or vertex.name != "vertex":
        raise FormatError("a streamed PLY must be binary with the vertex element first", path)
    if any(c is not None for _, _, c in vertex.properties):
        raise FormatError("a streamed PLY cannot hold list properties in its vertex element", path)
    order = "<" if header.format == "binary_little_endian" else ">"
    dtype = np.dtype([(name, order + _PLY_NUMPY[t]) for name, t, _ in vertex.properties])
    names = set(dtype.names or ())
    if not {"x", "y", "z"} <= names:
        raise FormatError(f"PLY vertex element lacks x, y or z (has: {', '.join(dtype.names or ())})", path)
    colors = next((t for t in COLOR_NAMES if set(t) <= names), None)
    normals = NORMAL_NAMES if set(NORMAL_NAMES) <= names else None
    skip = {"x", "y", "z", *(colors or ()), *(normals or ())}

    def rows() -> Iterator[tuple[int, np.ndarray]]:
        for a in range(0, vertex.count, chunk):
            n = min(chunk, vertex.count - a)
            yield a, np.fromfile(path, dtype, count=n, offset=header.data_offset + a * dtype.itemsize)

    lo, hi, rgb_max = np.full(3, np.inf), np.full(3, -np.inf), 0
    for _, part in rows():
        xyz = np.stack([part[c].astype(np.float64) for c in "xyz"], axis=1)
        ok = np.isfinite(xyz).all(axis=1)
        if ok.any():
            lo, hi = np.minimum(lo, xyz[ok].min(axis=0)), np.maximum(hi, xyz[ok].max(axis=0))
        if colors is not None and dtype[colors[0]].kind in "iu" and dtype[colors[0]].itemsize > 1:
            rgb_max = max(rgb_max, max(int(part[c].max(initial=0)) for c in colors))
    extra = choose_origin(np.array([lo, hi])) if np.isfinite(lo).all() else np.zeros(3)
    origin = read_origin(path) + extra
    vis = Path(vis_path) if vis_path is not None else None
    bounds = _vis_bounds(vis, vertex.count, chunk) if vis is not None else None

    def chunks() -> Iterator[PointCloud]:
        for a, part in rows():
            xyz = np.stack([part[c].astype(np.float64) for c in "xyz"], axis=1) - extra
            rgb = None
            if colors is not None:
                raw = np.stack([part[c] for c in colors], axis=1)
                if raw.dtype.kind == "f":
                    rgb = colors_from_ply(raw, path)
                else:  # 16-bit when any value of the file is above 255, as read_ply decides on the whole file
                    rgb = (raw / 257.0).round().astype(np.uint8) if rgb_max > 255 else raw.astype(np.uint8)
            nrm = np.stack([part[c].astype(np.float32) for c in normals], axis=1) if normals else None
            fields = {n: part[n].astype(part[n].dtype.newbyteorder("=")) for n in dtype.names or () if n not in skip}
            seen = _vis_chunk(vis, bounds, a // chunk, len(part)) if vis is not None else None  # type: ignore[arg-type]
            yield PointCloud(xyz, origin, rgb, nrm, fields, seen)

    return PointSource(chunks, path)


def _vis_bounds(path: Path, count: int, chunk: int) -> np.ndarray:
    """Word offsets (after the 8-byte count) of the first record of every ``chunk`` points of a ``fused.ply.vis``
    and of its end, checked as :func:`core.io.colmap_vis.read_vis` checks the file (:class:`FormatError`)."""
    if not path.is_file():
        raise InputFileError("visibility file does not exist", path)
    size = path.stat().st_size
    if size < 8 or (size - 8) % 4:
        raise FormatError(f"visibility file size {size} is not 8 + a multiple of 4 bytes", path)
    declared, total = int(np.fromfile(path, "<u8", count=1)[0]), (size - 8) // 4
    if declared != count:
        raise FormatError(f"visibility file lists {declared} points, the cloud has {count}", path)
    bounds, pos = [0], 0
    for a in range(0, count, chunk):
        n, guess = min(chunk, count - a), 4 * min(chunk, count - a) + 1
        while True:
            words = np.fromfile(path, "<u4", count=min(guess, total - pos), offset=8 + 4 * pos)
            end = _vis_offsets_kernel(words, np.empty(n + 1, np.int64))
            if end >= 0:
                break
            if pos + len(words) >= total:
                raise FormatError(f"visibility file is truncated in the records of points {a}..{a + n - 1}", path)
            guess *= 2
        pos += end
        bounds.append(pos)
    if pos != total:
        raise FormatError(f"visibility file has {4 * (total - pos)} bytes after its {count} points", path)
    return np.array(bounds, dtype=np.int64)


@numba.njit(cache=True)
def _vis_offsets_kernel(words: np.ndarray, starts: np.ndarray) -> int:
    """starts[i] = word offset of record i in ``words`` (len(starts) − 1 records); returns the end offset, or −1
    when a record runs past the end of ``words``."""
    pos = 0
    for i in range(len(starts) - 1):
        starts[i] = pos
        if pos >= len(words):
            return -1
        pos += 1 + np.int64(words[pos])
        if pos > len(words):
            return -1
    starts[len(starts) - 1] = pos
    return pos


def _vis_chunk(path: Path, bounds: np.ndarray, index: int, n: int) -> list[np.ndarray]:
    """The visibility lists (int64 image positions) of the n points of chunk ``index``."""
    a, b = int(bounds[index]), int(bounds[index + 1])
    words = np.fromfile(path, "<u4", count=b - a, offset=8 + 4 * a).astype(np.int64)
    local = np.empty(n + 1, np.int64)
    _vis_offsets_kernel(words, local)
    return [words[local[i] + 1 : local[i + 1]] for i in range(n)]
