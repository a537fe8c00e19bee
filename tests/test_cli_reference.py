"""docs/cli.md against the command line: the committed reference is what the commands say, every option has help,
every stage's declared option is in it, and every value it lists for an option passes the real parser.

The values are run through ``hybridsplat ...`` in-process (:func:`hybridsplat.cli.run_cli`) and followed to where
the command hands them on: the configuration given to the pipeline (stage options, ``[input]``), or the call the
command makes with them (render backend, preset, layers), with the heavy work after that replaced by a recorder.
"""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import numpy as np
import pytest

from core.errors import ConfigError
from hybridsplat.cli import run_cli
from hybridsplat.cli_reference import command_tree, entries, help_values, render

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "docs" / "cli.md"
ENTRIES = entries()
COMMANDS = {" ".join(path[1:]): cmd for path, cmd, _ in command_tree()}
#: examples for the placeholders a value list may name
PLACEHOLDERS = {"NxM": "3x2", "PATH": "models/mine.skops"}
#: options of the pipeline commands that set ``[input]`` rather than a stage option
INPUT_KEYS = {"--units": "units"}


def test_reference_is_the_command_line():
    assert REFERENCE.read_text(encoding="utf-8") == render(), (
        "docs/cli.md is out of date: run PYTHONPATH=$PWD .venv/bin/python scripts/gen_cli_reference.py"
    )


def test_every_argument_and_option_has_help():
    missing = [f"{e.command or 'hybridsplat'} {e.name}" for e in ENTRIES if not (e.param.help or "").strip()]
    assert not missing, f"options without help (they would have no entry in docs/cli.md): {missing}"


def test_every_declared_stage_option_is_in_the_reference():
    from hybridsplat.stages import registered_stages

    found = {(d.stage, d.path) for e in ENTRIES for d in e.declared}
    declared = {(s.name, o.path) for s in registered_stages() for o in (*s.run_options, *s.command_options)}
    assert declared - found == set()


def test_help_values_reads_a_value_list():
    text = "auto (exhaustive up to 150 photos; else sequential) | exhaustive | spatial. Or m | ft."
    assert help_values(text) == ["auto", "exhaustive", "spatial", "m", "ft"]
    assert help_values("Bound the memory (MiB, at least 704).") == []


def test_tiles_off_as_documented_is_accepted(tmp_path, monkeypatch):
    """The issue's case: ``run SCENE --out P --tiles off`` was refused ("got 'none'")."""
    seen = _fake_pipeline(monkeypatch, tmp_path)
    code = run_cli(["run", str(tmp_path), "--out", str(tmp_path / "p"), "--tiles", "off"])
    assert code == 0 and seen[0].stages["tiles"].grid == "off"


CASES = [(e, v) for e in ENTRIES for v in e.values]


@pytest.mark.parametrize(("entry", "value"), CASES, ids=[f"{e.command}{e.name}={v}" for e, v in CASES])
def test_every_listed_value_passes_the_parser(entry, value, tmp_path, monkeypatch, capsys):
    given = PLACEHOLDERS.get(value, value)
    assert given == value or value in PLACEHOLDERS, f"no example for the placeholder {value!r}"
    flag = entry.param.opts[-1]
    if entry.declared or entry.name in INPUT_KEYS:
        _check_pipeline_value(entry, flag, given, tmp_path, monkeypatch, capsys)
    elif entry.param.type_descriptor.is_choice:  # typer's own choice: its parser alone, the command not run
        ctx = COMMANDS[entry.command].make_context(entry.command, [*_required(entry, tmp_path), flag, given])
        assert _plain(ctx.params[entry.param.name]) == given
    else:
        check = CHECKS.get(entry.command)
        assert check is not None, f"no check of the values of {entry.command} {flag}: add one to CHECKS"
        check(flag, given, tmp_path, monkeypatch, capsys)


# ----------------------------------------------------------------------------------------------- pipeline commands


def _fake_pipeline(monkeypatch, tmp_path) -> list:
    """Record the configuration the command gives the pipeline instead of running it."""
    import hybridsplat.pipeline as pipeline
    from hybridsplat.config import InputOptions, ProjectConfig

    seen: list = []
    monkeypatch.setattr(pipeline, "run_pipeline", lambda project, config, *a, **k: seen.append(config))
    monkeypatch.setattr(pipeline, "load_config", lambda project: ProjectConfig(input=InputOptions(path=str(tmp_path))))
    return seen


def _required(entry, tmp_path) -> list[str]:
    """The command's arguments and required options (but ``entry``'s), as paths under ``tmp_path``."""
    params = [e.param for e in ENTRIES if e.command == entry.command]
    args = []
    for p in params:
        if p.param_type_name == "argument":
            args.append(str(tmp_path / f"missing_{p.name}"))
        elif p.required and p is not entry.param:
            args += [p.opts[-1], str(tmp_path / f"missing_{p.name}")]
    return args


def _plain(value):
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return "none" if value is None else value


def _at(options, path: str):
    for part in path.split("."):
        options = getattr(options, part)
    return options


def _check_pipeline_value(entry, flag, given, tmp_path, monkeypatch, capsys):
    seen = _fake_pipeline(monkeypatch, tmp_path)
    args = [*entry.command.split(), str(tmp_path)]
    if entry.command in ("run", "sfm"):
        args += ["--out", str(tmp_path / "p")]
    code = run_cli([*args, flag, given])
    assert code == 0, capsys.readouterr().err
    (config,) = seen
    if entry.name in INPUT_KEYS:
        assert getattr(config.input, INPUT_KEYS[entry.name]) == given
    for d in entry.declared:
        got = _plain(_at(config.stages[d.stage], d.path))
        assert given in got if isinstance(got, list) else str(got) == given, (d.stage, d.path, got)


# ---------------------------------------------------------------------------------------------- the file commands


def _tiny_product(tmp_path) -> Path:
    """A 3DGS PLY of six Gaussians, two of each layer (``source`` 1 survey, 2 fill, 3 background)."""
    from core.gaussians import GaussianSet
    from core.io.gaussian_ply import write_gaussian_ply

    rng = np.random.default_rng(0)
    gs = GaussianSet(
        means=rng.normal(size=(6, 3)),
        log_scales=np.full((6, 3), -3.0),
        quats=np.tile([1.0, 0, 0, 0], (6, 1)),
        logit_opacities=np.full(6, 2.0),
        sh_dc=rng.uniform(-1, 1, (6, 3)),
        fields={"source": np.array([1, 1, 2, 2, 3, 3], np.uint8)},
    )
    return write_gaussian_ply(tmp_path / "product.ply", gs, extra_fields=True)


def _check_export(flag, given, tmp_path, monkeypatch, capsys):
    """A real export of the tiny product: the value reaches the writer and the output is made."""
    out = {"--gltf-compression": "tiles/tileset.json", "--spz-version": "x.spz", "--layers": "x.ply"}[flag]
    code = run_cli(["export", str(_tiny_product(tmp_path)), "--out", str(tmp_path / out), flag, given])
    assert code == 0, capsys.readouterr().err
    assert (tmp_path / out).is_file()
    if flag == "--spz-version":
        import gzip

        assert int.from_bytes(gzip.decompress((tmp_path / out).read_bytes())[4:8], "little") == int(given)


def _check_render(flag, given, tmp_path, monkeypatch, capsys):
    """The value as render hands it on: the backend resolved, the layers kept (the rendering itself recorded)."""
    import fusion.render
    from core.cameras import Camera, Cameras, View
    from core.io.colmap import write_model

    cameras = Cameras(
        {1: Camera.pinhole(8.0, 8.0, 4.0, 3.0, 8, 6)}, {1: View.from_matrix(1, "a.jpg", 1, np.eye(4)[:3])}
    )
    write_model(tmp_path / "sparse", cameras)
    seen = []

    def record(splats, camera, view, **kwargs):
        seen.append((len(splats), kwargs["backend"]))
        raise ConfigError("recorded")

    monkeypatch.setattr(fusion.render, "render_gaussian_set", record)
    args = [str(_tiny_product(tmp_path)), "--cameras", str(tmp_path / "sparse"), "--out", str(tmp_path / "r")]
    run_cli(["render", *args, flag, given])
    assert seen, capsys.readouterr().err
    (count, backend), = seen  # fmt: skip
    if flag == "--backend":
        assert backend.value == given or given == "auto"
    else:
        assert count == 2


def _check_view(flag, given, tmp_path, monkeypatch, capsys):
    import hybridsplat.viewer.app as app

    seen = []

    class Recorder:
        layers, port = (), 0

        def __init__(self, scene, options, files):
            seen.append(scene)

        def stop(self):
            pass

    monkeypatch.setattr(app, "ViewerApp", Recorder)
    code = run_cli(["view", str(_tiny_product(tmp_path)), "--seconds", "0.01", flag, given])
    assert code == 0, capsys.readouterr().err
    assert len(seen[0].splats.centers) == 2


def _check_synth(flag, given, tmp_path, monkeypatch, capsys):
    """The preset name as the scene generator looks it up (the ray tracing after it not run)."""
    import data_synth.generate as generate

    seen, real = [], generate.get_preset

    def lookup(name):
        seen.append(real(name))  # the real look-up: a ConfigError for a name it does not know
        raise ConfigError("recorded")

    monkeypatch.setattr(generate, "get_preset", lookup)
    run_cli(["synth", "--out", str(tmp_path / "scene"), flag, given])
    assert len(seen) == 1, capsys.readouterr().err


CHECKS = {"export": _check_export, "render": _check_render, "view": _check_view, "synth": _check_synth}
