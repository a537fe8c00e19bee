"""What the viewer shows, as plain arrays in the cameras' local frame (no viser here, so it is tested alone).

Frames: everything is expressed in the local frame of the COLMAP model (``world = cameras_origin + local``);
Gaussian sets, clouds and meshes carry their own float64 origins and are shifted into that frame in float64
before going to float32 for the browser.
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from core.cameras import Camera, Cameras, View
from core.errors import DataError, FormatError, InputFileError
from core.gaussians import GaussianSet
from eval.measure.project import Georeference, read_cameras, read_georeference
from hybridsplat.project_io import sparse_model
from hybridsplat.viewer.project import cameras_origin, open_project


@dataclass(frozen=True)
class SplatArrays:
    """Gaussians for viser: centers (N, 3) float32 local, covariances (N, 3, 3) float32 m², rgbs (N, 3) float32
    in [0, 1] (SH degree 0), opacities (N, 1) float32 in (0, 1). ``total``: Gaussians in the file before any cap."""

    centers: np.ndarray
    covariances: np.ndarray
    rgbs: np.ndarray
    opacities: np.ndarray
    total: int


@dataclass(frozen=True)
class CloudArrays:
    """points (N, 3) float32 local, colors (N, 3) uint8; ``total`` before any cap."""

    points: np.ndarray
    colors: np.ndarray
    total: int


@dataclass(frozen=True)
class MeshArrays:
    """vertices (V, 3) float32 local, faces (F, 3) int32, vertex colours (V, 3) uint8 or None."""

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None


@dataclass(frozen=True)
class ViewerScene:
    """Everything ``hybridsplat view`` shows.

    cameras: training cameras (local frame); test_cameras: held-out ones (may be empty).
    georef: origin of the local frame (world = origin + local), unit and CRS (for display and exports).
    splats / cloud / mesh: optional layers. name: a title.
    """

    name: str
    cameras: Cameras
    test_cameras: Cameras
    georef: Georeference
    splats: SplatArrays | None = None
    cloud: CloudArrays | None = None
    mesh: MeshArrays | None = None

    @property
    def extent(self) -> float:
        """A length scale of the scene (metres): the spread of the camera centres, or 1."""
        centres = np.stack([v.center for v in self.cameras]) if len(self.cameras) else np.zeros((1, 3))
        spread = float(np.linalg.norm(centres.max(axis=0) - centres.min(axis=0)))
        return spread if spread > 0 else 1.0

    @property
    def centre(self) -> np.ndarray:
        """(3,) float64 local point to look at: the median splat / cloud position, or the cameras' mean."""
        if self.splats is not None and len(self.splats.centers):
            return np.median(self.splats.centers.astype(np.float64), axis=0)
        if self.cloud is not None and len(self.cloud.points):
            return np.median(self.cloud.points.astype(np.float64), axis=0)
        return np.mean([v.center for v in self.cameras], axis=0) if len(self.cameras) else np.zeros(3)


def _cap(n: int, limit: int, seed: int = 0) -> np.ndarray | None:
    """Indices of a seeded uniform subsample of ``limit`` out of ``n`` (None when nothing is dropped)."""
    if limit <= 0 or n <= limit:
        return None
    return np.sort(np.random.default_rng(seed).choice(n, size=limit, replace=False))


def splat_arrays(gs: GaussianSet, frame_origin: np.ndarray, max_splats: int = 2_000_000) -> SplatArrays:
    """Viewer arrays of a Gaussian set shifted into the frame with origin ``frame_origin`` (float64 (3,)).

    Covariance ``Σ = R diag(σ²) Rᵀ`` from the stored log-scales and quaternions; colour from the SH DC term.
    A set above ``max_splats`` is subsampled (seeded) and ``total`` says how many there were.
    """
    total = len(gs)
    keep = _cap(total, max_splats)
    if keep is not None:
        gs = gs.subset(keep)
    from core.cameras import quat_to_rotmat

    means = gs.means.astype(np.float64) + (gs.origin - np.asarray(frame_origin, np.float64))
    if not np.all(np.isfinite(means)):
        raise DataError("Gaussian means are not finite")
    R = quat_to_rotmat(gs.unit_quats.astype(np.float64))
    s2 = np.exp(2.0 * np.clip(gs.log_scales.astype(np.float64), -30.0, 10.0))
    cov = np.einsum("nij,nj,nkj->nik", R, s2, R)
    return SplatArrays(
        centers=means.astype(np.float32),
        covariances=cov.astype(np.float32),
        rgbs=gs.base_colors.astype(np.float32),
        opacities=gs.opacities.reshape(-1, 1).astype(np.float32),
        total=total,
    )


def cloud_arrays(path: str | PathLike[str], frame_origin: np.ndarray, max_points: int = 1_000_000) -> CloudArrays:
    """A PLY point cloud (origin sidecar honoured by ``read_ply``) as viewer arrays in the frame ``frame_origin``."""
    from core.io.ply import read_ply

    cloud = read_ply(path)
    origin = cloud.origin
    total = len(cloud.positions)
    keep = _cap(total, max_points)
    pos = cloud.positions if keep is None else cloud.positions[keep]
    colors = cloud.colors if cloud.colors is not None else np.full((total, 3), 180, np.uint8)
    colors = colors if keep is None else colors[keep]
    local = pos + (origin - np.asarray(frame_origin, np.float64))
    return CloudArrays(local.astype(np.float32), np.asarray(colors, np.uint8), total)


def mesh_arrays(path: str | PathLike[str], frame_origin: np.ndarray) -> MeshArrays:
    """A triangle mesh (PLY/OBJ/GLB via trimesh; origin sidecar honoured) in the frame of ``frame_origin``."""
    import trimesh

    from core.io.origin import read_origin

    path = Path(path)
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as err:  # trimesh raises many types for unreadable files
        raise FormatError(f"cannot read the mesh ({err})", path) from err
    if len(mesh.faces) == 0:
        raise DataError("the mesh has no faces", path)
    local = np.asarray(mesh.vertices, np.float64) + (read_origin(path) - np.asarray(frame_origin, np.float64))
    colors = None
    vc = getattr(mesh.visual, "vertex_colors", None)
    if vc is not None and len(vc) == len(local):
        colors = np.asarray(vc, np.uint8)[:, :3]
    return MeshArrays(local.astype(np.float32), np.asarray(mesh.faces, np.int32), colors)


def load_project(
    project: str | PathLike[str],
    max_splats: int = 2_000_000,
    max_points: int = 1_000_000,
    layers: tuple[int, ...] | None = None,
) -> ViewerScene:
    """Read a project folder: cameras (sparse/), merged splats (of ``layers``, ``Source`` codes; None: all), MVS
    cloud and mesh when present."""
    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.convert_options import select_layers

    layout = open_project(project)
    cameras = read_cameras(sparse_model(layout))
    georef = read_georeference(layout.merged_ply)
    origin = cameras_origin(layout, georef.origin)
    georef = Georeference(origin, georef.unit, georef.crs)
    merged = layout.merged_ply
    splats = None
    if merged.is_file():
        splats = splat_arrays(select_layers(read_gaussian_ply(merged), layers), origin, max_splats)
    cloud = cloud_arrays(layout.fused_ply, origin, max_points) if layout.fused_ply.is_file() else None
    mesh_file = next((layout.mesh_path(f) for f in ("ply", "obj", "glb") if layout.mesh_path(f).is_file()), None)
    mesh = mesh_arrays(mesh_file, origin) if mesh_file is not None else None
    return ViewerScene(layout.root.resolve().name, cameras, Cameras(), georef, splats, cloud, mesh)


def load_ply_alone(
    path: str | PathLike[str], max_splats: int = 2_000_000, layers: tuple[int, ...] | None = None
) -> ViewerScene:
    """A 3DGS PLY without a project: splats only (of ``layers``; None: all), no cameras (measurement needs a
    project)."""
    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.convert_options import select_layers

    path = Path(path)
    if not path.is_file():
        raise InputFileError("file does not exist", path)
    georef = read_georeference(path)
    gs = select_layers(read_gaussian_ply(path), layers)
    return ViewerScene(path.name, Cameras(), Cameras(), georef, splat_arrays(gs, georef.origin, max_splats))


def virtual_camera(
    position: np.ndarray, wxyz_world_from_cam: np.ndarray, fov_y: float, width: int, height: int
) -> tuple[Camera, View]:
    """A pinhole camera and pose for a viewer's client camera.

    position: (3,) camera centre (local frame); wxyz_world_from_cam: rotation camera → world (viser's ``wxyz``,
    OpenCV axes); fov_y: vertical field of view (radians); width, height: canvas size in pixels.
    """
    from core.cameras import quat_to_rotmat

    if not (0 < fov_y < np.pi) or width <= 0 or height <= 0:
        raise DataError(f"invalid viewer camera: fov {fov_y} rad, canvas {width}×{height}")
    f = 0.5 * height / np.tan(0.5 * fov_y)
    camera = Camera.pinhole(f, f, 0.5 * width, 0.5 * height, int(width), int(height), camera_id=0)
    R_wc = quat_to_rotmat(np.asarray(wxyz_world_from_cam, np.float64))
    cam_from_world = np.concatenate([R_wc.T, (-R_wc.T @ np.asarray(position, np.float64))[:, None]], axis=1)
    return camera, View.from_matrix(0, "<viewer>", 0, cam_from_world)
