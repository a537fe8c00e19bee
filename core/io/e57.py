"""E57 point clouds (read) through pye57.

All scans of the file are read (with each scan's pose applied by pye57) and concatenated in world
coordinates, then expressed relative to a local origin. Colours and intensity are kept when present.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import FormatError, InputFileError
from core.pointcloud import PointCloud, choose_origin


def read_e57(path: str | PathLike[str]) -> PointCloud:
    """Read every scan of an E57 file as one :class:`PointCloud`."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError("file does not exist" if not path.exists() else "is not a file", path)
    if path.stat().st_size == 0:
        raise InputFileError("file is empty", path)
    try:
        import pye57
    except ImportError as err:  # pragma: no cover - pye57 is a dependency
        raise FormatError("reading E57 needs the package pye57 (pip install pye57)", path) from err
    try:
        e57 = pye57.E57(str(path))
        scans = [
            e57.read_scan(i, colors=_has_color(e57, i), intensity=_has_intensity(e57, i), ignore_missing_fields=True)
            for i in range(e57.scan_count)
        ]
    except Exception as err:  # pye57 raises its own libE57 exceptions
        text = " ".join(str(err).split())
        text = text.split("(Error")[0].strip() or text  # libE57 appends a multi-line context dump
        raise FormatError(f"not a readable E57 file ({text[:120]})", path) from err
    if not scans:
        raise InputFileError("E57 file holds no scans", path)
    world = np.concatenate(
        [np.stack([s["cartesianX"], s["cartesianY"], s["cartesianZ"]], axis=1).astype(np.float64) for s in scans]
    )
    origin = choose_origin(world)
    colors = None
    if all("colorRed" in s for s in scans):
        colors = np.concatenate(
            [np.stack([s["colorRed"], s["colorGreen"], s["colorBlue"]], axis=1) for s in scans]
        ).astype(np.uint8)
    fields = {}
    if all("intensity" in s for s in scans):
        fields["intensity"] = np.concatenate([np.asarray(s["intensity"], np.float32) for s in scans])
    return PointCloud(world - origin, origin, colors, None, fields)


def _has_color(e57: object, index: int) -> bool:
    header = e57.get_header(index)  # type: ignore[attr-defined]
    return "colorRed" in header.point_fields


def _has_intensity(e57: object, index: int) -> bool:
    header = e57.get_header(index)  # type: ignore[attr-defined]
    return "intensity" in header.point_fields
