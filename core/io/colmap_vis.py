"""COLMAP's ``fused.ply.vis``: which images see each fused point.

Layout (little-endian, as ``pycolmap.stereo_fusion(..., output_type='PLY')`` writes it)::

    uint64 count                        number of points (equals the vertex count of fused.ply)
    count × { uint32 n; uint32 idx[n] } per point, the images that see it

``idx`` are POSITIONS in the fusion model's ``reg_image_ids()`` order (sorted image ids), not image ids
(see ``shared/notes/colmap-cpu-fusion.md``); :func:`positions_to_image_ids` maps them.

Written by hand: no library reads this COLMAP-internal file, and pycolmap exposes no reader.
"""

from __future__ import annotations

from collections.abc import Sequence
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import FormatError, InputFileError
from core.io.atomic import atomic_path

_HEADER_BYTES = 8


def read_vis(
    path: str | PathLike[str], num_points: int | None = None, num_images: int | None = None
) -> list[np.ndarray]:
    """Read ``fused.ply.vis``.

    Parameters
    ----------
    path:
        The ``.vis`` file.
    num_points:
        When given, the count in the file must equal it (the fused cloud's vertex count).
    num_images:
        When given, every position must be below it (the number of registered images of the model).

    Returns
    -------
    One (n_i,) int64 array per point: positions into the model's ``reg_image_ids()`` order.

    Raises :class:`InputFileError` when the file is missing, :class:`FormatError` when its size does not
    match its counts (truncated, trailing bytes, a count larger than the file could hold — checked before
    anything is allocated) or a position is out of range.
    """
    path = Path(path)
    if path.is_dir():
        raise InputFileError("is a folder, expected a visibility (.vis) file", path)
    if not path.is_file():
        raise InputFileError("visibility file does not exist", path)
    size = path.stat().st_size
    if size < _HEADER_BYTES:
        raise FormatError(f"visibility file is truncated: {size} bytes, the point count alone needs 8", path)
    if (size - _HEADER_BYTES) % 4:
        raise FormatError(f"visibility file size {size} is not 8 + a multiple of 4 bytes", path)
    with open(path, "rb") as f:
        count = int(np.frombuffer(f.read(_HEADER_BYTES), "<u8")[0])
        n_words = (size - _HEADER_BYTES) // 4
        if count > n_words:  # each point needs at least its uint32 n: refuse before allocating anything
            raise FormatError(
                f"visibility file declares {count} points but its {size} bytes hold at most {n_words}", path
            )
        if num_points is not None and count != num_points:
            raise FormatError(f"visibility file lists {count} points, the cloud has {num_points}", path)
        words = np.fromfile(f, dtype="<u4", count=n_words)
    out: list[np.ndarray] = []
    pos = 0
    for i in range(count):  # sequential: each record's start depends on the previous length
        n = int(words[pos]) if pos < n_words else -1
        if n < 0 or pos + 1 + n > n_words:
            raise FormatError(f"visibility file is truncated in point {i} of {count}", path)
        out.append(words[pos + 1 : pos + 1 + n].astype(np.int64))
        pos += 1 + n
    if pos != n_words:
        raise FormatError(f"visibility file has {4 * (n_words - pos)} bytes after its {count} points", path)
    if num_images is not None:
        worst = max((int(v.max()) for v in out if len(v)), default=-1)
        if worst >= num_images:
            raise FormatError(
                f"visibility position {worst} is out of range for the {num_images} registered images", path
            )
    return out


def write_vis(path: str | PathLike[str], visibility: Sequence[np.ndarray]) -> Path:
    """Write ``fused.ply.vis`` atomically: one array of non-negative positions (< 2^32) per point."""
    path = Path(path)
    parts = [np.array([len(visibility)], dtype="<u8").view("<u4")]
    for i, v in enumerate(visibility):
        v = np.asarray(v).reshape(-1)
        if len(v) and (v.min() < 0 or v.max() > np.iinfo(np.uint32).max):
            raise ValueError(f"visibility of point {i} holds positions outside uint32")
        parts.append(np.array([len(v)], dtype="<u4"))
        parts.append(v.astype("<u4"))
    with atomic_path(path) as tmp:
        np.concatenate(parts).astype("<u4").tofile(tmp)
    return path


def positions_to_image_ids(
    visibility: Sequence[np.ndarray], reg_image_ids: Sequence[int], path: str | PathLike[str] | None = None
) -> list[np.ndarray]:
    """Map per-point positions (into sorted ``reg_image_ids``) to COLMAP image ids (int64).

    Raises :class:`FormatError` (naming ``path``) when a position is out of range.
    """
    ids = np.asarray(sorted(int(i) for i in reg_image_ids), dtype=np.int64)
    worst = max((int(v.max()) for v in visibility if len(v)), default=-1)
    if worst >= len(ids):
        raise FormatError(f"visibility position {worst} is out of range for the {len(ids)} registered images", path)
    return [ids[np.asarray(v, dtype=np.int64)] for v in visibility]
