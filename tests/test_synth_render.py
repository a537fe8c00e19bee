"""The ray tracer, rigs, textures and presets against analytic cases."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import ConfigError
from data_synth.geometry import MeshBuilder, box, plane
from data_synth.lighting import Environment
from data_synth.materials import MATERIALS, material
from data_synth.presets import apply_overrides, get_preset
from data_synth.raytrace import RayTracer, RenderSettings, camera_rays, linear_to_srgb8, srgb8_to_linear
from data_synth.rig import AerialRig, OrbitRig, build_cameras, look_at, pinhole_from_fov
from data_synth.textures import TextureField

LEGEND = {m.id: m for m in MATERIALS}


def _tracer(builder: MeshBuilder, env: Environment | None = None, depth: int = 2) -> RayTracer:
    return RayTracer(builder.build(), LEGEND, TextureField(0), env or Environment(), RenderSettings(1, depth))


def test_srgb_transfer_matches_the_standard() -> None:
    # IEC 61966-2-1 reference points: linear 0.5 -> 0.7354 -> 188; the linear toe below 0.0031308.
    values = np.array([0.0, 0.0031308, 0.5, 1.0, 2.0, -1.0])
    assert linear_to_srgb8(values).tolist() == [0, 10, 188, 255, 255, 0]
    codes = np.arange(256)
    assert np.array_equal(linear_to_srgb8(srgb8_to_linear(codes)), codes)


def test_look_at_puts_the_target_at_the_principal_point() -> None:
    cam = pinhole_from_fov(64, 48, 60.0)
    m = look_at(np.array([1.0, -2.0, 0.7]), np.array([0.1, 0.2, 0.05]))
    R, t = m[:, :3], m[:, 3]
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    p = R @ np.array([0.1, 0.2, 0.05]) + t
    assert np.allclose(cam.project(p), (32.0, 24.0))
    up = R @ np.array([0.1, 0.2, 1.05]) + t  # a point above the target appears higher (smaller y)
    assert cam.project(up)[1] < 24.0
    with pytest.raises(ConfigError):
        look_at(np.zeros(3), np.array([0.0, 0.0, -1.0]))


def test_lambert_plane_matches_the_analytic_radiance() -> None:
    b = MeshBuilder()
    b.add(plane((4.0, 4.0)), material("textureless_paint").id)
    env = Environment(sun_elevation_deg=60.0)
    tracer = _tracer(b, env)
    o = np.array([[0.3, -0.2, 1.0]])
    d = np.array([[0.1, 0.05, -1.0]])
    d /= np.linalg.norm(d)
    got = tracer.radiance(o, d)[0]
    albedo = np.asarray(material("textureless_paint").albedo)
    expected = albedo * (np.sin(np.radians(60.0)) * np.asarray(env.sun_rgb) + np.asarray(env.ambient))
    assert np.allclose(got, expected, rtol=1e-12)


def test_shadow_and_depth_of_a_box_on_a_plane() -> None:
    b = MeshBuilder()
    b.add(plane((4.0, 4.0)), material("textureless_paint").id)
    b.add(box((0.2, 0.2, 1.0), (0.0, 0.0, 0.5)), material("textureless_paint").id)
    env = Environment(sun_azimuth_deg=0.0, sun_elevation_deg=45.0)
    tracer = _tracer(b, env)
    # The sun is along +x at 45°: the ground at x = -0.5 lies in the box's shadow, at x = +0.5 it is lit.
    down = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    lit = tracer.radiance(np.array([[0.5, 0.0, 3.0], [-0.5, 0.0, 3.0]]), down)
    albedo = np.asarray(material("textureless_paint").albedo)
    assert np.allclose(lit[1], albedo * np.asarray(env.ambient))
    assert np.all(lit[0] > lit[1] * 2)
    hits = tracer.cast(np.array([[0.0, 0.0, 3.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert hits.hit[0] and abs(hits.t[0] - 2.0) < 1e-12 and hits.material[0] == material("textureless_paint").id


def test_mirror_reflects_the_environment_and_the_scene() -> None:
    b = MeshBuilder()
    b.add(plane((4.0, 4.0)), material("mirror").id)
    env = Environment()
    tracer = _tracer(b, env)
    d = np.array([[0.6, 0.0, -0.8]])
    got = tracer.radiance(np.array([[0.0, 0.0, 1.0]]), d)[0]
    assert np.allclose(got, material("mirror").specular * env.radiance(np.array([[0.6, 0.0, 0.8]]))[0])
    # A wall in the reflected path shows up in the mirror.
    b.add(box((0.1, 4.0, 4.0), (2.0, 0.0, 2.0)), material("textureless_paint").id)
    with_wall = _tracer(b, env).radiance(np.array([[0.0, 0.0, 1.0]]), d)[0]
    assert not np.allclose(with_wall, got)


def test_glass_refraction_obeys_snell_and_total_internal_reflection() -> None:
    b = MeshBuilder()
    b.add(plane((1.0, 1.0)), material("glass").id)
    tracer = _tracer(b)
    glass = material("glass")
    n = np.array([[0.0, 0.0, 1.0]])
    theta = np.radians(40.0)
    d = np.array([[np.sin(theta), 0.0, -np.cos(theta)]])
    parts = tracer._glass(glass, np.array([0]), np.zeros((1, 3)), n, d, np.array([True]))
    refr = parts[1][2][0]
    assert np.isclose(np.sin(theta), glass.ior * np.hypot(refr[0], refr[1]))
    assert np.isclose(np.linalg.norm(refr), 1.0) and refr[2] < 0
    # From inside at 50° (> critical angle 41.8°): only reflection, with weight 1.
    theta = np.radians(50.0)
    d_in = np.array([[np.sin(theta), 0.0, np.cos(theta)]])
    parts = tracer._glass(glass, np.array([0]), np.zeros((1, 3)), -n, d_in, np.array([False]))
    assert len(parts) == 1 and np.allclose(parts[0][3], 1.0)


def test_camera_rays_give_z_depth() -> None:
    cam = pinhole_from_fov(32, 24, 70.0)
    b = MeshBuilder()
    b.add(plane((100.0, 100.0)), material("textureless_paint").id)
    tracer = _tracer(b)
    views, _ = build_cameras(
        AerialRig(area_m=(10.0, 10.0), grid=(2, 2), nadir_height_m=7.0, oblique_per_side=1, n_test=0),
        32,
        24,
        np.zeros(3),
    )
    view = views.views[1]
    rows, cols = np.mgrid[0:24, 0:32]
    pix = np.stack([cols.ravel() + 0.5, rows.ravel() + 0.5], axis=1).astype(float)
    o, d, z_per_t = camera_rays(views.camera_of(view), view, pix)
    hits = tracer.cast(o, d)
    assert np.allclose(hits.t * z_per_t, 7.0, rtol=1e-12)  # nadir over a flat plane: z-depth = height
    assert cam.width == 32


def test_textures_are_functions_of_the_point_and_the_seed() -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.3, 0.3, (2000, 3))
    normals = np.tile([0.0, 0.0, 1.0], (2000, 1))
    for name in ("ground_noise", "bricks", "text_label", "wood"):
        mat = material(name)
        a = TextureField(3).albedo(mat, pts, normals)
        perm = rng.permutation(2000)
        assert np.array_equal(TextureField(3).albedo(mat, pts[perm], normals[perm]), a[perm])
        assert a.min() >= 0 and a.max() <= 1 and a.std(axis=0).mean() > 0.02
        assert not np.array_equal(TextureField(4).albedo(mat, pts, normals), a)
    flat = TextureField(3).albedo(material("textureless_paint"), pts, normals)
    assert np.all(flat == np.asarray(material("textureless_paint").albedo))


def test_orbit_rig_counts_and_test_views_between() -> None:
    rig = OrbitRig(radius_m=1.0, elevations_deg=(20.0, 40.0), views_per_ring=12, n_test=4)
    train, test = rig.poses()
    assert len(train) == 24 and len(test) == 4
    centres = [-m[:, :3].T @ m[:, 3] for m in train]
    assert np.allclose([np.linalg.norm(c) for c in centres], 1.0)
    for m in test:
        c = -m[:, :3].T @ m[:, 3]
        gaps = [np.degrees(np.arccos(np.clip(c @ t, -1, 1))) for t in centres]
        assert min(gaps) > 5.0  # never on top of a training camera (step 30°)


def test_presets_and_overrides() -> None:
    tabletop = get_preset("tabletop")
    assert tabletop.n_train >= 64 and tabletop.width >= 640 and tabletop.height >= 480
    assert len(tabletop.rig.elevations_deg) >= 2
    tiny = get_preset("tiny")
    assert tiny.n_train <= 12 and tiny.width <= 128
    p = apply_overrides(tabletop, views=30, width=320, height=240, noise=0, georef=True)
    assert p.n_train == 30 and p.width == 320 and not p.noise.enabled and p.origin[0] == 500000.0
    aerial = apply_overrides(get_preset("aerial"), views=40)
    assert abs(aerial.n_train - 40) <= 4
    with pytest.raises(ConfigError):
        apply_overrides(tiny, colour="red")
    with pytest.raises(ConfigError):
        apply_overrides(tiny, width=0)
    with pytest.raises(ConfigError):
        get_preset("huge")


def test_compiled_noise_equals_the_numpy_reference() -> None:
    from data_synth.textures import NoiseTable

    table = NoiseTable(5)
    pts = np.random.default_rng(1).uniform(-300.0, 300.0, (5000, 3))
    fast = table.noise(pts)
    assert np.array_equal(fast, table.noise_reference(pts))
    assert 0.0 <= fast.min() and fast.max() <= 1.0
    # Continuity across lattice cells: tiny steps give tiny changes.
    assert np.abs(table.noise(pts + 1e-7) - fast).max() < 1e-5


def test_glass_casts_no_shadow_but_opaque_boxes_do() -> None:
    for name, shadowed in (("glass", False), ("textureless_paint", True)):
        b = MeshBuilder()
        b.add(plane((4.0, 4.0)), material("textureless_paint").id)
        b.add(box((0.2, 0.2, 1.0), (0.0, 0.0, 0.5)), material(name).id)
        tracer = _tracer(b, Environment(sun_azimuth_deg=0.0, sun_elevation_deg=45.0))
        p = np.array([[-0.5, 0.0, 1e-4]])  # on the ground, where the box's shadow falls
        assert tracer.occluded(p, np.broadcast_to(tracer.env.sun_dir, (1, 3)).copy())[0] == shadowed
