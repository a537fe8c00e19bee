"""COLMAP dense workspace: layout, depth/normal map files, setup from a sparse model and import.

Layout (what ``pycolmap.stereo_fusion`` reads and ``pycolmap.undistort_images`` writes)::

    dense/
      images/NAME                      undistorted (pinhole) images, possibly downscaled
      sparse/                          the undistorted model: cameras, images AND 3D points with tracks
      stereo/fusion.cfg                one image name per line
      stereo/depth_maps/NAME.{geometric,photometric}.bin
      stereo/normal_maps/NAME.{geometric,photometric}.bin
      fused.ply, fused.ply.vis         the fused cloud and, per point, the images that see it

Map files: ASCII header ``W&H&C&`` then little-endian float32, one channel after another (planar).
Depth maps hold z-depth along the optical axis (<= 0 invalid); normal maps hold camera-frame unit normals
facing the camera. COLMAP's dense stage back-projects array element (row, col) along ``K⁻¹·(col, row, 1)``
(no +0.5): writers of depth maps must follow that convention (see :mod:`recon.mvs_cpu`).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import FormatError, InputFileError, ReconstructionError
from core.io import colmap_vis
from core.io.atomic import atomic_path
from core.io.colmap_scan import scan_model
from core.pointcloud import PointCloud

MAP_SUFFIXES = ("geometric", "photometric")


# -- map files --------------------------------------------------------------------------------------
def write_array(path: str | PathLike[str], array: np.ndarray) -> None:
    """Write an (H, W) or (H, W, C) array as a COLMAP map file (float32, planar channels), atomically."""
    a = np.asarray(array, dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3:
        raise FormatError(f"map must be (H, W) or (H, W, C), got shape {a.shape}", path)
    h, w, c = a.shape
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(f"{w}&{h}&{c}&".encode("ascii"))
        f.write(np.ascontiguousarray(a.transpose(2, 0, 1)).astype("<f4").tobytes())


def read_array(path: str | PathLike[str]) -> np.ndarray:
    """Read a COLMAP map file as (H, W) float32 (one channel) or (H, W, C) float32."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError("map file does not exist", path)
    data = path.read_bytes()
    parts = data.split(b"&", 3)
    try:
        w, h, c = (int(p) for p in parts[:3])
    except (ValueError, IndexError) as err:
        raise FormatError("not a COLMAP map file (header 'W&H&C&' missing)", path) from err
    payload = parts[3] if len(parts) > 3 else b""
    if w <= 0 or h <= 0 or c <= 0 or len(payload) != 4 * w * h * c:
        raise FormatError(f"map payload has {len(payload)} bytes, header {w}x{h}x{c} needs {4 * w * h * c}", path)
    a = np.frombuffer(payload, dtype="<f4").reshape(c, h, w).transpose(1, 2, 0).astype(np.float32)
    return a[:, :, 0] if c == 1 else a


# -- workspace layout -------------------------------------------------------------------------------
@dataclass(frozen=True)
class DenseWorkspace:
    """Paths of a COLMAP dense workspace rooted at ``root``."""

    root: Path

    @property
    def images(self) -> Path:
        return self.root / "images"

    @property
    def sparse(self) -> Path:
        return self.root / "sparse"

    @property
    def stereo(self) -> Path:
        return self.root / "stereo"

    @property
    def fused_ply(self) -> Path:
        return self.root / "fused.ply"

    @property
    def fused_vis(self) -> Path:
        return self.root / "fused.ply.vis"

    def depth_map(self, name: str, kind: str = "geometric") -> Path:
        return self.stereo / "depth_maps" / f"{name}.{kind}.bin"

    def normal_map(self, name: str, kind: str = "geometric") -> Path:
        return self.stereo / "normal_maps" / f"{name}.{kind}.bin"

    def make_dirs(self) -> None:
        for sub in (self.images, self.sparse, self.stereo / "depth_maps", self.stereo / "normal_maps"):
            sub.mkdir(parents=True, exist_ok=True)

    def write_fusion_cfg(self, names: list[str]) -> None:
        """``stereo/fusion.cfg``: the images to fuse, one per line."""
        with atomic_path(self.stereo / "fusion.cfg") as tmp:
            tmp.write_text("".join(f"{n}\n" for n in names), encoding="utf-8")

    def map_kind(self, name: str) -> str | None:
        """'geometric' or 'photometric' when both maps of ``name`` exist (geometric preferred), else None."""
        for kind in MAP_SUFFIXES:
            if self.depth_map(name, kind).is_file() and self.normal_map(name, kind).is_file():
                return kind
        return None


def setup_dense_workspace(
    sparse_dir: str | PathLike[str],
    image_dir: str | PathLike[str],
    dense_dir: str | PathLike[str],
    max_image_size: int = -1,
) -> DenseWorkspace:
    """Undistort the images of a sparse model into a fresh dense workspace (``pycolmap.undistort_images``).

    ``max_image_size`` (pixels, -1 = keep) caps the longer side of the undistorted images; the dense model's
    cameras are scaled accordingly. Existing ``images/``, ``sparse/`` and ``stereo/`` under ``dense_dir`` are replaced.
    """
    import pycolmap

    sparse_dir, image_dir, dense = Path(sparse_dir), Path(image_dir), Path(dense_dir)
    if not (sparse_dir / "cameras.bin").is_file() and not (sparse_dir / "cameras.txt").is_file():
        raise InputFileError("no COLMAP sparse model (cameras.bin / cameras.txt) here", sparse_dir)
    scan_model(sparse_dir)  # declared counts against file sizes before pycolmap allocates anything
    ws = DenseWorkspace(dense)
    for sub in (ws.images, ws.sparse, ws.stereo):
        if sub.exists():
            shutil.rmtree(sub)
    dense.mkdir(parents=True, exist_ok=True)
    opts = pycolmap.UndistortCameraOptions()
    opts.max_image_size = int(max_image_size)
    pycolmap.undistort_images(
        output_path=str(dense), input_path=str(sparse_dir), image_path=str(image_dir), undistort_options=opts
    )
    ws.make_dirs()
    return ws


# -- import -----------------------------------------------------------------------------------------
def read_vis(path: str | PathLike[str], num_points: int | None = None) -> list[np.ndarray]:
    """Read ``fused.ply.vis``: per point, positions (int64) into the model's ``reg_image_ids()`` order.

    Thin wrapper of :func:`core.io.colmap_vis.read_vis` (the one reader of this file).
    """
    return colmap_vis.read_vis(path, num_points)


def write_vis(path: str | PathLike[str], visibility: list[np.ndarray]) -> None:
    """Write ``fused.ply.vis``; thin wrapper of :func:`core.io.colmap_vis.write_vis`."""
    colmap_vis.write_vis(path, visibility)


def read_fused(dense_dir: str | PathLike[str]) -> PointCloud:
    """The fused cloud of a dense workspace, with ``visibility`` as COLMAP image ids (not vis-file positions)."""
    import pycolmap

    from core.io.ply import read_ply

    ws = DenseWorkspace(Path(dense_dir))
    if not ws.fused_ply.is_file():
        raise InputFileError("dense workspace has no fused.ply", ws.root)
    cloud = read_ply(ws.fused_ply)
    if ws.fused_vis.is_file():
        vis = read_vis(ws.fused_vis, len(cloud))
        rec = pycolmap.Reconstruction(str(ws.sparse))
        cloud.visibility = colmap_vis.positions_to_image_ids(vis, rec.reg_image_ids(), ws.fused_vis)
    return cloud


def import_dense_workspace(source: str | PathLike[str], dense_dir: str | PathLike[str]) -> DenseWorkspace:
    """Copy an existing COLMAP dense workspace (e.g. from COLMAP's GUI) into ``dense_dir`` and validate it.

    Accepts a workspace with ``sparse/`` and ``images/`` plus either ``fused.ply`` (+ ``.vis``) or depth and
    normal maps to fuse (run :func:`recon.mvs.fuse` afterwards). Raises :class:`InputFileError` when neither exists.
    """
    src, dst = Path(source), Path(dense_dir)
    src_ws = DenseWorkspace(src)
    if not src_ws.sparse.is_dir() or not src_ws.images.is_dir():
        raise InputFileError("not a COLMAP dense workspace (needs sparse/ and images/)", src)
    has_maps = any((src_ws.stereo / "depth_maps").glob("*.bin")) if (src_ws.stereo / "depth_maps").is_dir() else False
    if not src_ws.fused_ply.is_file() and not has_maps:
        raise InputFileError("dense workspace has neither fused.ply nor stereo/depth_maps/*.bin", src)
    if src.resolve() != dst.resolve():
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(src, dst)
    ws = DenseWorkspace(dst)
    if ws.fused_ply.is_file():
        read_fused(dst)  # validates ply + vis against the model
    return ws


def check_fused_nonempty(ws: DenseWorkspace) -> None:
    """Raise :class:`ReconstructionError` when fusion produced no points."""
    if not ws.fused_ply.is_file():
        raise ReconstructionError("fusion wrote no fused.ply", ws.root)
