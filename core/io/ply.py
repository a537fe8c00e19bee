"""PLY point clouds through plyfile.

Reads binary little/big-endian and ASCII files with float or double positions, colours as uchar (0–255)
or float (0–1) named ``red/green/blue`` (or ``r/g/b``, ``diffuse_*``), normals ``nx/ny/nz`` and keeps every
other scalar vertex property as a named field. Positions are returned relative to a local origin: the
``<name>.origin.json`` sidecar when present, otherwise a rounded centre for georeferenced coordinates.
"""

from __future__ import annotations

import warnings
from os import PathLike
from pathlib import Path
from typing import Literal

import numpy as np
import plyfile

from core.errors import DataError, FormatError, InputFileError
from core.io.atomic import atomic_path
from core.io.origin import read_origin, remove_origin, write_origin
from core.pointcloud import PointCloud, choose_origin

_COLOR_NAMES = (("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green", "diffuse_blue"))
_NORMAL_NAMES = ("nx", "ny", "nz")
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


def load_ply_data(path: str | PathLike[str]) -> plyfile.PlyData:
    """Parse a PLY file fully; plyfile's and the OS's errors become :class:`InputFileError` / :class:`FormatError`."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError("file does not exist" if not path.exists() else "is not a file", path)
    if path.stat().st_size == 0:
        raise InputFileError("file is empty", path)
    try:
        with path.open("rb") as f:
            return plyfile.PlyData.read(f)
    except plyfile.PlyHeaderParseError as err:
        raise FormatError(f"not a valid PLY header ({err})", path) from err
    except (plyfile.PlyElementParseError, ValueError, EOFError, IndexError, UnicodeDecodeError) as err:
        raise InputFileError(f"PLY data is truncated or corrupt ({err})", path) from err
    except OSError as err:
        raise InputFileError(f"cannot read file ({err.strerror or err})", path) from err


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

    xyz = np.stack([np.asarray(vertex[n], dtype=np.float64) for n in ("x", "y", "z")], axis=1)
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
    for triple in _COLOR_NAMES:
        if all(n in names for n in triple):
            raw = np.stack([np.asarray(vertex[n]) for n in triple], axis=1)
            colors = _colors_from_ply(raw, path)
            used.update(triple)
            break
    normals = None
    if all(n in names for n in _NORMAL_NAMES):
        normals = np.stack([np.asarray(vertex[n], dtype=np.float32) for n in _NORMAL_NAMES], axis=1)
        used.update(_NORMAL_NAMES)

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


def _colors_from_ply(raw: np.ndarray, path: Path) -> np.ndarray:
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
    if coordinates == "world":
        xyz = cloud.world_positions
        position_dtype = "f8"
    else:
        xyz = cloud.positions
    columns: list[tuple[str, np.ndarray]] = [(n, xyz[:, i].astype(position_dtype)) for i, n in enumerate("xyz")]
    if cloud.normals is not None:
        columns += [(n, cloud.normals[:, i].astype("f4")) for i, n in enumerate(_NORMAL_NAMES)]
    if cloud.colors is not None:
        c = cloud.colors if color_dtype == "u1" else cloud.colors.astype(np.float32) / 255.0
        columns += [(n, c[:, i]) for i, n in enumerate(("red", "green", "blue"))]
    for name, values in cloud.fields.items():
        columns.append((name, _ply_compatible(values)))

    dtype = np.dtype([(name, byte_order + _PLY_TYPES[np.dtype(v.dtype)]) for name, v in columns])
    vertex = np.empty(len(cloud), dtype=dtype)
    for name, values in columns:
        vertex[name] = values
    element = plyfile.PlyElement.describe(vertex, "vertex")
    ply = plyfile.PlyData([element], text=not binary, byte_order=byte_order if binary else "=")
    with atomic_path(path) as tmp:
        ply.write(str(tmp))
    if coordinates == "local" and np.any(cloud.origin != 0):
        write_origin(path, cloud.origin)
    else:
        remove_origin(path)
    return path


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
