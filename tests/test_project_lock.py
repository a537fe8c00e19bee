"""One writer at a time on a project (issue 35): the lock itself, a second ``run`` refused while the first goes on
to the products of an undisturbed run, readers refused during a write, a killed holder's lock taken over."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from project_runs import REPO, assert_same_products, start_cli, start_run

from core.errors import ProjectBusyError
from hybridsplat.cli import EXIT_BUSY, run_cli
from hybridsplat.project_lock import HOLDER_NAME, LockHolder, ProjectLock, read_holder, reading_project

HOLD = """
import sys, time
from hybridsplat.project_lock import ProjectLock
lock = ProjectLock(sys.argv[1], exclusive=sys.argv[2] == "write", command="holder of the test", stages=["sfm", "mvs"])
lock.acquire()
lock.note_stage("mvs")
print("locked", flush=True)
time.sleep(600)
"""


def _hold(project: Path, mode: str = "write") -> subprocess.Popen:
    """A process that takes the project's lock and keeps it until killed."""
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(project), mode],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert proc.stdout.readline().strip() == "locked"
    return proc


def _stop(proc: subprocess.Popen) -> None:
    proc.kill()
    proc.wait(timeout=30)


def test_a_second_writer_is_refused_naming_the_holder_and_gets_the_lock_once_it_is_released(tmp_path):
    holder = _hold(tmp_path)
    try:
        with pytest.raises(ProjectBusyError) as err:
            ProjectLock(tmp_path).acquire()
        text = err.value.one_line()
        assert f"pid {holder.pid}" in text and "'holder of the test'" in text and "now at stage mvs" in text
        assert socket.gethostname() in text and str(tmp_path) in text
        assert err.value.holder.pid == holder.pid
        with pytest.raises(ProjectBusyError, match="is writing it"):  # a reader too
            ProjectLock(tmp_path, exclusive=False).acquire()
    finally:
        holder.terminate()  # SIGTERM kills the holder without running its clean-up, like SIGKILL
        holder.wait(timeout=30)
    with ProjectLock(tmp_path) as lock:
        assert lock.took_over is not None and lock.took_over.pid == holder.pid  # its holder file was left behind
        assert read_holder(tmp_path).pid == os.getpid()
    assert not (tmp_path / HOLDER_NAME).exists()  # released: the holder file goes


def test_readers_share_the_lock_and_a_writer_waits_for_none_of_them_beyond_its_patience(tmp_path, monkeypatch):
    reader = _hold(tmp_path, mode="read")
    try:
        with ProjectLock(tmp_path, exclusive=False):  # readers share
            pass
        monkeypatch.setattr("hybridsplat.project_lock.READER_WAIT_S", 0.3)
        start = time.monotonic()
        with pytest.raises(ProjectBusyError, match="another hybridsplat command is reading it"):
            ProjectLock(tmp_path).acquire()
        assert time.monotonic() - start >= 0.3  # the writer waited for the reader, then gave up
    finally:
        _stop(reader)
    with ProjectLock(tmp_path):
        pass


def test_the_lock_is_reentrant_within_a_process(tmp_path):
    with ProjectLock(tmp_path, stages=["a"]) as outer:
        with ProjectLock(tmp_path) as inner, reading_project(tmp_path):
            inner.note_stage("a")  # recorded by the lock that holds it
        assert read_holder(tmp_path).stage == "a" and outer._fd is not None
    assert read_holder(tmp_path) is None


def _write_holder(project: Path, holder: LockHolder) -> None:
    data = {**holder.__dict__, "stages": list(holder.stages)}
    (project / HOLDER_NAME).write_text(json.dumps(data))


def test_a_holder_file_naming_a_live_process_is_refused_even_when_the_os_lock_is_free(tmp_path):
    """A file system that accepts flock without locking (a network mount): the holder file still stops a writer."""
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
    try:
        import psutil

        holder = LockHolder(live.pid, socket.gethostname(), "elsewhere", "now", psutil.Process(live.pid).create_time())
        _write_holder(tmp_path, holder)
        with pytest.raises(ProjectBusyError, match="did not lock the project"):
            ProjectLock(tmp_path).acquire()
        # the same pid, given to a process started later, is not the holder: taken over
        _write_holder(tmp_path, LockHolder(live.pid, socket.gethostname(), "old", "then", holder.process_started - 60))
        with ProjectLock(tmp_path) as lock:
            assert lock.took_over.command == "old"
    finally:
        _stop(live)


def test_a_holder_on_another_host_is_refused_with_what_to_delete(tmp_path):
    _write_holder(tmp_path, LockHolder(4242, "another-host.example", "hybridsplat run x", "then", 1.0))
    with pytest.raises(ProjectBusyError, match=f"delete {tmp_path / HOLDER_NAME}"):
        ProjectLock(tmp_path).acquire()


def _wait_for_stage(project: Path, proc: subprocess.Popen, stages: tuple[str, ...], timeout: float = 300) -> str:
    """Wait until the run writing ``project`` is in one of ``stages``; that stage."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()[1]
        holder = read_holder(project)
        if holder is not None and holder.stage in stages:
            return holder.stage
        time.sleep(0.05)
    raise AssertionError(f"the run did not reach {stages} in {timeout} s")


def _cli(*args: str) -> tuple[int, str]:
    proc = start_cli(*args)
    out, err = proc.communicate(timeout=300)
    return proc.returncode, out + err


def test_two_runs_on_one_project_the_second_refused_the_first_unchanged(tiny_reference, tmp_path):
    """The issue's case: the same ``run`` twice, seconds apart. The second exits 3 naming the first, which goes on
    to the products of an undisturbed run; readers during the write are refused the same way, and ``status``
    says which stage runs."""
    scene, expected, _ = tiny_reference
    project = tmp_path / "p"
    first = start_run(scene, project)
    try:
        stage = _wait_for_stage(project, first, ("mvs", "classify", "train"))
        code, text = _cli("run", str(scene), "--out", str(project), "--quiet")
        assert code == EXIT_BUSY, text
        assert f"pid {first.pid}" in text and "hybridsplat run" in text and "Traceback" not in text
        assert len(text.strip().splitlines()) <= 2, text  # the run's heading, then one error line
        code, text = _cli("info", str(project / "sparse"))  # a reader of a project file during the write
        assert code == EXIT_BUSY and f"pid {first.pid}" in text, text
        code, text = _cli("status", str(project), "--json")
        assert code == 0, text
        status = json.loads(text)
        assert status["writer"]["pid"] == first.pid
        states = {s["name"]: s["state"] for s in status["stages"]}
        assert "running" in states.values() and states["report"] == "queued", states
        assert states["sfm"] == "current" and stage != "sfm"
    finally:
        _, err = first.communicate(timeout=900)
    assert first.returncode == 0, err
    assert_same_products(project, expected)
    code, text = _cli("run", str(scene), "--out", str(project), "--quiet")  # afterwards: nothing to do
    assert code == 0 and "Traceback" not in text
    manifest = json.loads((project / "manifest.json").read_text())
    assert all(r["cached"] or r["skipped"] for r in manifest["stages"].values()), "a stage reran with no change"


@pytest.mark.slow  # the fast suite takes a killed holder's lock over in the first test, without a whole run
def test_a_killed_run_leaves_a_lock_that_the_next_run_takes_over_and_says_so(tiny_reference, tmp_path):
    scene, expected, _ = tiny_reference
    project = tmp_path / "p"
    first = start_run(scene, project)
    _wait_for_stage(project, first, ("classify", "masks", "convert", "train"))
    first.send_signal(signal.SIGKILL)
    first.communicate(timeout=60)
    assert read_holder(project).pid == first.pid  # left behind: the OS lock went with the process
    proc = start_run(scene, project)
    _, err = proc.communicate(timeout=900)
    assert proc.returncode == 0, err
    assert f"took over the project's lock from 'hybridsplat run {scene}" in err and f"pid {first.pid}" in err
    assert_same_products(project, expected)


def test_a_per_stage_command_and_a_reader_in_process_see_the_lock(tmp_path):
    """Commands that write a project all go through the pipeline's lock; one line, exit 3."""
    (tmp_path / "config.toml").write_text('[input]\npath = "/nowhere"\n')
    holder = _hold(tmp_path)
    try:
        assert run_cli(["status", str(tmp_path)]) == 0  # status reads the holder, it does not wait for it
        assert run_cli(["export", str(tmp_path / "export" / "merged.ply"), "--out", str(tmp_path / "x.splat")]) == 3
    finally:
        _stop(holder)


def test_the_viewers_export_is_refused_while_another_process_writes_the_project(tmp_path):
    from test_viewer_scene import make_project

    from hybridsplat.viewer.app import ViewerApp, ViewerOptions
    from hybridsplat.viewer.project import open_project
    from hybridsplat.viewer.scene import load_project

    make_project(tmp_path)
    app = ViewerApp(load_project(tmp_path), ViewerOptions(host="127.0.0.1", port=0), open_project(tmp_path))
    try:
        holder = _hold(tmp_path)
        try:
            assert app.export() == [] and not (tmp_path / "export" / "measurements.csv").exists()
        finally:
            _stop(holder)
        assert "measurements.csv" in [p.name for p in app.export()]
    finally:
        app.stop()
