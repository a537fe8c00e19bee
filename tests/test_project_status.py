"""``hybridsplat status`` on a fresh, a half-run, a finished and a modified project (issue 35)."""

from __future__ import annotations

import json
import re

import pytest

from data_synth import generate_scene
from fusion.train.masked import MaskedTrainingOptions
from hybridsplat.cli import run_cli
from hybridsplat.config import InputOptions, ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.options import options_with
from hybridsplat.pipeline import run_pipeline
from hybridsplat.project_status import project_status
from hybridsplat.stages import stage_named, stage_names

FAST = {"train": options_with(MaskedTrainingOptions, {"training.iterations": 40, "snapshot_iterations": [20]})}


def _states(project) -> dict[str, str]:
    return {s.name: s.state for s in project_status(project).stages}


def _printed(capsys, *args: str) -> str:
    assert run_cli(["status", *args]) == 0
    return capsys.readouterr().out


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    root = tmp_path_factory.mktemp("status")
    scene = generate_scene("tiny", root / "scene", seed=0)
    config = ProjectConfig(input=InputOptions(path=str(scene)), stages=FAST)
    run_pipeline(root / "finished", config)
    return scene, config, root / "finished"


def test_fresh_and_half_run_projects(finished, tmp_path, capsys):
    scene, config, _ = finished
    fresh = tmp_path / "fresh"
    run_pipeline(fresh, config, stages=[])  # the folder and config.toml, no stage yet
    states = _states(fresh)
    assert states["sfm"] == "not run" and states["report"] == "not run"
    assert states["train"] == "waiting"  # "no classified cloud" now; decided again once classify has run
    half = tmp_path / "half"
    run_pipeline(half, config, stages=[stage_named("sfm"), stage_named("mvs")])
    states = _states(half)
    assert states["sfm"] == "current" and states["mvs"] == "current" and states["classify"] == "not run"
    text = _printed(capsys, str(half))
    assert re.search(r"^  mvs\s+current\s+[\d.]+ s\s+\d+ MB peak\s+[\d.]+ [kM]B", text, re.M), text
    assert "cpu: 10 views at 96 px" in text  # the stage's own summary of what it made
    print("--- fresh ---\n" + _printed(capsys, str(fresh)) + "--- half-run ---\n" + text)


def test_finished_then_one_option_changed(finished, tmp_path, capsys):
    _, _, project = finished
    states = _states(project)
    assert set(states.values()) == {"current", "skipped"}, states
    assert [n for n, s in states.items() if s == "skipped"] == ["control", "tiles", "mesh", "baseline"]
    data = json.loads(_printed(capsys, str(project), "--json"))
    assert [s["name"] for s in data["stages"]] == list(stage_names()) and data["writer"] is None
    mvs = next(s for s in data["stages"] if s["name"] == "mvs")
    assert mvs["counts"]["points"] > 0 and mvs["seconds"] > 0 and mvs["bytes_written"] > 0
    config = ProjectLayout(project).config
    before = config.read_text()
    try:
        config.write_text(before.replace("iterations = 40\n", "iterations = 50\n", 1))
        states = _states(project)
        stale = {n for n, s in states.items() if s == "stale"}
        assert stale == {"train", "clean", "background", "appearance", "merge", "eval", "report"}
        assert all(states[n] == "current" for n in ("sfm", "mvs", "classify", "masks", "convert"))
        text = _printed(capsys, str(project))
        assert "option training.iterations: 40 -> 50" in text and "after train, which will run first" in text
        print("--- finished, then [train.training] iterations = 50 ---\n" + text)
    finally:
        config.write_text(before)
    assert _states(project)["train"] == "current"


def test_an_input_that_changed_or_went_missing_is_named(finished, tmp_path):
    scene, config, _ = finished
    project = tmp_path / "p"
    run_pipeline(project, config, stages=[stage_named("sfm"), stage_named("mvs")])
    (ProjectLayout(project).sparse / "points3D.bin").write_bytes(b"changed")
    status = {s.name: s for s in project_status(project).stages}
    assert status["mvs"].state == "stale" and "input sparse changed" in status["mvs"].reasons
    assert status["sfm"].state == "current"  # as the runner sees it: sfm's inputs are the photos
    (ProjectLayout(project).dense / "fused.ply").unlink()
    assert "output dense/fused.ply missing" not in project_status(project).stages[1].reasons  # dense/ is there
    import shutil

    shutil.rmtree(ProjectLayout(project).dense)
    assert "output dense missing" in {s.name: s for s in project_status(project).stages}["mvs"].reasons


def test_a_folder_that_is_not_a_project(tmp_path, capsys):
    assert run_cli(["status", str(tmp_path)]) == 2
    assert "not a hybridsplat project (no config.toml)" in capsys.readouterr().err
    assert run_cli(["eval", "project", str(tmp_path)]) == 2  # one line naming the missing file, nothing written
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "config.toml" in err[0] and "not a hybridsplat project" in err[0]
    assert list(tmp_path.iterdir()) == []
