"""End-to-end checks of the ``tiny`` synthetic scene against independent truth.

The reference for "on the mesh" is open3d's closest-point query (a different code path from the renderer's
float64 ray re-intersection); float32 inside open3d limits it to ~1e-7 m at this 1 m scale, so 1e-6 m is a
tolerance with a 5x margin.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import open3d as o3d
import pycolmap
import pytest
from synth_reference import point_triangle_distance

from data_synth import generate_scene, load_scene
from data_synth.materials import material

ON_MESH_TOL_M = 1e-6
DEPTH_REL_TOL = 1e-4


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate_scene("tiny", tmp_path_factory.mktemp("synth") / "tiny", seed=0)


@pytest.fixture(scope="module")
def tiny_clean(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny scene with the LiDAR range noise switched off."""
    return generate_scene("tiny", tmp_path_factory.mktemp("synth") / "tiny_clean", seed=0, noise=0)


def _o3d_scene(vertices: np.ndarray, faces: np.ndarray) -> o3d.t.geometry.RaycastingScene:
    scene = o3d.t.geometry.RaycastingScene()
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(vertices.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(faces.astype(np.int32))
    scene.add_triangles(mesh)
    return scene


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_layout_and_cameras(tiny: Path) -> None:
    meta = json.loads((tiny / "scene.json").read_text())
    for key in ("preset", "seed", "units", "origin", "gsd_m", "rig", "image_size", "materials", "views"):
        assert key in meta
    assert meta["units"] == "m" and meta["preset"] == "tiny"
    train_names, test_names = meta["views"]["train"], meta["views"]["test"]
    assert 2 <= len(train_names) <= 12 and len(test_names) >= 1
    assert not set(train_names) & set(test_names)

    rec = pycolmap.Reconstruction(str(tiny / "sparse" / "0"))
    assert sorted(im.name for im in rec.images.values()) == sorted(train_names)
    assert rec.num_points3D() == 0
    assert {cam.model.name for cam in rec.cameras.values()} == {"PINHOLE"}
    test_rec = pycolmap.Reconstruction(str(tiny / "sparse" / "test"))
    assert sorted(im.name for im in test_rec.images.values()) == sorted(test_names)

    scene = load_scene(tiny)
    w, h = meta["image_size"]["width"], meta["image_size"]["height"]
    for split, names in (("train", train_names), ("test", test_names)):
        for name in names:
            assert scene.image(split, name).shape == (h, w, 3)
            depth = scene.depth(split, name)
            assert depth.dtype == np.float32 and depth.shape == (h, w)
            assert scene.labels(split, name).shape == (h, w)
    legend = {m["name"]: m for m in meta["materials"]}
    assert legend["mirror"]["collaborative"] is False and legend["bricks"]["collaborative"] is True
    assert legend["textureless_paint"]["kind"] == "textureless"
    cloud = scene.gt_cloud
    assert cloud.fields["material"].dtype == np.int32 and len(cloud) > 1000
    assert set(np.unique(cloud.fields["material"]).tolist()) <= {m["id"] for m in meta["materials"]}


def test_test_views_lie_between_training_views(tiny: Path) -> None:
    scene = load_scene(tiny)
    az_train = np.sort([np.degrees(np.arctan2(v.center[1], v.center[0])) for v in scene.train])
    for view in scene.test:
        az = np.degrees(np.arctan2(view.center[1], view.center[0]))
        assert az_train[0] < az < az_train[-1]
        assert np.min(np.abs(az_train - az)) > 1.0  # not on top of a training camera


def test_same_seed_gives_identical_bytes(tiny: Path, tmp_path: Path) -> None:
    again = generate_scene("tiny", tmp_path / "again", seed=0)
    first, second = _files(tiny), _files(again)
    assert first.keys() == second.keys()
    different = [name for name in first if first[name] != second[name]]
    assert different == []
    other = generate_scene("tiny", tmp_path / "other", seed=1)
    third = _files(other)
    assert third["images/train_000.png"] != first["images/train_000.png"]
    assert third["gt/lidar.ply"] != first["gt/lidar.ply"]


def test_clean_lidar_points_lie_on_the_mesh(tiny_clean: Path) -> None:
    scene = load_scene(tiny_clean)
    mesh, cloud = scene.mesh, scene.gt_cloud
    ref = _o3d_scene(mesh.vertices, mesh.faces)
    query = o3d.core.Tensor(cloud.positions.astype(np.float32))
    dist = ref.compute_distance(query).numpy()
    assert dist.max() < ON_MESH_TOL_M
    faces = ref.compute_closest_points(query)["primitive_ids"].numpy()
    assert np.mean(mesh.face_material[faces] == cloud.fields["material"]) > 0.999


def test_clean_lidar_points_on_the_mesh_in_float64(tiny_clean: Path) -> None:
    """The same claim with a brute-force float64 distance (no float32 anywhere) on a random subset."""
    scene = load_scene(tiny_clean)
    cloud = scene.gt_cloud
    pick = np.random.default_rng(0).choice(len(cloud), 300, replace=False)
    dist, face = point_triangle_distance(cloud.positions[pick], scene.mesh.triangles)
    assert dist.max() < 1e-9  # float64 re-intersection: rounding-level distances
    assert np.array_equal(scene.mesh.face_material[face], cloud.fields["material"][pick])


def test_noisy_lidar_follows_the_noise_model(tiny: Path) -> None:
    scene = load_scene(tiny)
    sigma = json.loads((tiny / "scene.json").read_text())["rig"]["lidar_noise"]["sigma_m"]
    mesh, cloud = scene.mesh, scene.gt_cloud
    dist = _o3d_scene(mesh.vertices, mesh.faces).compute_distance(o3d.core.Tensor(cloud.positions.astype(np.float32)))
    rms = float(np.sqrt(np.mean(dist.numpy().astype(np.float64) ** 2)))
    # Distance to the surface is the range error times the cosine of incidence: below sigma, same order.
    assert 0.3 * sigma < rms <= 1.05 * sigma


def test_depth_maps_unproject_onto_the_mesh(tiny: Path) -> None:
    scene = load_scene(tiny)
    mesh = scene.mesh
    ref = _o3d_scene(mesh.vertices, mesh.faces)
    for split, cams in (("train", scene.train), ("test", scene.test)):
        for view in cams:
            depth = scene.depth(split, view.name).astype(np.float64)
            labels = scene.labels(split, view.name)
            rows, cols = np.nonzero(depth > 0)
            pix = np.stack([cols + 0.5, rows + 0.5], axis=1)
            pts = cams.unproject(view, pix, depth[rows, cols])
            query = o3d.core.Tensor(pts.astype(np.float32))
            dist = ref.compute_distance(query).numpy()
            assert dist.max() < ON_MESH_TOL_M, f"{split}/{view.name}: depth off the mesh by {dist.max():.2e} m"
            faces = ref.compute_closest_points(query)["primitive_ids"].numpy()
            assert np.mean(mesh.face_material[faces] == labels[rows, cols]) > 0.995
            assert np.all(labels[depth == 0] == 255)


def test_projected_gt_points_match_rendered_depth_and_labels(tiny_clean: Path) -> None:
    """Project LiDAR points with the COLMAP cameras; the pixel they land in must show them.

    A point rarely sits at a pixel centre, so its depth is carried to the centre along its own face's plane
    (exact for planar triangles). Points whose pixel centre sees another face (silhouettes, facet edges) are
    identified by an independent open3d ray cast and excluded; occluded points fail the depth test and are
    excluded by it.
    """
    scene = load_scene(tiny_clean)
    mesh, cloud = scene.mesh, scene.gt_cloud
    ref = _o3d_scene(mesh.vertices, mesh.faces)
    pts = cloud.positions
    point_face = ref.compute_closest_points(o3d.core.Tensor(pts.astype(np.float32)))["primitive_ids"].numpy()
    normals = mesh.face_normals()[point_face]
    checked = total = 0
    for view in scene.train:
        cam = scene.train.camera_of(view)
        depth = scene.depth("train", view.name).astype(np.float64)
        labels = scene.labels("train", view.name)
        pix, z = scene.train.project(view, pts)
        inside = (z > 0) & (pix[:, 0] >= 0) & (pix[:, 0] < cam.width) & (pix[:, 1] >= 0) & (pix[:, 1] < cam.height)
        idx = np.flatnonzero(inside)
        cols, rows = np.floor(pix[idx, 0]).astype(int), np.floor(pix[idx, 1]).astype(int)
        centre_dirs = cam.unproject(np.stack([cols + 0.5, rows + 0.5], axis=1), 1.0)  # camera frame, z = 1
        n_cam = normals[idx] @ view.rotation.T
        p_cam = view.world_to_camera(pts[idx])
        z_centre = np.sum(n_cam * p_cam, axis=1) / np.sum(n_cam * centre_dirs, axis=1)
        # Independent ray through the pixel centre: which face does it hit first?
        d_world = centre_dirs @ view.rotation
        d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
        rays = np.concatenate([np.broadcast_to(view.center, d_world.shape), d_world], axis=1).astype(np.float32)
        ans = ref.cast_rays(o3d.core.Tensor(rays))
        centre_face = ans["primitive_ids"].numpy().astype(np.int64)
        z_ray = ans["t_hit"].numpy().astype(np.float64) / np.linalg.norm(centre_dirs, axis=1)
        same = centre_face == point_face[idx]
        rel = np.abs(depth[rows, cols] - z_centre) / z_centre
        total += len(idx)
        checked += int(same.sum())
        assert np.all(rel[same] < DEPTH_REL_TOL), f"{view.name}: max rel depth error {rel[same].max():.2e}"
        assert np.all(labels[rows[same], cols[same]] == cloud.fields["material"][idx[same]])
        # Every pixel, whatever face it sees, agrees with open3d's float32 ray (1e-5 covers its rounding).
        hit = np.isfinite(z_ray)
        assert np.array_equal(hit, depth[rows, cols] > 0)
        assert np.all(np.abs(depth[rows, cols][hit] - z_ray[hit]) < 1e-5 * z_ray[hit])
    assert checked > 0.6 * total


def test_scene_statistics_separate_collaborative_materials(tiny: Path) -> None:
    meta = json.loads((tiny / "scene.json").read_text())
    std = meta["cross_view_color_std"]
    textured = [std[m["name"]] for m in meta["materials"] if m["kind"] == "textured" and m["name"] in std]
    assert textured and max(textured) < 1.0  # Lambertian: view-independent up to 8-bit rounding
    assert std["mirror"] > 5.0 * max(max(textured), 1.0)
    grad = meta["image_gradient"]
    textured_grad = [grad[m["name"]] for m in meta["materials"] if m["kind"] == "textured"]
    assert grad["textureless_paint"] < 0.25 * min(textured_grad)
    assert meta["image_gradient_median"]["textureless_paint"] < 0.5  # grey levels per pixel
    image_std = meta["cross_view_color_std_image"]
    assert image_std["mirror"] > np.mean([image_std[m["name"]] for m in meta["materials"] if m["kind"] == "textured"])


def test_georeferenced_origin_travels_to_las_and_cameras(tmp_path: Path) -> None:
    import laspy

    root = generate_scene("tiny", tmp_path / "geo", seed=0, georef=True, views=3, test_views=1)
    scene = load_scene(root)
    assert np.allclose(scene.origin, (500000.0, 5000000.0, 300.0))
    assert np.allclose(scene.train.origin, scene.origin)
    cloud = scene.gt_cloud
    assert np.abs(cloud.positions).max() < 10.0  # the local frame stays small
    las = laspy.read(root / "gt" / "lidar.las")
    world = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1)
    assert np.abs(world - cloud.world_positions).max() < 1e-5  # 10 µm LAS steps
    assert np.array_equal(np.asarray(las["material"]), cloud.fields["material"])
    mesh_ids = {m.id for m in scene.materials}
    assert set(np.unique(las["material"]).tolist()) <= mesh_ids
    assert set(np.unique(np.asarray(las.classification)).tolist()) <= {1, 2, 6, 14, 15, 19}
    assert material("mirror").id in np.unique(las["material"]).tolist()
