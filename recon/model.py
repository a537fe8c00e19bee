"""Conversion between :class:`core.cameras.Cameras` and ``pycolmap.Reconstruction`` for recon.

Thin layer over :mod:`core.io.colmap` (the toolkit's COLMAP I/O): recon mostly needs cameras without points,
and a model reader that accepts a folder with ``cameras.*`` as pycolmap does.
"""

from __future__ import annotations

from pathlib import Path

from core.cameras import Cameras
from core.errors import FormatError, InputFileError
from core.io import colmap as colmap_io
from core.io.colmap_scan import scan_model


def to_reconstruction(cameras: Cameras):  # -> pycolmap.Reconstruction
    """A reconstruction with every camera (trivial rigs) and every view registered at its pose, no points."""
    return colmap_io.to_reconstruction(cameras)


def from_reconstruction(rec) -> Cameras:
    """Cameras and registered views of a ``pycolmap.Reconstruction`` (points are not converted)."""
    return colmap_io.from_reconstruction(rec)[0]


def read_reconstruction(path: str | Path):  # -> pycolmap.Reconstruction
    """Load a COLMAP model folder (binary or text), raising toolkit errors for missing/corrupt models."""
    import pycolmap

    path = Path(path)
    if not any((path / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
        raise InputFileError("no COLMAP model here (cameras.bin or cameras.txt missing)", path)
    scan_model(path)  # declared counts against file sizes before pycolmap allocates anything
    try:
        return pycolmap.Reconstruction(str(path))
    except Exception as err:  # pycolmap raises plain RuntimeError/ValueError on corrupt files
        raise FormatError(f"cannot read COLMAP model ({' '.join(str(err).split())[:200]})", path) from err
