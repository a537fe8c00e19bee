"""Files of a synthetic scene folder (layout in :mod:`data_synth.layout`), written through ``core.io``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import plyfile

from core.cameras import Cameras
from core.io.atomic import atomic_path, write_text_atomic
from core.io.colmap import write_model
from core.io.images import write_image
from core.io.las import write_las
from core.io.origin import write_origin
from core.io.ply import write_ply
from core.pointcloud import PointCloud
from data_synth.geometry import SceneMesh
from data_synth.layout import SceneLayout

LAS_SCALE_M = 1e-5
"""LAS integer step (10 µm): keeps noise-free points within 1e-5 m of the mesh; ±21 km around the offset."""


def write_view(
    layout: SceneLayout, split: str, name: str, image: np.ndarray, depth: np.ndarray, labels: np.ndarray
) -> None:
    """Photo (H, W, 3) uint8, z-depth (H, W) float32 metres, labels (H, W) uint8 of one view of ``split``."""
    write_image(layout.image(split, name), image)
    depth_path = layout.depth(split, name)
    depth_path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(depth_path) as tmp, tmp.open("wb") as f:
        np.save(f, np.ascontiguousarray(depth, dtype=np.float32))
    write_image(layout.labels(split, name), np.ascontiguousarray(labels, dtype=np.uint8))


def write_cameras(layout: SceneLayout, train: Cameras, test: Cameras) -> None:
    """COLMAP binary models of the true training (``sparse/0``) and test (``sparse/test``) cameras, no points."""
    write_model(layout.sparse_train, train)
    write_model(layout.sparse_test, test)


def write_mesh(path: Path, mesh: SceneMesh, origin: np.ndarray) -> None:
    """PLY with float64 vertices (local frame) and a face ``material`` (int32); origin sidecar when non-zero."""
    vertex = np.empty(len(mesh.vertices), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    vertex["x"], vertex["y"], vertex["z"] = mesh.vertices.T
    face = np.empty(len(mesh.faces), dtype=[("vertex_indices", "O"), ("material", "<i4")])
    face["vertex_indices"] = list(mesh.faces.astype(np.int32))
    face["material"] = mesh.face_material
    ply = plyfile.PlyData(
        [
            plyfile.PlyElement.describe(vertex, "vertex"),
            plyfile.PlyElement.describe(
                face, "face", val_types={"vertex_indices": "i4"}, len_types={"vertex_indices": "u1"}
            ),
        ],
        byte_order="<",
    )
    with atomic_path(path) as tmp:
        ply.write(str(tmp))
    if np.any(origin != 0):
        write_origin(path, origin)


def write_cloud(layout: SceneLayout, cloud: PointCloud) -> None:
    """The LiDAR cloud as PLY (float64 local + origin sidecar) and LAS (world coordinates, 10 µm steps)."""
    write_ply(layout.lidar_ply, cloud, position_dtype="f8")
    write_las(layout.lidar_las, cloud, scale=LAS_SCALE_M)


def write_gcp(layout: SceneLayout, targets, origin: np.ndarray) -> None:
    """``control/gcp.csv``: the targets' exact centres in world coordinates (metres), with their roles."""
    from core.io.control import ControlPoint, Role, write_gcp_csv

    points = [
        ControlPoint(t.point_id, np.asarray(origin, np.float64) + np.asarray(t.center_m), Role(t.role), 0.0, 0.0)
        for t in targets.targets
    ]
    write_gcp_csv(layout.gcp_csv, points)


def write_scene_json(layout: SceneLayout, payload: dict[str, object]) -> None:
    """``scene.json`` (sorted keys are not used: the order is the documented one)."""
    write_text_atomic(layout.scene_json, json.dumps(payload, indent=2) + "\n")
