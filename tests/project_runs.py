"""``hybridsplat run`` on the tiny preset in a subprocess, and the products two runs are compared by.

Shared by the tests that disturb a run (Ctrl-C, a second writer, a reader) and compare its products with those of
an undisturbed run (the session fixture ``tiny_reference`` in ``conftest.py``).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from core.io.ply import read_ply
from eval.metrics_io import read_metrics
from hybridsplat.layout import ProjectLayout

REPO = Path(__file__).resolve().parents[1]


def _default_sigint() -> None:
    # A test run started in the background by a non-interactive shell inherits SIGINT ignored, and Python then
    # installs no KeyboardInterrupt handler: give the child the disposition of a foreground terminal.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_cli(*args: str, user: list[str] | None = None) -> subprocess.Popen:
    """``hybridsplat ARGS`` in a subprocess (stdout and stderr piped, text); ``user``: a command prefix such as
    ``setpriv --reuid=...`` that runs it as another user."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_WAIT_POLICY": "PASSIVE"}
    return subprocess.Popen(
        [*(user or []), sys.executable, "-m", "hybridsplat", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=_default_sigint,
    )


def start_run(scene: Path, project: Path) -> subprocess.Popen:
    return start_cli("run", str(scene), "--out", str(project), "--quiet")


def run_to_end(scene: Path, project: Path) -> float:
    """Run every stage; the seconds it took."""
    start = time.perf_counter()
    proc = start_run(scene, project)
    _, err = proc.communicate(timeout=900)
    assert proc.returncode == 0, err
    return time.perf_counter() - start


def _numbers(value, prefix: str = "") -> dict[str, float]:
    """Every numeric leaf of the metrics, by key path (file names and timings left out)."""
    out: dict[str, float] = {}
    if isinstance(value, dict):
        for k, v in value.items():
            if k not in ("files", "reference", "seconds"):
                out.update(_numbers(v, f"{prefix}.{k}"))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            out.update(_numbers(v, f"{prefix}[{i}]"))
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        out[prefix] = float(value)
    return out


def products(project: Path) -> tuple[np.ndarray, dict[str, float]]:
    """The fused MVS cloud's positions and every number of the evaluation."""
    layout = ProjectLayout(project)
    return read_ply(layout.fused_ply).world_positions, _numbers(read_metrics(layout.metrics_json))


def assert_same_products(project: Path, expected: tuple[np.ndarray, dict[str, float]]) -> None:
    fused, metrics = products(project)
    ref_fused, ref_metrics = expected
    np.testing.assert_array_equal(fused, ref_fused)
    assert metrics.keys() == ref_metrics.keys()
    for key, value in ref_metrics.items():
        assert metrics[key] == pytest.approx(value, rel=1e-9, abs=1e-12, nan_ok=True), key
