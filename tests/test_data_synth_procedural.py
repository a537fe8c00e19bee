"""Procedural scene families (``random-object``, ``random-aerial``): layouts drawn from a seed, deterministic per
seed, varied across seeds, physically placed, with the same ground truth as the fixed presets."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from data_synth import generate_scene, load_scene
from data_synth.materials import BACKGROUND_LABEL, material
from data_synth.presets import PRESETS, SCORING_SEEDS, TUNING_SEEDS, apply_overrides, preset_for_seed
from data_synth.procedural import THIN_SHAPES, ProceduralLayout, Shape, draw_layout
from data_synth.rig import build_cameras
from data_synth.scenes import LAYOUTS
from hybridsplat.cli import main

FAMILIES = {"random-object": "random_object", "random-aerial": "random_aerial"}
TINY = {"views": 6, "test_views": 1, "width": 48, "height": 36}


def _rngs(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """The layout and rig generators of a seed, derived as ``data_synth.generate`` does (streams 1 and 6)."""
    layout, rig = (np.random.default_rng(np.random.SeedSequence([seed, stream, 0])) for stream in (1, 6))
    return layout, rig


def _layout(family: str, seed: int) -> ProceduralLayout:
    return draw_layout(family, _rngs(seed)[0])


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Path]]:
    """Each family, seed 3, at a tiny size: once through the CLI, once through the API."""
    root = tmp_path_factory.mktemp("procedural")
    out = {}
    for preset in FAMILIES:
        cli = root / f"{preset}_cli"
        args = ["synth", "--preset", preset, "--seed", "3", "--views", "6", "--test-views", "1"]
        main([*args, "--width", "48", "--height", "36", "--out", str(cli)])
        api = generate_scene(preset, root / f"{preset}_api", seed=3, **TINY)
        out[preset] = (cli, api)
    return out


@pytest.mark.parametrize("preset", FAMILIES)
def test_same_seed_gives_the_same_bytes(scenes: dict[str, tuple[Path, Path]], preset: str) -> None:
    a, b = scenes[preset]
    for rel in ("scene.json", "gt/mesh.ply", "gt/lidar.ply", "images/train_000.png", "test/test_000.png",
                "gt/labels/train/train_001.png", "gt/depth/train/train_002.npy"):  # fmt: skip
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel


@pytest.mark.parametrize("preset", FAMILIES)
def test_cli_scene_records_preset_seed_and_layout(scenes: dict[str, tuple[Path, Path]], preset: str) -> None:
    meta = json.loads((scenes[preset][0] / "scene.json").read_text())
    assert meta["preset"] == preset and meta["seed"] == 3
    assert meta["image_size"] == {"width": 48, "height": 36}
    assert len(meta["views"]["test"]) == 1
    if preset == "random-object":  # views per ring = ceil(6 / rings) for 2 or 3 rings: 6 in all
        assert len(meta["views"]["train"]) == 6
    else:  # a 2 x 2 nadir grid (the fewest) plus the four oblique passes
        assert len(meta["views"]["train"]) == 4 + 4 * PRESETS[preset].rig.oblique_per_side
        assert set(meta["rig"]["nadir_overlap"]) == {"forward", "side"}
    layout = meta["layout"]
    assert layout["family"] == FAMILIES[preset] and layout["objects"]
    assert meta["rig"]["rig_ranges"]["type"] in ("OrbitRigRanges", "AerialRigRanges")
    for obj in layout["objects"]:
        assert {"shape", "size_m", "position_m", "yaw_deg", "lying", "materials", "bounds_m"} <= set(obj)
    # the layout in scene.json is the one the seed draws
    assert _layout(FAMILIES[preset], 3).describe() == layout


@pytest.mark.parametrize("preset", FAMILIES)
def test_ground_truth_is_consistent(scenes: dict[str, tuple[Path, Path]], preset: str) -> None:
    scene = load_scene(scenes[preset][0])
    legend = set(scene.material_ids())
    assert set(np.unique(scene.mesh.face_material).tolist()) == legend
    names = {m.name for m in scene.materials}
    layout = scene.description.extra["layout"]
    assert {n for obj in layout["objects"] for n in obj["materials"]} <= names
    assert scene.material_ids(collaborative=True) and scene.material_ids(collaborative=False)
    assert set(np.unique(scene.gt_cloud.fields["material"]).tolist()) <= legend
    for split, cams in (("train", scene.train), ("test", scene.test)):
        for view in cams:
            labels = scene.labels(split, view.name)
            depth = scene.depth(split, view.name)
            assert set(np.unique(labels).tolist()) <= legend | {BACKGROUND_LABEL}
            surface = labels != BACKGROUND_LABEL
            assert surface.any()
            assert np.isfinite(depth).all() and (depth[surface] > 0).all() and (depth[~surface] == 0).all()


@pytest.mark.parametrize("family", FAMILIES.values())
def test_seeds_give_different_layouts(family: str) -> None:
    layouts = [_layout(family, seed) for seed in range(10)]
    signatures = {(len(lay.objects), frozenset(lay.material_names())) for lay in layouts}
    assert len(signatures) >= 8
    positions = {tuple(o.position_m for o in lay.objects) for lay in layouts}
    assert len(positions) == 10
    # the same generator state gives the same layout, and the registered builder builds its mesh
    again = _layout(family, 4)
    assert again == layouts[4] and again.describe() == layouts[4].describe()
    mesh = LAYOUTS[family](_rngs(4)[0])
    np.testing.assert_array_equal(mesh.vertices, layouts[4].mesh().vertices)


@pytest.mark.parametrize("family", FAMILIES.values())
def test_every_layout_mixes_collaborative_and_non_collaborative_objects(family: str) -> None:
    kinds: set[str] = set()
    for seed in range(30):
        lay = _layout(family, seed)
        used = [material(n) for obj in lay.objects for n in obj.materials]
        assert any(m.collaborative for m in used) and any(not m.collaborative for m in used), seed
        for obj in lay.objects:  # thin members are thin materials; nothing else is
            thin = [material(n).kind.value == "thin" for n in obj.materials]
            assert all(thin) if obj.shape in THIN_SHAPES else not any(thin), (seed, obj)
        kinds |= {m.kind.value for m in used}
    assert kinds == {"textured", "textureless", "metal", "mirror", "glass", "thin"}


def _overlap_xy(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all(a[0, :2] < b[1, :2]) and np.all(b[0, :2] < a[1, :2]))


@pytest.mark.parametrize("family", FAMILIES.values())
def test_objects_do_not_intersect_and_rest_on_the_support(family: str) -> None:
    shapes: set[Shape] = set()
    for seed in range(20):
        lay = _layout(family, seed)
        bounds = lay.object_bounds()
        support = lay.support
        z0 = support.surface_z_m
        for i, obj in enumerate(lay.objects):
            shapes.add(obj.shape)
            lo, hi = bounds[i]
            for j in range(i):
                assert not _overlap_xy(bounds[i], bounds[j]), (seed, i, j)
            assert hi[2] > z0
            if obj.shape is Shape.MOUND:  # rim on the surface, a skirt below it
                assert lo[2] < z0 and obj.position_m[2] == z0
            else:
                assert abs(lo[2] - z0) < 1e-9, (seed, obj.shape, lo[2])
            # inside the support's top (the table, the yard slab)
            assert np.all(np.abs(lo[:2]) <= np.asarray(support.size_m) / 2)
            assert np.all(np.abs(hi[:2]) <= np.asarray(support.size_m) / 2)
    assert len(shapes) >= 7


@pytest.mark.parametrize("preset", FAMILIES)
def test_seed_draws_the_rig_and_cameras_stay_clear_of_objects(preset: str) -> None:
    rigs, suns = set(), set()
    for seed in range(8):
        layout_rng, rig_rng = _rngs(seed)
        p, description = preset_for_seed(PRESETS[preset], layout_rng, rig_rng)
        assert description is not None and p.name == preset
        rigs.add(p.rig)
        suns.add((p.environment.sun_azimuth_deg, p.environment.sun_elevation_deg))
        bounds = draw_layout(FAMILIES[preset], _rngs(seed)[0]).object_bounds()
        train, test = build_cameras(p.rig, p.width, p.height, np.zeros(3))
        for cams in (train, test):
            for view in cams:
                c = view.center
                inside = np.all((c >= bounds[:, 0] - 1e-3) & (c <= bounds[:, 1] + 1e-3), axis=1)
                assert not inside.any() and c[2] > description["support"]["surface_z_m"], (seed, view.name)
        # overrides still apply to the drawn rig
        small = apply_overrides(p, views=6, test_views=1, width=48, height=36)
        assert (small.width, small.height, small.rig.n_test) == (48, 36, 1)
        if preset == "random-object":
            assert 2 <= len(p.rig.elevations_deg) <= 3 and small.n_train == 6
    assert len(rigs) == 8 and len(suns) == 8


def test_fixed_presets_are_unchanged_by_seed_resolution() -> None:
    for name in ("tiny", "tabletop", "aerial", "demo", "textured"):
        p, description = preset_for_seed(PRESETS[name], *_rngs(0))
        assert p is PRESETS[name] and description is None


def test_seed_ranges_are_disjoint() -> None:
    assert not set(TUNING_SEEDS) & set(SCORING_SEEDS)
    assert (min(SCORING_SEEDS), max(SCORING_SEEDS)) == (100, 199)
