"""Manifest: timings and counts recorded, stages skipped only when nothing they depend on changed."""

import json

import numpy as np

from hybridsplat.manifest import Manifest, StageOutcome, hash_path


def test_stage_runs_once_and_reruns_on_change(tmp_path):
    src = tmp_path / "in.txt"
    src.write_text("a")
    out = tmp_path / "out.txt"
    calls = []

    def stage():
        calls.append(1)
        out.write_text(src.read_text() * 2)
        return StageOutcome(counts={"chars": 2})

    m = Manifest(tmp_path)
    rec = m.run_stage("double", stage, inputs=[src], outputs=[out], config={"k": 1})
    assert not rec.cached and rec.counts == {"chars": 2} and len(calls) == 1
    rec = Manifest(tmp_path).run_stage("double", stage, inputs=[src], outputs=[out], config={"k": 1})
    assert rec.cached and len(calls) == 1 and "up to date" in rec.reason
    src.write_text("b")  # input changed
    Manifest(tmp_path).run_stage("double", stage, inputs=[src], outputs=[out], config={"k": 1})
    assert len(calls) == 2 and out.read_text() == "bb"
    Manifest(tmp_path).run_stage("double", stage, inputs=[src], outputs=[out], config={"k": 2})  # config changed
    assert len(calls) == 3
    out.unlink()  # output gone
    Manifest(tmp_path).run_stage("double", stage, inputs=[src], outputs=[out], config={"k": 2})
    assert len(calls) == 4
    payload = json.loads((tmp_path / "manifest.json").read_text())
    assert payload["stages"]["double"]["seconds"] >= 0 and "numpy" in payload["versions"]


def test_skip_reason_and_peak_memory(tmp_path):
    m = Manifest(tmp_path)
    rec = m.run_stage(
        "train", lambda: StageOutcome(skipped=True, reason="no non-collaborative region"), inputs=[], outputs=[]
    )
    assert rec.skipped and rec.reason == "no non-collaborative region"

    def allocate():
        block = np.ones(300 * 2**20 // 8)  # 300 MB, touched
        return StageOutcome(counts={"sum": float(block[:10].sum())})

    rec = m.run_stage("alloc", allocate, inputs=[], outputs=[])
    assert rec.peak_mb > 300


def test_hash_of_folder_changes_with_content(tmp_path):
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "x").write_text("1")
    h1 = hash_path(tmp_path / "d")
    (tmp_path / "d" / "x").write_text("2")
    assert hash_path(tmp_path / "d") != h1
    assert hash_path(tmp_path / "nothing") == "missing"
