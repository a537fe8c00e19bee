"""Adding a stage is one module and one registration line: a toy stage registered that way runs, is up to date on a
second run, has its own command and ``run`` option in ``--help``, and its section in the report."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.io.images import write_image
from hybridsplat.cli import build_app, run_cli
from hybridsplat.layout import ProjectLayout
from hybridsplat.stages import register_stage, stage_names, unregister_stage

TOY_MODULE = '''
from dataclasses import dataclass

from hybridsplat.stages.base import CliOption, ReportSection, Stage, StageResult


@dataclass(frozen=True)
class ToyOptions:
    """factor: how many times the photo count is written."""

    factor: int = 2


@dataclass(frozen=True)
class ToyResult(StageResult):
    """photos: the input's photos; factor: how many times their count was written."""

    photos: int = 0
    factor: int = 0


class ToyStage(Stage):
    name = "toy"
    Options = ToyOptions
    Result = ToyResult
    title = "toy stage"
    command = "toy"
    command_help = "Write the photo count, factor times."
    command_options = (CliOption("factor", help="How many times."),)
    run_options = (CliOption("factor", "--toy-factor", help="The toy stage's factor."),)

    def outputs(self, ctx):
        return [ctx.layout.root / "toy.txt"]

    def run(self, ctx):
        n = len(ctx.source.spec.image_names)
        (ctx.layout.root / "toy.txt").write_text(str(n) * ctx.options(self).factor)
        return ToyResult(photos=n, factor=ctx.options(self).factor)

    def summary(self, result):
        return f"{result.photos} photos"

    def report_section(self, result):
        return ReportSection("Toy", (f"toy counted {result.photos} photos, factor {result.factor}",))
'''


@pytest.fixture
def toy(tmp_path, monkeypatch):
    (tmp_path / "toystage.py").write_text(TOY_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    register_stage("toy", "toystage:ToyStage", after="report")  # the one registration line
    yield build_app()
    unregister_stage("toy")


def _photos(root):
    for i in range(3):
        write_image(root / f"p{i}.png", np.full((8, 8, 3), 100 + i, np.uint8))
    return root


def test_a_registered_toy_stage_runs_skips_when_current_and_shows_in_help_and_report(toy, tmp_path, capsys):
    assert stage_names()[-2:] == ("report", "toy")
    assert run_cli(["--help"], toy) == 0
    assert "toy" in capsys.readouterr().out
    assert run_cli(["run", "--help"], toy) == 0
    assert "--toy-factor" in capsys.readouterr().out
    assert run_cli(["toy", "--help"], toy) == 0
    assert "--factor" in capsys.readouterr().out

    from hybridsplat.config import InputOptions, ProjectConfig
    from hybridsplat.pipeline import run_pipeline
    from hybridsplat.stages import stage_named

    project = tmp_path / "project"
    photos = _photos(tmp_path / "photos")
    run_pipeline(project, ProjectConfig(input=InputOptions(path=str(photos))), [stage_named("toy")])
    layout = ProjectLayout(project)
    assert (project / "toy.txt").read_text() == "33"
    assert run_cli(["toy", str(project), "--factor", "3"], toy) == 0  # an option changed: it runs again
    assert (project / "toy.txt").read_text() == "333"
    record = json.loads(layout.manifest.read_text())["stages"]["toy"]
    assert not record["cached"] and record["counts"] == {"photos": 3, "factor": 3}  # its result, field by field
    from hybridsplat.project_io import stage_result

    assert stage_result(layout, stage_named("toy")) == stage_named("toy").Result(photos=3, factor=3)
    assert "factor = 3" in layout.config.read_text()  # recorded in the project's configuration
    assert run_cli(["toy", str(project)], toy) == 0  # nothing changed: up to date
    assert json.loads(layout.manifest.read_text())["stages"]["toy"]["cached"]
    assert run_cli(["report", str(project)], toy) == 0
    assert "toy counted 3 photos, factor 3" in layout.report_md.read_text()
    assert "toy counted 3 photos, factor 3" in layout.report_html.read_text()


def test_unregistered_toy_is_gone(toy):
    unregister_stage("toy")
    assert "toy" not in stage_names()
    register_stage("toy", "toystage:ToyStage")  # the fixture removes it again
    assert stage_names()[-1] == "toy"
