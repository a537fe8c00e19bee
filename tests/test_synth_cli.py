"""The ``hybridsplat synth`` command and the generator's handling of bad options and failures."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from core.errors import ConfigError
from data_synth import generate_scene, writer
from hybridsplat.cli import main


def test_cli_generates_a_scene_with_overrides(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "scene"
    args = ["synth", "--preset", "tiny", "--seed", "2", "--out", str(out), "--views", "4", "--test-views", "1"]
    main([*args, "--width", "48", "--height", "36", "--lidar-noise", "0"])  # returns normally on success
    meta = json.loads((out / "scene.json").read_text())
    assert meta["seed"] == 2 and len(meta["views"]["train"]) == 4 and len(meta["views"]["test"]) == 1
    assert meta["image_size"] == {"width": 48, "height": 36}
    assert meta["rig"]["lidar_noise"]["sigma_m"] == 0.0
    assert "wrote" in capsys.readouterr().out

    with pytest.raises(SystemExit) as ex:  # refuses to overwrite
        main(args)
    assert ex.value.code == 2
    assert "not empty" in capsys.readouterr().err


def test_cli_rejects_unknown_preset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as ex:
        main(["synth", "--preset", "moon", "--out", str(tmp_path / "x")])
    assert ex.value.code == 2
    assert "tiny, tabletop, aerial, demo, textured" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_failure_leaves_no_half_written_scene(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(writer, "write_cloud", broken)
    with pytest.raises(OSError):
        generate_scene("tiny", tmp_path / "scene", views=3, test_views=1)
    assert list(tmp_path.iterdir()) == []


def test_bad_seed_and_overrides_are_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError):
        generate_scene("tiny", tmp_path / "a", seed=-1)
    with pytest.raises(ConfigError):
        generate_scene("tiny", tmp_path / "b", views=0)
    with pytest.raises(ConfigError):
        generate_scene("tiny", tmp_path / "c", origin=(1.0, float("nan"), 0.0))


def test_overwrite_replaces_an_existing_scene(tmp_path: Path) -> None:
    out = generate_scene("tiny", tmp_path / "s", views=3, test_views=1, width=32, height=24)
    (out / "stale.txt").write_text("old")
    generate_scene("tiny", out, views=3, test_views=1, width=32, height=24, overwrite=True)
    assert not (out / "stale.txt").exists() and (out / "scene.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]
