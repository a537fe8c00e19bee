"""The runner: stages run once, rerun when inputs or options change, skip with reasons, and never leave an output
that looks current after a failure or an interruption."""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from hybridsplat.config import ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.manifest import Manifest, hash_path
from hybridsplat.runner import run_stages
from hybridsplat.stages.base import Stage, StageContext, StageResult
from hybridsplat.terminal import Terminal


@dataclass(frozen=True)
class DoubleOptions:
    times: int = 2


@dataclass(frozen=True)
class DoubleResult(StageResult):
    chars: int = 0


class Double(Stage):
    """Toy stage: writes the input text repeated ``times`` times; can be told to fail halfway."""

    name = "double"
    Options = DoubleOptions
    Result = DoubleResult

    def __init__(self, src: Path, out: Path, fail_with: BaseException | None = None) -> None:
        self.src, self.out, self.fail_with, self.calls = src, out, fail_with, 0

    def inputs(self, ctx):
        return [self.src]

    def outputs(self, ctx):
        return [self.out]

    def run(self, ctx):
        self.calls += 1
        self.out.write_text(self.src.read_text() * ctx.options(self).times)  # a partial output first
        if self.fail_with is not None:
            raise self.fail_with
        return DoubleResult(len(self.out.read_text()))


class Unneeded(Stage):
    name = "train"

    def __init__(self, out: Path) -> None:
        self.out = out

    def outputs(self, ctx):
        return [self.out]

    def needs(self, ctx):
        return "no non-collaborative region"


def _ctx(root: Path, times: int = 2) -> StageContext:
    config = ProjectConfig(stages={"double": DoubleOptions(times)})
    return StageContext(layout=ProjectLayout(root), config=config, source=None)  # type: ignore[arg-type]


def _run(root: Path, stages, times: int = 2, force=()):
    return run_stages(_ctx(root, times), stages, Terminal(quiet=True), force)


def test_stage_runs_once_and_reruns_on_change(tmp_path):
    src, out = tmp_path / "in.txt", tmp_path / "out.txt"
    src.write_text("a")
    stage = Double(src, out)
    rec = _run(tmp_path, [stage]).stages["double"]
    assert not rec.cached and rec.counts == {"chars": 2} and stage.calls == 1
    rec = _run(tmp_path, [stage]).stages["double"]
    assert rec.cached and stage.calls == 1 and "up to date" in rec.reason
    src.write_text("b")  # input changed
    _run(tmp_path, [stage])
    assert stage.calls == 2 and out.read_text() == "bb"
    _run(tmp_path, [stage], times=3)  # options changed
    assert stage.calls == 3 and out.read_text() == "bbb"
    out.unlink()  # output gone
    _run(tmp_path, [stage], times=3)
    assert stage.calls == 4
    _run(tmp_path, [stage], times=3, force=["double"])
    assert stage.calls == 5
    payload = Manifest(tmp_path / "manifest.json")
    assert payload.stages["double"].seconds >= 0 and payload.stages["double"].config["options"] == {"times": 3}


@pytest.mark.parametrize("failure", [RuntimeError("boom"), KeyboardInterrupt()])
def test_failure_or_interruption_leaves_no_current_looking_output(tmp_path, failure):
    src, out = tmp_path / "in.txt", tmp_path / "out.txt"
    src.write_text("a")
    _run(tmp_path, [Double(src, out)])
    assert out.read_text() == "aa"
    src.write_text("b")
    with pytest.raises(type(failure)):
        _run(tmp_path, [Double(src, out, fail_with=failure)])
    assert not out.exists(), "the failed stage's partial output and its previous output are both gone"
    assert "double" not in Manifest(tmp_path / "manifest.json").stages  # invalidated: the next run must run it
    rerun = Double(src, out)
    _run(tmp_path, [rerun])
    assert rerun.calls == 1 and out.read_text() == "bb"


def test_unneeded_stage_is_skipped_with_reason_and_stale_output_removed(tmp_path):
    stale = tmp_path / "splats.ply"
    stale.write_text("from an earlier run")
    rec = _run(tmp_path, [Unneeded(stale)]).stages["train"]
    assert rec.skipped and rec.reason == "no non-collaborative region"
    assert not stale.exists()


def test_peak_memory_is_recorded(tmp_path):
    @dataclass(frozen=True)
    class Sum(StageResult):
        sum: float = 0.0

    class Allocate(Stage):
        name = "alloc"
        Result = Sum

        def run(self, ctx):
            block = np.ones(300 * 2**20 // 8)  # 300 MB, touched
            return Sum(block[:10].sum())

    rec = _run(tmp_path, [Allocate()]).stages["alloc"]
    assert rec.peak_mb > 300 and rec.counts == {"sum": 10.0}


def test_hash_of_folder_changes_with_content(tmp_path):
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "x").write_text("1")
    h1 = hash_path(tmp_path / "d")
    (tmp_path / "d" / "x").write_text("2")
    assert hash_path(tmp_path / "d") != h1
    assert hash_path(tmp_path / "nothing") == "missing"
