"""The collaborative-only variant of the tabletop: same objects, every surface textured, no thin wire."""

import numpy as np

from data_synth.materials import MATERIALS
from data_synth.presets import PRESETS
from data_synth.scenes import LAYOUTS


def _materials(layout: str) -> set[str]:
    mesh = LAYOUTS[layout](np.random.default_rng(0))
    names = {m.id: m.name for m in (MATERIALS.values() if isinstance(MATERIALS, dict) else MATERIALS)}
    return {names[int(i)] for i in np.unique(mesh.face_material)}


def test_textured_layout_has_only_collaborative_materials_and_the_same_objects():
    by_name = {m.name: m for m in (MATERIALS.values() if isinstance(MATERIALS, dict) else MATERIALS)}
    full, textured = _materials("tabletop"), _materials("tabletop_textured")
    assert any(not by_name[n].collaborative for n in full)  # the original has every hard material
    assert textured and all(by_name[n].collaborative for n in textured)
    assert "wire" not in textured
    a = LAYOUTS["tabletop"](np.random.default_rng(0))
    b = LAYOUTS["tabletop_textured"](np.random.default_rng(0))
    wire = by_name["wire"].id
    kept = a.face_material != wire
    # the same jittered geometry where the wire cage is dropped: every other face is at the same place
    assert len(b.faces) == int(kept.sum())
    np.testing.assert_allclose(np.sort(b.vertices[b.faces].reshape(-1, 3), axis=0),
                               np.sort(a.vertices[a.faces[kept]].reshape(-1, 3), axis=0))  # fmt: skip


def test_demo_presets_are_the_reduced_tabletop():
    demo, textured = PRESETS["demo"], PRESETS["textured"]
    assert (demo.width, demo.height, demo.n_train, demo.rig.n_test) == (320, 240, 24, 4)
    assert demo.layout == "tabletop" and textured.layout == "tabletop_textured"
    assert textured.rig == demo.rig and textured.lidar == demo.lidar
