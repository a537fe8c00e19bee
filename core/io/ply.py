"""PLY point clouds through plyfile.

Reads binary little/big-endian and ASCII files with float or double positions, colours as uchar (0–255)
or float (0–1) named ``red/green/blue`` (or ``r/g/b``, ``diffuse_*``), normals ``nx/ny/nz`` and keeps every
other scalar vertex property as a named field. Positions are returned relative to a local origin: the
``<name>.origin.json`` sidecar when present, otherwise a rounded centre for georeferenced coordinates.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Literal

import numpy as np
import plyfile

from core.errors import DataError, FormatError, InputFileError
from core.io.atomic import atomic_path
from core.io.origin import read_origin, remove_origin, write_origin
from core.pointcloud import PointCloud, choose_origin

COLOR_NAMES = (("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green", "diffuse_blue"))
NORMAL_NAMES = ("nx", "ny", "nz")
# plyfile property type names for numpy dtypes PLY can hold.
_PLY_TYPES = {
    np.dtype(np.int8): "i1",
    np.dtype(np.uint8): "u1",
    np.dtype(np.int16): "i2",
    np.dtype(np.uint16): "u2",
    np.dtype(np.int32): "i4",
    np.dtype(np.uint32): "u4",
    np.dtype(np.float32): "f4",
    np.dtype(np.float64): "f8",
}


# PLY scalar type names (both spellings) -> size in bytes
_PLY_SIZES = {
    "char": 1, "int8": 1, "uchar": 1, "uint8": 1,
    "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
    "int": 4, "int32": 4, "uint": 4, "uint32": 4,
    "float": 4, "float32": 4, "double": 8, "float64": 8,
}  # fmt: skip
_MAX_HEADER = 1 << 20


@dataclass(frozen=True)
class PlyElementHeader:
    """One ``element`` of a PLY header: its name, declared count and properties.

    ``properties``: (name, type, list count type or None) in file order.
    """

    name: str
    count: int
    properties: tuple[tuple[str, str, str | None], ...]

    def min_bytes(self, binary: bool) -> int:
        """The fewest bytes ``count`` rows can take (lists may be empty)."""
        if binary:
            row = sum(_PLY_SIZES[t] if c is None else _PLY_SIZES[c] for _, t, c in self.properties)
            return self.count * row
        return max(0, self.count * 2 * len(self.properties) - 1)  # one digit and one separator per value


@dataclass(frozen=True)
class PlyHeader:
    """A parsed PLY header: ``format`` (ascii, binary_little_endian, binary_big_endian), elements,
    and ``data_offset``, the byte where the payload starts."""

    format: str
    elements: tuple[PlyElementHeader, ...]
    data_offset: int

    def element(self, name: str) -> PlyElementHeader | None:
        return next((e for e in self.elements if e.name == name), None)


def scan_ply_header(path: str | PathLike[str]) -> PlyHeader:
    """Parse and check a PLY header before any payload is read.

    Checks the magic, the format, every element count (a non-negative integer) and property type, and
    that the file is large enough for the declared counts (so that a header declaring 2^31 vertices over
    a few bytes is refused at once instead of allocating gigabytes). Raises :class:`InputFileError`
    (missing, folder, empty, truncated) or :class:`FormatError` naming the header line.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError("file does not exist" if not path.exists() else "is not a file", path)
    size = path.stat().st_size
    if size == 0:
        raise InputFileError("file is empty", path)
    try:
        with path.open("rb") as f:
            head = f.read(min(size, _MAX_HEADER))
    except OSError as err:
        raise InputFileError(f"cannot read file ({err.strerror or err})", path) from err
    if not head.startswith(b"ply"):
        raise FormatError("not a PLY file (it does not start with 'ply')", path)
    end = head.find(b"end_header")
    if end < 0:
        raise FormatError("PLY header has no 'end_header' line (file truncated or not PLY)", path)
    nl = head.find(b"\n", end)
    data_offset = (nl + 1) if nl >= 0 else len(head)
    try:
        lines = head[:end].decode("ascii").splitlines()
    except UnicodeDecodeError as err:
        raise FormatError("PLY header is not ASCII text", path) from err
    fmt = None
    elements: list[PlyElementHeader] = []
    current: tuple[str, int, list[tuple[str, str, str | None]]] | None = None
    for no, line in enumerate(lines[1:], 2):
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format":
            if len(tok) != 3 or tok[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise FormatError(f"PLY header line {no}: unknown format {' '.join(tok[1:])!r}", path)
            fmt = tok[1]
        elif tok[0] == "element":
            if len(tok) != 3 or not tok[2].isdigit():
                raise FormatError(f"PLY header line {no}: expected 'element NAME COUNT' with COUNT >= 0", path)
            if current is not None:
                elements.append(PlyElementHeader(current[0], current[1], tuple(current[2])))
            current = (tok[1], int(tok[2]), [])
        elif tok[0] == "property":
            if current is None:
                raise FormatError(f"PLY header line {no}: property before any element", path)
            if len(tok) == 3 and tok[1] in _PLY_SIZES:
                current[2].append((tok[2], tok[1], None))
            elif len(tok) == 5 and tok[1] == "list" and tok[2] in _PLY_SIZES and tok[3] in _PLY_SIZES:
                current[2].append((tok[4], tok[3], tok[2]))
            else:
                shown = " ".join(tok)[:60]
                raise FormatError(f"PLY header line {no}: unknown property declaration {shown!r}", path)
        else:
            raise FormatError(f"PLY header line {no}: unknown keyword {tok[0][:30]!r}", path)
    if current is not None:
        elements.append(PlyElementHeader(current[0], current[1], tuple(current[2])))
    if fmt is None:
        raise FormatError("PLY header has no 'format' line", path)
    header = PlyHeader(fmt, tuple(elements), data_offset)
    need = sum(e.min_bytes(fmt != "ascii") for e in elements)
    have = size - data_offset
    if need > have:
        counts = ", ".join(f"{e.count} {e.name}" for e in elements)
        raise InputFileError(
            f"PLY header declares {counts} needing at least {need} bytes, but only {have} bytes follow "
            "(file truncated or header count wrong)",
            path,
        )
    return header


def load_ply_data(path: str | PathLike[str]) -> plyfile.PlyData:
    """Parse a PLY file fully after :func:`scan_ply_header`; plyfile's and the OS's errors become
    :class:`InputFileError` / :class:`FormatError`."""
    path = Path(path)
    scan_ply_header(path)
    try:
        with path.open("rb") as f:
            return plyfile.PlyData.read(f)
    except plyfile.PlyHeaderParseError as err:
        raise FormatError(f"not a valid PLY header ({_short(err)})", path) from err
    except (plyfile.PlyElementParseError, ValueError, EOFError, IndexError, UnicodeDecodeError, TypeError) as err:
        raise InputFileError(f"PLY data is truncated or corrupt ({_short(err)})", path) from err
    except MemoryError as err:
        raise InputFileError(
            "PLY data declares more values than memory can hold (corrupt list lengths?)", path
        ) from err
    except OSError as err:
        raise InputFileError(f"cannot read file ({err.strerror or err})", path) from err


def _short(err: BaseException, limit: int = 120) -> str:
    text = " ".join(str(err).split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def scalar_column(vertex: np.ndarray, name: str, path: Path) -> np.ndarray:
    """A scalar (non-list) numeric vertex property, or :class:`FormatError` naming its declared type."""
    values = vertex[name]
    if values.dtype == object or not (np.issubdtype(values.dtype, np.number) or values.dtype == np.bool_):
        raise FormatError(f"PLY property {name!r} is a list, expected a single number per vertex", path)
    return np.asarray(values)


def read_ply(path: str | PathLike[str]) -> PointCloud:
    """Read the ``vertex`` element of a PLY file as a :class:`PointCloud`.

    Raises :class:`FormatError` when there is no vertex element or no x/y/z, :class:`DataError` on NaN/inf
    coordinates, :class:`InputFileError` for missing, empty or truncated files.
    """
    path = Path(path)
    data = load_ply_data(path)
    if "vertex" not in data:
        raise FormatError("PLY file has no 'vertex' element", path)
    vertex = data["vertex"].data
    names = list(vertex.dtype.names or ())
    missing = [n for n in ("x", "y", "z") if n not in names]
    if missing:
        raise FormatError(f"PLY vertex element lacks {', '.join(missing)} (has: {', '.join(names) or 'nothing'})", path)

    xyz = np.stack([scalar_column(vertex, n, path).astype(np.float64) for n in ("x", "y", "z")], axis=1)
    bad = ~np.isfinite(xyz).all(axis=1)
    if bad.any():
        raise DataError(
            f"{int(bad.sum())} of {len(xyz)} points have NaN or infinite coordinates "
            f"(first: vertex {int(np.flatnonzero(bad)[0])})",
            path,
        )
    origin = read_origin(path)
    extra_origin = choose_origin(xyz)  # non-zero only for georeferenced payloads
    positions = xyz - extra_origin
    origin = origin + extra_origin

    used = {"x", "y", "z"}
    colors = None
    for triple in COLOR_NAMES:
        if all(n in names for n in triple):
            raw = np.stack([scalar_column(vertex, n, path) for n in triple], axis=1)
            colors = colors_from_ply(raw, path)
            used.update(triple)
            break
    normals = None
    if all(n in names for n in NORMAL_NAMES):
        normals = np.stack([scalar_column(vertex, n, path).astype(np.float32) for n in NORMAL_NAMES], axis=1)
        used.update(NORMAL_NAMES)

    fields: dict[str, np.ndarray] = {}
    skipped = []
    for name in names:
        if name in used:
            continue
        values = vertex[name]
        if values.dtype == object:  # list property
            skipped.append(name)
            continue
        fields[name] = np.asarray(values).astype(values.dtype.newbyteorder("="))
    if skipped:
        warnings.warn(f"{path}: list properties ignored: {', '.join(skipped)}", stacklevel=2)
    return PointCloud(positions, origin, colors, normals, fields)


def colors_from_ply(raw: np.ndarray, path: Path) -> np.ndarray:
    if np.issubdtype(raw.dtype, np.floating):
        if not np.isfinite(raw).all():
            raise DataError("colours contain NaN or infinite values", path)
        return np.clip(np.round(raw.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
    if raw.dtype.itemsize > 1 and raw.max(initial=0) > 255:  # 16-bit colours
        return (raw.astype(np.float64) / 257.0).round().astype(np.uint8)
    return raw.astype(np.uint8)


def write_ply(
    path: str | PathLike[str],
    cloud: PointCloud,
    *,
    binary: bool = True,
    byte_order: Literal["<", ">"] = "<",
    position_dtype: Literal["f4", "f8"] = "f4",
    coordinates: Literal["local", "world"] = "local",
    color_dtype: Literal["u1", "f4"] = "u1",
) -> Path:
    """Write a point cloud as PLY, atomically.

    ``coordinates="local"`` (default) writes positions relative to ``cloud.origin`` and, when the origin is
    not zero, a ``<name>.origin.json`` sidecar; ``"world"`` writes float64 world coordinates (for tools that
    ignore sidecars, e.g. CloudCompare with its own global shift) and no sidecar. Scalar fields are written
    with their dtype (int64 → int32 when it fits, else float64; bool → uint8).
    """
    path = Path(path)
    vertex = ply_vertex_rows(cloud, byte_order, position_dtype, coordinates, color_dtype)
    element = plyfile.PlyElement.describe(vertex, "vertex")
    ply = plyfile.PlyData([element], text=not binary, byte_order=byte_order if binary else "=")
    with atomic_path(path) as tmp:
        ply.write(str(tmp))
    if coordinates == "local" and np.any(cloud.origin != 0):
        write_origin(path, cloud.origin)
    else:
        remove_origin(path)
    return path


def ply_vertex_rows(
    cloud: PointCloud,
    byte_order: Literal["<", ">"] = "<",
    position_dtype: Literal["f4", "f8"] = "f4",
    coordinates: Literal["local", "world"] = "local",
    color_dtype: Literal["u1", "f4"] = "u1",
) -> np.ndarray:
    """The vertex rows (N,) structured array that :func:`write_ply` writes for ``cloud`` (same options; ``world``
    writes float64 whatever ``position_dtype`` says): a chunked writer appends these after
    :func:`ply_vertex_header` to write the same file chunk by chunk."""
    if coordinates == "world":
        xyz, position_dtype = cloud.world_positions, "f8"
    else:
        xyz = cloud.positions
    columns: list[tuple[str, np.ndarray]] = [(n, xyz[:, i].astype(position_dtype)) for i, n in enumerate("xyz")]
    if cloud.normals is not None:
        columns += [(n, cloud.normals[:, i].astype("f4")) for i, n in enumerate(NORMAL_NAMES)]
    if cloud.colors is not None:
        c = cloud.colors if color_dtype == "u1" else cloud.colors.astype(np.float32) / 255.0
        columns += [(n, c[:, i]) for i, n in enumerate(("red", "green", "blue"))]
    for name, values in cloud.fields.items():
        columns.append((name, _ply_compatible(values)))
    dtype = np.dtype([(name, byte_order + _PLY_TYPES[np.dtype(v.dtype)]) for name, v in columns])
    vertex = np.empty(len(cloud), dtype=dtype)
    for name, values in columns:
        vertex[name] = values
    return vertex


def ply_vertex_header(rows_dtype: np.dtype, count: int, byte_order: Literal["<", ">"] = "<") -> bytes:
    """The binary PLY header :func:`write_ply` (through plyfile) writes for ``count`` vertex rows of ``rows_dtype``
    (a :func:`ply_vertex_rows` dtype)."""
    element = plyfile.PlyElement.describe(np.empty(0, dtype=rows_dtype), "vertex")
    header = plyfile.PlyData([element], text=False, byte_order=byte_order).header
    return (header.replace("element vertex 0\n", f"element vertex {count}\n", 1) + "\n").encode("ascii")


def _ply_compatible(values: np.ndarray) -> np.ndarray:
    v = np.asarray(values)
    if v.dtype == np.bool_:
        return v.astype(np.uint8)
    if v.dtype == np.int64 or v.dtype == np.uint64:
        if v.size == 0 or (v.min() >= np.iinfo(np.int32).min and v.max() <= np.iinfo(np.int32).max):
            return v.astype(np.int32)
        return v.astype(np.float64)
    if np.dtype(v.dtype.newbyteorder("=")) in _PLY_TYPES:
        return v.astype(v.dtype.newbyteorder("="))
    if np.issubdtype(v.dtype, np.floating):
        return v.astype(np.float64)
    raise DataError(f"field of dtype {v.dtype} cannot be stored in PLY")
