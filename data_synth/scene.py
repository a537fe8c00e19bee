"""Reading a generated scene folder back: cameras, ground-truth cloud and mesh, legend, per-view maps."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from os import PathLike
from pathlib import Path

import numpy as np

from core.cameras import Cameras
from core.errors import FormatError, InputFileError
from core.io.colmap import read_model
from core.io.images import read_image
from core.io.origin import read_origin
from core.io.ply import load_ply_data, read_ply
from core.io.scene_description import MaterialEntry, SceneDescription, read_scene_description
from core.pointcloud import PointCloud
from data_synth.geometry import SceneMesh
from data_synth.layout import SceneLayout

MaterialInfo = MaterialEntry  # a legend entry of scene.json (the reader lives in core.io.scene_description)


@dataclass
class Scene:
    """A synthetic scene on disk.

    train / test: true cameras (local frame; ``origin`` set from scene.json). gsd_m: median ground sample
    distance of the training views (metres per pixel at the median depth). materials: the legend.
    ``gt_cloud`` and ``mesh`` load on first access. ``description`` is the parsed scene.json.
    """

    paths: SceneLayout
    preset: str
    seed: int
    origin: np.ndarray
    gsd_m: float
    train: Cameras
    test: Cameras
    materials: list[MaterialInfo]
    description: SceneDescription = field(repr=False)

    @cached_property
    def gt_cloud(self) -> PointCloud:
        """The simulated LiDAR cloud (float64 local positions + origin, field ``material``)."""
        return read_ply(self.paths.lidar_ply)

    @cached_property
    def mesh(self) -> SceneMesh:
        """The ground-truth mesh (local frame) with per-face material ids."""
        return read_mesh(self.paths.mesh)

    def material_ids(self, collaborative: bool | None = None) -> list[int]:
        """Ids of the legend's materials, optionally only (non-)collaborative ones."""
        return [m.id for m in self.materials if collaborative is None or m.collaborative == collaborative]

    def image(self, split: str, name: str) -> np.ndarray:
        """Photo (H, W, 3) uint8 of view ``name`` in ``split`` (train or test)."""
        return read_image(self.paths.image(split, name))

    def depth(self, split: str, name: str) -> np.ndarray:
        """z-depth (H, W) float32 metres, 0 where no surface."""
        path = self.paths.depth(split, name)
        if not path.is_file():
            raise InputFileError("depth map does not exist", path)
        return np.load(path)

    def labels(self, split: str, name: str) -> np.ndarray:
        """Material id (H, W) uint8 per pixel, 255 = background."""
        return read_image(self.paths.labels(split, name), grayscale=True)


def read_mesh(path: str | PathLike[str]) -> SceneMesh:
    """Read ``gt/mesh.ply`` (vertices float64, faces with ``material``); raises FormatError if fields miss."""
    path = Path(path)
    data = load_ply_data(path)
    if "vertex" not in data or "face" not in data:
        raise FormatError("mesh PLY needs 'vertex' and 'face' elements", path)
    v = data["vertex"].data
    f = data["face"].data
    if "material" not in (f.dtype.names or ()):
        raise FormatError("mesh PLY faces lack the 'material' property", path)
    verts = np.stack([np.asarray(v[n], dtype=np.float64) for n in "xyz"], axis=1)
    faces = np.stack([np.asarray(x, dtype=np.int64) for x in f["vertex_indices"]]) if len(f) else np.zeros((0, 3))
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise FormatError("mesh PLY faces must be triangles", path)
    return SceneMesh(verts, faces, np.asarray(f["material"], dtype=np.int32))


def load_scene(root: str | PathLike[str]) -> Scene:
    """Open a scene folder written by :func:`data_synth.generate_scene`."""
    layout = SceneLayout(Path(root))
    if not layout.scene_json.is_file():
        raise InputFileError("not a synthetic scene: scene.json is missing", layout.root)
    desc = read_scene_description(layout.scene_json)
    for key, value in (("preset", desc.preset), ("seed", desc.seed), ("gsd_m", desc.gsd_m)):
        if value is None:
            raise FormatError(f"scene.json is not valid: '{key}' is missing", layout.scene_json)
    origin = np.asarray(desc.origin, dtype=np.float64)
    legend = list(desc.materials)
    preset, seed, gsd = str(desc.preset), int(desc.seed), float(desc.gsd_m)
    train, _ = read_model(layout.sparse_train)
    test, _ = read_model(layout.sparse_test)
    train.origin = origin.copy()
    test.origin = origin.copy()
    if layout.mesh.is_file() and np.any(read_origin(layout.mesh) != origin):
        raise FormatError("mesh origin sidecar disagrees with scene.json", layout.mesh)
    return Scene(layout, preset, seed, origin, gsd, train, test, legend, desc)
