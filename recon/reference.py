"""Readers of reference cameras that are not COLMAP models: Strecha et al. ``.camera`` files (fountain-P11).

Format (one file per image, ``NAME.camera``): K (3 rows), radial distortion (1 row), R (3 rows), camera
centre C (1 row), ``w h``; a world point X projects as ``K·[Rᵀ | −Rᵀ·C]·X`` (R is camera-to-world).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from core.cameras import Camera, Cameras, View
from core.errors import FormatError, InputFileError


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
