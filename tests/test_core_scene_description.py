"""core.io.scene_description: the one scene.json reader, checked against a hand-written file and the writer."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from core.errors import FormatError, InputFileError
from core.io.scene_description import read_scene_description

GOOD = {
    "preset": "tiny",
    "seed": 3,
    "units": "m",
    "origin": [500000.25, 5400000.5, 312.125],
    "gsd_m": 0.004,
    "crs": "EPSG:32632",
    "materials": [
        {"id": 0, "name": "bricks", "kind": "textured", "collaborative": True, "why": "texture"},
        {"id": 7, "name": "mirror", "kind": "mirror", "collaborative": False, "why": "reflections"},
    ],
    "views": {"train": ["a.png", "b.png"], "test": ["t.png"]},
    "rig": {"kind": "orbit"},
}


def _write(path: Path, data) -> Path:
    path.write_text(json.dumps(data) if not isinstance(data, str) else data, encoding="utf-8")
    return path


def test_fields_are_read_exactly(tmp_path: Path):
    desc = read_scene_description(_write(tmp_path / "scene.json", GOOD))
    assert desc.origin == (500000.25, 5400000.5, 312.125)  # float64, exact
    assert desc.gsd_m == 0.004 and desc.crs == "EPSG:32632" and desc.units == "m"
    assert desc.preset == "tiny" and desc.seed == 3
    assert [m.name for m in desc.materials] == ["bricks", "mirror"]
    assert desc.non_collaborative_ids == (7,) and desc.material_ids(collaborative=True) == (0,)
    assert desc.material(7).kind == "mirror"
    assert desc.splits["train"] == ("a.png", "b.png") and desc.splits["test"] == ("t.png",)
    assert desc.extra["rig"] == {"kind": "orbit"} and "materials" not in desc.extra
    assert read_scene_description(tmp_path) == desc  # a folder holding scene.json works the same


def test_minimal_file_has_defaults(tmp_path: Path):
    desc = read_scene_description(_write(tmp_path / "scene.json", {}))
    assert desc.origin == (0.0, 0.0, 0.0) and desc.gsd_m is None and desc.crs is None
    assert desc.materials == () and dict(desc.splits) == {}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"units": "mm"}, "units must be 'm'"),
        ({"origin": [1, 2]}, "origin must be a list of 3"),
        ({"origin": [1, "x", 3]}, "origin must be a number"),
        ({"gsd_m": -1}, "gsd_m must be > 0"),
        ({"gsd_m": float("nan")}, "gsd_m must be finite"),
        ({"crs": 4326}, "crs must be a string"),
        ({"materials": [{"id": 1, "name": "a", "kind": "k"}]}, r"materials\[0\] lacks 'collaborative'"),
        ({"materials": [{"id": 300, "name": "a", "kind": "k", "collaborative": True}]}, "0..254"),
        ({"materials": [{"id": 1, "name": "a", "kind": "k", "collaborative": "yes"}]}, "true or false"),
        (
            {"materials": [{"id": 1, "name": n, "kind": "k", "collaborative": True} for n in "ab"]},
            "repeat an id",
        ),
        ({"views": {"train": "a.png"}}, "views.train must be a list"),
        ({"seed": 1.5}, "seed must be an integer"),
    ],
)
def test_invalid_content_names_the_file_and_the_problem(tmp_path: Path, change, message):
    path = _write(tmp_path / "scene.json", {**GOOD, **change})
    with pytest.raises(FormatError, match=message) as err:
        read_scene_description(path)
    assert err.value.path == path


def test_missing_and_broken_files(tmp_path: Path):
    with pytest.raises(InputFileError, match="does not exist"):
        read_scene_description(tmp_path / "scene.json")
    path = _write(tmp_path / "scene.json", "{not json")
    with pytest.raises(FormatError, match="not valid JSON") as err:
        read_scene_description(path)
    assert err.value.path == path
    with pytest.raises(FormatError, match="expected a JSON object"):
        read_scene_description(_write(path, "[1, 2]"))


def test_reads_what_data_synth_writes(tmp_path: Path):
    """Round trip through the scene writer: the legend equals the materials' own legend entries."""
    from data_synth.layout import SceneLayout
    from data_synth.materials import material
    from data_synth.writer import write_scene_json

    mats = [material("bricks"), material("mirror")]
    layout = SceneLayout(tmp_path)
    write_scene_json(layout, {"units": "m", "origin": [1.0, 2.0, 3.0], "materials": [m.legend_entry() for m in mats]})
    desc = read_scene_description(layout.scene_json)
    assert [(e.id, e.name, e.kind, e.collaborative) for e in desc.materials] == [
        (m.id, m.name, m.kind.value, m.collaborative) for m in mats
    ]
