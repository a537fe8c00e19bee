"""Conversion between :class:`core.cameras.Cameras` and ``pycolmap.Reconstruction``.

Local to recon until ``core.io.colmap`` offers the same (``to_reconstruction`` / ``from_reconstruction``).
Poses are world-to-camera in both; the Cameras' float64 ``origin`` is not part of a COLMAP model and is
carried separately by the callers (models are written in the local frame).
"""

from __future__ import annotations

import numpy as np

from core.cameras import Camera, CameraModel, Cameras, View


def camera_to_pycolmap(cam: Camera):  # -> pycolmap.Camera
    import pycolmap

    return pycolmap.Camera(
        model=cam.model.value, width=int(cam.width), height=int(cam.height), params=cam.params, camera_id=cam.camera_id
    )


def to_reconstruction(cameras: Cameras):  # -> pycolmap.Reconstruction
    """A reconstruction with every camera (trivial rigs) and every view registered at its pose, no points."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    for cam in cameras.cameras.values():
        rec.add_camera_with_trivial_rig(camera_to_pycolmap(cam))
    for view in cameras:
        image = pycolmap.Image(name=view.name, camera_id=view.camera_id, image_id=view.image_id)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(_wxyz_to_xyzw(view.quat_wxyz)), view.translation)
        rec.add_image_with_trivial_frame(image, pose)
    return rec


def from_reconstruction(rec) -> Cameras:
    """Cameras and registered views of a ``pycolmap.Reconstruction`` (points are not converted)."""
    cams = {
        int(cid): Camera(CameraModel(c.model.name), int(c.width), int(c.height), np.asarray(c.params), int(cid))
        for cid, c in rec.cameras.items()
    }
    views = {}
    for iid in rec.reg_image_ids():
        im = rec.image(iid)
        m = np.asarray(im.cam_from_world().matrix(), dtype=np.float64)
        views[int(iid)] = View.from_matrix(int(iid), im.name, int(im.camera_id), m)
    return Cameras(cams, views)


def _wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    return np.array([q[1], q[2], q[3], q[0]], dtype=np.float64)


def read_reconstruction(path):  # -> pycolmap.Reconstruction
    """Load a COLMAP model folder (binary or text), raising toolkit errors for missing/corrupt models."""
    from pathlib import Path

    import pycolmap

    from core.errors import FormatError, InputFileError

    path = Path(path)
    if not any((path / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
        raise InputFileError("no COLMAP model here (cameras.bin or cameras.txt missing)", path)
    try:
        return pycolmap.Reconstruction(str(path))
    except Exception as err:  # pycolmap raises plain RuntimeError/ValueError on corrupt files
        raise FormatError(f"cannot read COLMAP model ({err})", path) from err
