"""Readers of reference cameras that are not COLMAP models: Strecha et al. ``.camera`` files (fountain-P11), and
camera centres for alignment in COLMAP model_aligner's text format (``NAME X Y Z`` per line) in any unit, converted
to metres on input (the toolkit's internal unit, docs/conventions.md).

Format (one file per image, ``NAME.camera``): K (3 rows), radial distortion (1 row), R (3 rows), camera
centre C (1 row), ``w h``; a world point X projects as ``K·[Rᵀ | −Rᵀ·C]·X`` (R is camera-to-world).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from core.cameras import Camera, Cameras, View
from core.errors import ConfigError, FormatError, InputFileError


def read_strecha_camera(path: str | Path, image_id: int = 1, camera_id: int = 1) -> tuple[Camera, View]:
    """One ``.camera`` file → (PINHOLE Camera, View named after the file without ``.camera``)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError("camera file does not exist", path)
    rows = [line.split() for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    try:
        K = np.array(rows[0:3], dtype=np.float64)
        R = np.array(rows[4:7], dtype=np.float64)
        C = np.array(rows[7], dtype=np.float64)
        w, h = (int(float(v)) for v in rows[8][:2])
    except (ValueError, IndexError) as err:
        raise FormatError(f"not a Strecha .camera file ({err})", path) from err
    if K.shape != (3, 3) or R.shape != (3, 3) or C.shape != (3,):
        raise FormatError("not a Strecha .camera file (expected K 3x3, R 3x3, C 3)", path)
    cam = Camera.pinhole(K[0, 0], K[1, 1], K[0, 2], K[1, 2], w, h, camera_id)
    Rcw = R.T  # world-to-camera
    view = View.from_matrix(image_id, path.name.removesuffix(".camera"), camera_id, np.c_[Rcw, -Rcw @ C])
    return cam, view


def read_strecha_cameras(folder: str | Path) -> Cameras:
    """All ``*.camera`` files of a folder, one camera per image, ids in name order."""
    folder = Path(folder)
    files = sorted(folder.glob("*.camera"))
    if not files:
        raise InputFileError("no .camera files here", folder)
    cams, views = {}, {}
    for i, f in enumerate(files, start=1):
        cam, view = read_strecha_camera(f, i, i)
        cams[i], views[i] = cam, view
    return Cameras(cams, views)


METRES_PER_UNIT = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "ft": 0.3048}


def metres_per_unit(units: str) -> float:
    try:
        return METRES_PER_UNIT[units]
    except KeyError as err:
        raise ConfigError(f"unknown unit {units!r} (known: {', '.join(METRES_PER_UNIT)})") from err


def read_reference_centers(path: str | PathLike[str], units: str = "m") -> dict[str, np.ndarray]:
    """Camera centres by image name, in metres (float64), from a text file or a COLMAP model folder."""
    path = Path(path)
    scale = metres_per_unit(units)
    if path.is_dir():
        from recon.model import from_reconstruction, read_reconstruction

        return {v.name: v.center * scale for v in from_reconstruction(read_reconstruction(path))}
    if not path.is_file():
        raise InputFileError("reference not found (a NAME X Y Z text file or a COLMAP model folder)", path)
    centers: dict[str, np.ndarray] = {}
    for number, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        parts = text.split()
        if len(parts) != 4:
            raise FormatError(f"line {number}: expected 'NAME X Y Z', got {line.strip()!r}", path)
        try:
            xyz = np.array([float(v) for v in parts[1:]], dtype=np.float64)
        except ValueError as err:
            raise FormatError(f"line {number}: coordinates must be numbers ({err})", path) from err
        if not np.all(np.isfinite(xyz)):
            raise FormatError(f"line {number}: coordinates must be finite", path)
        centers[parts[0]] = xyz * scale
    if len(centers) < 3:
        raise FormatError(f"needs at least 3 camera centres to align, found {len(centers)}", path)
    return centers
