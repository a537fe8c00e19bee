"""Coded targets in the synthetic scenes: placement, scene files, and their detection (recon.targets) against the
exact projections of their centres."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from core.cameras import Cameras, View
from core.io.control import Role, read_gcp_csv
from data_synth import generate_scene, load_scene
from data_synth.geometry import MeshBuilder, plane
from data_synth.lighting import Environment
from data_synth.materials import MATERIALS, TARGET_MATERIAL_ID, material
from data_synth.raytrace import RayTracer, RenderSettings
from data_synth.rig import look_at, pinhole_from_fov
from data_synth.targets import CELLS, Target, marker_bits, with_targets
from data_synth.textures import TextureField
from recon.targets import detect_markers, quad_center

# SHA-256 of the tiny preset's files (seed 0) as the generator wrote them before targets existed: a scene without
# targets must stay byte-identical.
TINY_DIGESTS = {
    "images/train_000.png": "4fd3ae8a7a53a29ecdddd058eda927ca19a66689584c849986d1ad29fd924cb8",
    "images/train_007.png": "b1f4844f815f6fe1d6d2c7b132494738fb702e37cea431193150082a548441aa",
    "test/test_000.png": "c3c1e9c59396b890b4fd733314543040caba60634055bc2cd77e10728cb4cc9c",
    "gt/lidar.ply": "9e121f574e064d46e82e7e0e176200af369d7c9e7fae280877a0704b649a530e",
}


def test_scene_without_targets_is_byte_identical_to_before(tmp_path):
    root = generate_scene("tiny", tmp_path / "s", seed=0, targets=0)
    got = {name: hashlib.sha256((root / name).read_bytes()).hexdigest() for name in TINY_DIGESTS}
    assert got == TINY_DIGESTS
    assert not (root / "control").exists()


def _one_target_view(yaw: float, tilt_deg: float, width: int = 240, height: int = 180):
    """A ground plane with one 0.5 m target at (0.1, -0.05), seen from 2.2 m at ``tilt_deg`` off nadir."""
    b = MeshBuilder()
    b.add(plane((6.0, 6.0)), material("gravel").id)
    target = Target(3, (0.1, -0.05, 0.001), 0.5, yaw, "control")
    mesh, targets = with_targets(b.build(), (target,))
    env = Environment(sun_azimuth_deg=30.0, sun_elevation_deg=60.0)
    tracer = RayTracer(mesh, {m.id: m for m in MATERIALS}, TextureField(0), env, RenderSettings(2, 1), targets=targets)
    tilt = np.radians(tilt_deg)
    centre = np.array([0.1 + 2.2 * np.sin(tilt), -0.05, 2.2 * np.cos(tilt)])
    camera = pinhole_from_fov(width, height, 50.0)
    view = View.from_matrix(1, "v.png", 1, look_at(centre, np.array([0.1, -0.05, 0.0]), np.array([0.0, 1.0, 0.0])))
    render = tracer.render_view(camera, view, np.random.default_rng(0))
    return render, Cameras({1: camera}, {1: view}), target


@pytest.mark.parametrize(("yaw", "tilt"), [(0.0, 0.0), (37.0, 0.0), (121.0, 30.0)])
def test_a_rendered_target_is_detected_within_a_third_of_a_pixel(yaw, tilt):
    render, cams, target = _one_target_view(yaw, tilt)
    assert (render.labels == TARGET_MATERIAL_ID).sum() > 500
    found = detect_markers(render.image)
    assert [m.marker_id for m in found] == [3]
    truth, _ = cams.project(1, np.asarray(target.center_m)[None])
    assert np.linalg.norm(found[0].center - truth[0]) < 0.3  # exact projection of the centre (COLMAP pixels)
    corners, _ = cams.project(1, target.marker_corners())
    # Printed marker order, top-left first; the contour of the thresholded black square runs up to a pixel inside
    # its edge, about a pixel at a 45° corner (every side alike, so the diagonals' intersection is not shifted).
    assert np.linalg.norm(found[0].corners - corners, axis=1).max() < 1.5


def test_marker_bitmap_has_a_black_border_inside_a_white_quiet_zone():
    bits = marker_bits(7)
    assert bits.shape == (CELLS, CELLS)
    assert bits[0].all() and bits[-1].all() and bits[:, 0].all() and bits[:, -1].all()
    assert not bits[1, 1:-1].any() and not bits[1:-1, 1].any()


def test_quad_center_is_the_diagonals_intersection():
    quad = np.array([[0.0, 0.0], [4.0, 0.0], [3.0, 2.0], [1.0, 2.0]])  # a trapezoid: not the corners' mean
    c = quad_center(quad)
    assert c == pytest.approx([2.0, 4.0 / 3.0])


def test_demo_scene_has_targets_in_scene_json_and_a_control_file(tmp_path):
    root = generate_scene("demo", tmp_path / "d", seed=1, views=12, test_views=1)
    scene = load_scene(root)
    points = scene.description.extra["targets"]["points"]
    gcp = read_gcp_csv(root / "control" / "gcp.csv")
    assert len(points) == len(gcp.points) >= 3
    assert {p.role for p in gcp.points} == {Role.CONTROL, Role.CHECK}
    by_id = gcp.by_id()
    for p in points:
        assert by_id[p["id"]].xyz_m == pytest.approx(np.asarray(p["center_world_m"]), abs=1e-12)
    labels = np.stack([scene.labels("train", v.name) for v in scene.train])
    assert (labels == TARGET_MATERIAL_ID).any()
