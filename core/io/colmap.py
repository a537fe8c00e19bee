"""COLMAP sparse models (cameras, images, points3D; ``.bin`` or ``.txt``) through pycolmap.

:func:`from_reconstruction` / :func:`to_reconstruction` convert between ``pycolmap.Reconstruction`` and the
toolkit's :class:`~core.cameras.Cameras` + :class:`~core.pointcloud.PointCloud` (sparse points with colours,
reprojection ``error`` and track ``visibility`` as image ids). Poses stay COLMAP's world-to-camera.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
import pycolmap

from core.cameras import Camera, CameraModel, Cameras, View
from core.errors import ConfigError, DataError, FormatError
from core.io.atomic import atomic_path
from core.io.colmap_scan import scan_model
from core.pointcloud import PointCloud

_MODEL_FILES = ("cameras", "images", "points3D")


def _model_name(model: object) -> str:
    name = getattr(model, "name", None)
    return str(name) if name is not None else str(model).split(".")[-1]


def from_reconstruction(rec: pycolmap.Reconstruction) -> tuple[Cameras, PointCloud]:
    """Cameras (registered images only) and sparse points of a pycolmap reconstruction."""
    cameras: dict[int, Camera] = {}
    for cam_id, cam in rec.cameras.items():
        model = _model_name(cam.model)
        if model not in CameraModel.__members__:
            raise FormatError(f"camera {cam_id} uses COLMAP model {model}, which the toolkit does not support")
        cameras[cam_id] = Camera(CameraModel(model), cam.width, cam.height, np.asarray(cam.params), cam_id)
    views: dict[int, View] = {}
    for image_id in rec.reg_image_ids():
        image = rec.image(image_id)
        pose = image.cam_from_world()
        xyzw = np.asarray(pose.rotation.quat, dtype=np.float64)
        views[image_id] = View(
            image_id, image.name, image.camera_id, np.r_[xyzw[3], xyzw[:3]], np.asarray(pose.translation)
        )
    ids = sorted(rec.point3D_ids())
    if ids:
        pts = [rec.point3D(i) for i in ids]
        xyz = np.array([p.xyz for p in pts], dtype=np.float64)
        rgb = np.array([p.color for p in pts], dtype=np.uint8)
        err = np.array([p.error for p in pts], dtype=np.float64)
        vis = [np.unique([el.image_id for el in p.track.elements]) for p in pts]
        cloud = PointCloud(
            xyz, colors=rgb, fields={"error": err, "point3D_id": np.array(ids, np.int64)}, visibility=vis
        )
    else:
        cloud = PointCloud(np.zeros((0, 3)), colors=np.zeros((0, 3), np.uint8), visibility=[])
    return Cameras(cameras, views), cloud


def camera_to_pycolmap(cam: Camera) -> pycolmap.Camera:
    """The pycolmap camera with the same model, size, parameters and id."""
    return pycolmap.Camera(
        model=cam.model.value, width=int(cam.width), height=int(cam.height), params=cam.params, camera_id=cam.camera_id
    )


def to_reconstruction(cameras: Cameras, points: PointCloud | None = None) -> pycolmap.Reconstruction:
    """A pycolmap reconstruction with the given cameras and posed images (trivial rigs and frames).

    Points are added without tracks (pycolmap needs 2D observations for tracks; recon's triangulation
    adds real ones).
    """
    rec = pycolmap.Reconstruction()
    for cam_id in sorted(cameras.cameras):
        rec.add_camera_with_trivial_rig(camera_to_pycolmap(cameras.cameras[cam_id]))
    for view in cameras:
        image = pycolmap.Image(name=view.name, camera_id=view.camera_id, image_id=view.image_id)
        q = view.quat_wxyz
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(np.r_[q[1:], q[0]]), view.translation)
        rec.add_image_with_trivial_frame(image, pose)
    if points is not None and len(points):
        colors = points.colors if points.colors is not None else np.full((len(points), 3), 128, np.uint8)
        for xyz, rgb in zip(points.positions, colors, strict=True):
            rec.add_point3D(xyz, pycolmap.Track(), rgb)
    return rec


def read_model(path: str | PathLike[str]) -> tuple[Cameras, PointCloud]:
    """Read a COLMAP sparse model folder (binary or text) as cameras and sparse points."""
    path = Path(path)
    scan_model(path)  # counts against file sizes, ids, finiteness: before pycolmap trusts any count
    has_bin = all((path / f"{n}.bin").is_file() for n in _MODEL_FILES)
    rec = pycolmap.Reconstruction()
    try:
        if has_bin:
            rec.read_binary(str(path))
        else:
            rec.read_text(str(path))
    except Exception as err:  # pycolmap raises RuntimeError/ValueError from C++ checks
        raise FormatError(f"cannot read COLMAP model ({' '.join(str(err).split())[:200]})", path) from err
    try:
        return from_reconstruction(rec)
    except (ConfigError, DataError, FormatError) as err:
        culprit = "cameras" if "camera" in err.problem else "images"
        raise FormatError(err.problem, path / f"{culprit}{'.bin' if has_bin else '.txt'}") from err


def write_model(
    path: str | PathLike[str],
    cameras: Cameras,
    points: PointCloud | None = None,
    *,
    binary: bool = True,
    reconstruction: pycolmap.Reconstruction | None = None,
) -> Path:
    """Write a COLMAP sparse model folder (``.bin`` by default, ``.txt`` with ``binary=False``).

    Pass ``reconstruction`` to write a pycolmap model as is (keeping tracks); otherwise one is built from
    ``cameras`` and ``points``. Files are written to a temporary folder first and moved into place.
    """
    path = Path(path)
    rec = reconstruction if reconstruction is not None else to_reconstruction(cameras, points)
    path.mkdir(parents=True, exist_ok=True)
    suffix = ".bin" if binary else ".txt"
    tmp_dir = path / ".tmp_write"
    tmp_dir.mkdir(exist_ok=True)
    try:
        if binary:
            rec.write_binary(str(tmp_dir))
        else:
            rec.write_text(str(tmp_dir))
        for name in _MODEL_FILES:
            with atomic_path(path / f"{name}{suffix}") as tmp:
                (tmp_dir / f"{name}{suffix}").replace(tmp)
        for extra in tmp_dir.iterdir():  # rigs / frames files of newer COLMAP versions
            extra.replace(path / extra.name)
    finally:
        for leftover in tmp_dir.glob("*"):
            leftover.unlink()
        tmp_dir.rmdir()
    return path
