"""A run over an existing project says which options of its config.toml it replaced (``run`` rebuilds the file from
its own command line, so a hand edit is overwritten: the line makes that visible)."""

from __future__ import annotations

from pathlib import Path

from hybridsplat.config import ProjectConfig
from hybridsplat.pipeline import config_changes, describe_changes
from hybridsplat.stages import registered_stages


def test_the_changed_keys_are_exactly_those_that_differ(tmp_path: Path):
    old = tmp_path / "config.toml"
    old.write_text('seed = 0\n[input]\npath = "a"\n[stages.background]\nenvironment_radius_px = 8.0\nenabled = true\n')
    new = 'seed = 0\n[input]\npath = "a"\n[stages.background]\nenvironment_radius_px = 0.0\n[stages.mesh]\nbudget = 5\n'
    assert config_changes(old, new) == [
        ("stages.background.enabled", True, None),
        ("stages.background.environment_radius_px", 8.0, 0.0),
        ("stages.mesh.budget", None, 5),
    ]
    assert config_changes(old, old.read_text()) == []


def test_no_file_or_an_unreadable_one_reports_nothing(tmp_path: Path):
    assert config_changes(tmp_path / "missing.toml", "seed = 1\n") == []
    broken = tmp_path / "config.toml"
    broken.write_text("seed = = 1\n")
    assert config_changes(broken, "seed = 1\n") == []


def test_a_whole_config_round_trip_changes_nothing_and_one_edit_is_named(tmp_path: Path):
    from dataclasses import replace

    from hybridsplat.commands.common import input_options_from_cli

    stages = {s.name: s.Options() for s in registered_stages()}
    config = ProjectConfig(input=input_options_from_cli(tmp_path), seed=0, stages=stages)
    path = tmp_path / "config.toml"
    path.write_text(config.to_toml())
    assert config_changes(path, config.to_toml()) == []
    edited = ProjectConfig(input=config.input, seed=0, stages={**stages, "mesh": replace(stages["mesh"], budget=7)})
    changes = config_changes(path, edited.to_toml())
    assert [(key.split(".")[-1], old, new) for key, old, new in changes] == [("budget", 0, 7)]
    line = describe_changes(changes)
    assert line.startswith("1 option(s) replaced") and "budget 0 -> 7" in line


def test_the_description_lists_a_few_and_counts_the_rest():
    changes = [(f"k{i}", i, i + 1) for i in range(6)]
    line = describe_changes(changes, most=2)
    assert "k0 0 -> 1, k1 1 -> 2 and 4 more" in line and line.startswith("6 option(s)")
