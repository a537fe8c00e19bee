"""LAS / LAZ point clouds through laspy (+ lazrs for LAZ).

Scales and offsets are honoured both ways: reading turns the integer records into float64 world
coordinates (``X·scale + offset``) expressed relative to a local origin; writing stores
``round((world − offset) / scale)`` with the offset at the cloud's origin, so georeferenced clouds keep
their millimetres. RGB is 16-bit in LAS (value·257 on write; /257 on read, or kept when the file holds 8-bit
values), ``classification`` maps to the LAS classification, normals travel as extra dims ``nx, ny, nz``, other
scalar fields as extra dims. A cloud is written whole (:func:`write_las`) or chunk by chunk with bounded memory
(:class:`LasChunkWriter`: the same header and records; :func:`write_las_chunks`: positions only).
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from os import PathLike
from pathlib import Path

import laspy
import numpy as np

from core.errors import ConfigError, DataError, FormatError, InputFileError
from core.io.atomic import atomic_path
from core.pointcloud import PointCloud, choose_origin

_STANDARD_KEPT = ("intensity",)
_EXTRA_TYPES = {
    np.dtype(t)
    for t in (np.int8, np.uint8, np.int16, np.uint16, np.int32, np.uint32, np.int64, np.uint64, np.float32, np.float64)
}


def read_las(path: str | PathLike[str]) -> PointCloud:
    """Read a LAS or LAZ file as a :class:`PointCloud` (float64 positions relative to a local origin)."""
    path = Path(path)
    declared = scan_las_header(path)
    try:
        las = laspy.read(path)
    except laspy.errors.LaspyException as err:
        raise FormatError(f"not a valid LAS/LAZ file ({_short(err)})", path) from err
    except (ValueError, EOFError, OSError, struct.error) as err:
        raise InputFileError(f"LAS data is truncated or corrupt ({_short(err)})", path) from err
    except MemoryError as err:
        raise InputFileError(f"header declares {declared} points, more than memory can hold", path) from err
    except Exception as err:  # lazrs raises its own LazrsError for truncated or corrupt compressed data
        raise InputFileError(f"LAZ data is truncated or corrupt ({type(err).__name__}: {_short(err)})", path) from err
    if len(las.points) != declared:
        raise InputFileError(f"header declares {declared} points but {len(las.points)} could be read", path)

    scales = np.asarray(las.header.scales, dtype=np.float64)
    offsets = np.asarray(las.header.offsets, dtype=np.float64)
    if not (np.isfinite(scales).all() and np.isfinite(offsets).all() and (scales > 0).all()):
        raise FormatError(f"invalid scales {scales.tolist()} or offsets {offsets.tolist()} in the header", path)
    ints = np.stack([np.asarray(las.X), np.asarray(las.Y), np.asarray(las.Z)], axis=1).astype(np.float64)
    world_approx = ints * scales + offsets
    origin = choose_origin(world_approx)
    # (X·scale) + (offset − origin): the large offset cancels in float64 before adding the small part.
    positions = ints * scales + (offsets - origin)

    dims = set(las.point_format.dimension_names)
    colors = None
    if {"red", "green", "blue"} <= dims:
        rgb = np.stack([np.asarray(las.red), np.asarray(las.green), np.asarray(las.blue)], axis=1)
        if rgb.size and rgb.max() > 255:
            colors = np.round(rgb.astype(np.float64) / 257.0).astype(np.uint8)
        else:
            colors = rgb.astype(np.uint8)

    extra_names = list(las.point_format.extra_dimension_names)
    fields: dict[str, np.ndarray] = {"classification": np.asarray(las.classification, dtype=np.uint8)}
    for name in _STANDARD_KEPT:
        values = np.asarray(las[name])
        if values.size and values.any():
            fields[name] = values.copy()
    normals = None
    if {"nx", "ny", "nz"} <= set(extra_names):
        normals = np.stack([np.asarray(las[n], dtype=np.float32) for n in ("nx", "ny", "nz")], axis=1)
    for name in extra_names:
        if name in ("nx", "ny", "nz") and normals is not None:
            continue
        fields[name] = np.asarray(las[name]).copy()
    return PointCloud(positions, origin, colors, normals, fields)


# Byte offsets of the LAS public header block (LAS 1.0–1.4, little-endian).
_HEADER_MIN = 227  # LAS 1.0–1.2 header size
#: A LAZ file cannot hold more uncompressed point bytes than this multiple of its size. LASzip reaches
#: 5–15× on real scans and ~100× on constant records; a header declaring more is corrupt, and refusing it
#: here avoids allocating the declared size.
MAX_LAZ_RATIO = 1000


def _short(err: BaseException, limit: int = 120) -> str:
    text = " ".join(str(err).split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def scan_las_header(path: str | PathLike[str]) -> int:
    """Check a LAS/LAZ header against the file size before laspy reads it; returns the declared point count.

    Checks the signature, the header size, the point data offset, the legacy and LAS 1.4 point counts
    (they must agree when both are set), and that the declared records fit in the file (LAS: exactly the
    bytes present, except for trailing EVLRs; LAZ: at most :data:`MAX_LAZ_RATIO` times the file size).
    Raises :class:`InputFileError` (missing, empty, truncated) or :class:`FormatError` (inconsistent).
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError("file does not exist" if not path.exists() else "is not a file", path)
    size = path.stat().st_size
    if size == 0:
        raise InputFileError("file is empty", path)
    with path.open("rb") as f:
        head = f.read(375)
    if head[:4] != b"LASF":
        raise FormatError(f"not a LAS/LAZ file (signature {head[:4]!r}, expected b'LASF')", path)
    if len(head) < _HEADER_MIN:
        raise InputFileError(f"file is truncated inside the LAS header ({size} bytes)", path)
    major, minor = head[24], head[25]
    header_size, point_offset = struct.unpack_from("<HI", head, 94)
    fmt_id, rec_len, legacy = struct.unpack_from("<BHI", head, 104)
    if header_size < _HEADER_MIN or header_size > size:
        raise InputFileError(f"LAS header size {header_size} does not fit a {size}-byte file", path)
    count = legacy
    evlr_start = 0
    if (major, minor) >= (1, 3) and len(head) >= 235 and header_size >= 235:
        (evlr_start,) = struct.unpack_from("<Q", head, 227)  # internal waveform packets follow the points
    if (major, minor) >= (1, 4):
        if len(head) < 375 or header_size < 375:
            raise InputFileError("file is truncated inside the LAS 1.4 header", path)
        first_evlr, _n_evlr, count = struct.unpack_from("<QIQ", head, 235)
        if first_evlr > point_offset and (evlr_start <= point_offset or first_evlr < evlr_start):
            evlr_start = first_evlr
        if legacy and legacy != count:
            raise FormatError(f"header point counts disagree: legacy {legacy}, LAS 1.4 {count}", path)
    if point_offset < header_size or point_offset > size:
        raise FormatError(f"point data offset {point_offset} lies outside the file ({size} bytes)", path)
    compressed = bool(fmt_id & 0x80) or path.suffix.lower() == ".laz"
    room = (min(evlr_start, size) if evlr_start > point_offset else size) - point_offset
    need = count * rec_len
    if compressed:
        if need > MAX_LAZ_RATIO * max(room, 1):
            raise FormatError(
                f"header declares {count} points ({need} bytes uncompressed) in {room} compressed bytes", path
            )
    elif need > room:
        raise InputFileError(
            f"header declares {count} points ({need} bytes) but only {room} bytes of point records follow "
            f"({room // max(rec_len, 1)} points): file truncated or header count wrong",
            path,
        )
    elif rec_len and room - need >= rec_len:
        raise FormatError(
            f"header declares {count} points but the file holds {room // rec_len} records: header count wrong",
            path,
        )
    return int(count)


def write_las(
    path: str | PathLike[str],
    cloud: PointCloud,
    *,
    scale: float = 0.001,
    offset: np.ndarray | None = None,
    crs: str | None = None,
) -> Path:
    """Write a point cloud as LAS 1.4 (``.las``) or LAZ (``.laz``), atomically.

    ``scale`` (metres per integer step, default 1 mm) applies to x, y, z; ``offset`` defaults to the cloud's
    origin (rounded to the scale). ``crs`` (e.g. ``"EPSG:32632"``) is written as the WKT VLR that LAS 1.4 readers
    (laspy, PDAL, CloudCompare) take the georeference from. Raises :class:`DataError` when coordinates do not fit
    the int32 range at that scale, :class:`ConfigError` for a CRS that pyproj does not know.
    """
    path = Path(path)
    if path.suffix.lower() not in (".las", ".laz"):
        raise DataError(f"LAS output needs a .las or .laz suffix, got {path.suffix!r}", path)
    cloud.validate(str(path))
    offset_arr = np.round(np.asarray(cloud.origin if offset is None else offset, dtype=np.float64) / scale) * scale
    local = cloud.positions + (cloud.origin - offset_arr)
    ints = np.round(local / scale)
    limit = np.iinfo(np.int32).max
    if ints.size and np.abs(ints).max() > limit:
        raise DataError(f"coordinates span more than ±{limit * scale:.0f} m from the offset at scale {scale}", path)

    header = _las_header(cloud, offset_arr, scale, crs, path)
    las = laspy.LasData(header)
    _fill_points(las, cloud, ints, path)
    with atomic_path(path) as tmp:
        las.write(str(tmp), do_compress=path.suffix.lower() == ".laz")
    return path


def _las_extras(cloud: PointCloud) -> dict[str, np.ndarray]:
    """The cloud's attributes stored as LAS extra dims: normals as ``nx, ny, nz``, then every field except
    ``classification`` and the standard dimensions kept (``intensity``)."""
    extras = {k: v for k, v in cloud.fields.items() if k not in ("classification",) + _STANDARD_KEPT}
    if cloud.normals is not None:
        extras = {"nx": cloud.normals[:, 0], "ny": cloud.normals[:, 1], "nz": cloud.normals[:, 2], **extras}
    return extras


def _las_header(cloud: PointCloud, offset: np.ndarray, scale: float, crs: str | None, path: Path) -> laspy.LasHeader:
    """The LAS 1.4 header :func:`write_las` and :class:`LasChunkWriter` write for ``cloud`` (or its first chunk):
    point format 7 (RGB) or 6, ``scale`` (metres) on x, y, z, ``offset`` (world metres), the CRS as WKT, one extra
    dim per :func:`_las_extras` entry (bool as uint8). :class:`ConfigError` for an unknown CRS, :class:`DataError`
    for a field dtype LAS cannot hold; ``path`` is named in both."""
    point_format = 7 if cloud.colors is not None else 6
    header = laspy.LasHeader(point_format=point_format, version="1.4")
    header.scales = np.array([scale] * 3)
    header.offsets = offset
    if crs:
        import pyproj

        try:
            header.add_crs(pyproj.CRS.from_user_input(crs))
        except pyproj.exceptions.CRSError as err:
            raise ConfigError(f"unknown CRS {crs!r} ({err})", path) from err
    for name, values in _las_extras(cloud).items():
        dtype = np.dtype(values.dtype)
        if dtype == np.bool_:
            dtype = np.dtype(np.uint8)
        if dtype not in _EXTRA_TYPES:
            raise DataError(f"field {name!r} of dtype {values.dtype} cannot be stored as a LAS extra dim", path)
        header.add_extra_dim(laspy.ExtraBytesParams(name=name[:32], type=dtype))
    return header


def _fill_points(
    points: laspy.LasData | laspy.ScaleAwarePointRecord, cloud: PointCloud, ints: np.ndarray, path: Path
) -> None:
    """Set the records of ``points`` (made from :func:`_las_header` of the same attributes) from ``cloud``: integer
    coordinates ``ints`` (N, 3) (float, already rounded and range-checked), classification (0..255, else
    :class:`DataError` naming ``path``), ``intensity``, RGB as 16-bit (value·257), the extra dims."""
    points.X = ints[:, 0].astype(np.int32)
    points.Y = ints[:, 1].astype(np.int32)
    points.Z = ints[:, 2].astype(np.int32)
    if "classification" in cloud.fields:
        cls = np.asarray(cloud.fields["classification"])
        if cls.size and (cls.min() < 0 or cls.max() > 255):
            raise DataError("classification codes must lie in 0..255 for LAS", path)
        points.classification = cls.astype(np.uint8)
    for name in _STANDARD_KEPT:
        if name in cloud.fields:
            points[name] = np.asarray(cloud.fields[name])
    if cloud.colors is not None:
        rgb16 = cloud.colors.astype(np.uint16) * 257
        points.red, points.green, points.blue = rgb16[:, 0], rgb16[:, 1], rgb16[:, 2]
    for name, values in _las_extras(cloud).items():
        points[name[:32]] = np.asarray(values).astype(np.uint8) if values.dtype == np.bool_ else values


class LasChunkWriter:
    """Writes point-cloud chunks (one origin, the same attributes) to one LAS 1.4 / LAZ file as :func:`write_las`
    writes a whole cloud (the same header and records: :func:`_las_header`, :func:`_fill_points`): ``scale`` (metres,
    default 1 mm), offset at the first chunk's origin rounded to the scale, ``crs`` as WKT. ``path`` is written
    directly (give a temporary name and rename after, e.g. :func:`core.io.atomic.atomic_path`); ``target`` (default
    ``path``) is the final name: its suffix chooses LAZ compression and errors name it. The header's counts and
    bounds are completed by laspy on :meth:`close`; :attr:`count` is the number of points written."""

    def __init__(self, path: Path, *, scale: float = 0.001, crs: str | None = None, target: Path | None = None):
        self.path, self.target, self.scale, self.crs = path, target or path, scale, crs
        self.writer = None
        self.count = 0
        self._first: laspy.ScaleAwarePointRecord | None = None  # the file's first record (extra-dim statistics)

    def _open(self, first: PointCloud) -> None:
        self.offset = np.round(first.origin / self.scale) * self.scale
        self.header = _las_header(first, self.offset, self.scale, self.crs, self.target)
        compress = self.target.suffix.lower() == ".laz"
        self.writer = laspy.open(self.path, mode="w", header=self.header, do_compress=compress)

    def write(self, cloud: PointCloud) -> None:
        """Append a chunk (positions relative to the first chunk's origin)."""
        if self.writer is None:
            self._open(cloud)
        ints = np.round((cloud.positions + (cloud.origin - self.offset)) / self.scale)
        limit = np.iinfo(np.int32).max
        if ints.size and np.abs(ints).max() > limit:
            raise DataError(f"coordinates span more than ±{limit * self.scale:.0f} m from the offset", self.target)
        rec = laspy.ScaleAwarePointRecord.zeros(len(ints), header=self.header)
        _fill_points(rec, cloud, ints, self.target)
        if self._first is None and len(rec):
            self._first = laspy.ScaleAwarePointRecord.zeros(1, header=self.header)
            self._first.array[0] = rec.array[0]
        self.writer.write_points(rec)
        self.count += len(ints)

    def close(self) -> None:
        """Complete the header and close the file. The extra dims' min and max in the header are those
        :func:`write_las` writes: laspy takes both from the first point of each write (it reads a scalar dim with
        ``[..., 0]``), so a whole-cloud write records the file's first point and a chunked one would record the
        extremes over each chunk's first point; they are set back to the first point's."""
        if self.writer is not None:
            stats = self.writer.header.vlrs.get("ExtraBytesVlr")
            if stats and self._first is not None:
                stats[0].partial_reset()
                stats[0].grow(self._first)
            self.writer.close()


def write_las_chunks(
    path: str | PathLike[str],
    chunks: Iterable[np.ndarray],
    origin: np.ndarray,
    *,
    scale: float = 0.001,
    crs: str | None = None,
) -> int:
    """Write positions given chunk by chunk ((n, 3) float64 metres relative to ``origin``, world = origin + local) as
    LAS 1.4 / LAZ with bounded memory (one chunk at a time; laspy fills in the bounds and counts on close),
    atomically. The offset is ``origin`` rounded to ``scale``. Returns the number of points written. Positions only:
    :func:`write_las` writes colours, classes and fields of an in-memory cloud."""
    path = Path(path)
    if path.suffix.lower() not in (".las", ".laz"):
        raise DataError(f"LAS output needs a .las or .laz suffix, got {path.suffix!r}", path)
    origin = np.asarray(origin, dtype=np.float64)
    offset = np.round(origin / scale) * scale
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([scale] * 3)
    header.offsets = offset
    if crs:
        import pyproj

        header.add_crs(pyproj.CRS.from_user_input(crs))
    limit = np.iinfo(np.int32).max
    count = 0
    with atomic_path(path) as tmp:
        with laspy.open(tmp, mode="w", header=header, do_compress=path.suffix.lower() == ".laz") as writer:
            for chunk in chunks:
                ints = np.round((np.asarray(chunk, dtype=np.float64) + (origin - offset)) / scale)
                if ints.size and np.abs(ints).max() > limit:
                    raise DataError(f"coordinates span more than ±{limit * scale:.0f} m from the offset", path)
                record = laspy.ScaleAwarePointRecord.zeros(len(ints), header=header)
                record.X, record.Y, record.Z = (ints[:, k].astype(np.int32) for k in range(3))
                writer.write_points(record)
                count += len(ints)
    return count
