"""Disk space and the operating system's refusals (issue 35), on real file systems made for the test.

A small tmpfs stands for a nearly full disk: a stage whose estimate does not fit is refused before it touches
anything; a disk that fills up while a stage writes ends it with the stage and the file named, its partial outputs
removed and the earlier stages as they were, and the run resumes once there is space. Mounting needs root (or
CAP_SYS_ADMIN): elsewhere those tests are skipped with the reason. Permission denied is made real by running the
command as an unprivileged user (``setpriv``) when the test runs as root (root ignores permission bits).
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest
from project_runs import start_cli

from core.errors import FileSystemRefusedError
from data_synth import generate_scene
from hybridsplat.cli import EXIT_DISK_SPACE, EXIT_REFUSED, run_cli
from hybridsplat.disk_space import free_bytes
from hybridsplat.layout import ProjectLayout
from hybridsplat.manifest import Manifest, hash_path
from hybridsplat.stage_failures import explain_failure
from hybridsplat.stages import stage_named


def _can_mount(where: Path) -> str | None:
    """None when a tmpfs can be mounted here, else why not."""
    if os.geteuid() != 0:
        return "mounting a small file system needs root"
    probe = where / "probe"
    probe.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(probe)], capture_output=True)
    if done.returncode != 0:
        return f"cannot mount a tmpfs here: {done.stderr.decode().strip()}"
    subprocess.run(["umount", str(probe)], check=True)
    return None


@contextlib.contextmanager
def small_fs(folder: Path, size: int):
    folder.mkdir(parents=True, exist_ok=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)], check=True)
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def resize(folder: Path, size: int) -> None:
    subprocess.run(["mount", "-o", f"remount,size={size}", str(folder)], check=True)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return generate_scene("tiny", tmp_path_factory.mktemp("disk") / "scene", seed=0)


@pytest.fixture
def mountable(tmp_path):
    why = _can_mount(tmp_path)
    if why is not None:
        pytest.skip(why)
    return tmp_path


def _snapshot(project: Path) -> dict[str, str]:
    """Every file of the project but the manifest and the logs, with its content hash."""
    return {
        str(p.relative_to(project)): hash_path(p)
        for p in sorted(project.rglob("*"))
        if p.is_file() and p.name != "manifest.json" and "logs" not in p.parts
    }


def _records(project: Path) -> dict:
    return {name: record.content() for name, record in Manifest(ProjectLayout(project).manifest).stages.items()}


def _after_sfm(scene: Path, fs: Path, capsys) -> Path:
    project = fs / "p"
    assert run_cli(["sfm", str(scene), "--out", str(project)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    return project


def test_a_stage_that_does_not_fit_is_refused_before_it_starts(scene, mountable, capsys):
    with small_fs(mountable / "fs", 64 << 20) as fs:
        project = _after_sfm(scene, fs, capsys)
        before, records = _snapshot(project), _records(project)
        from hybridsplat.pipeline import load_config
        from hybridsplat.source import resolve_source
        from hybridsplat.stages.base import StageContext

        config = load_config(project)
        ctx = StageContext(ProjectLayout(project), config, resolve_source(config.input))
        needed = stage_named("mvs").expected_bytes(ctx)
        used = 64 * 2**20 - free_bytes(fs)
        resize(fs, used + needed // 2)
        assert run_cli(["mvs", str(project)]) == EXIT_DISK_SPACE
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith(f"hybridsplat: error: {project}: stage mvs needs about")
        assert "are free; nothing was changed" in err
        assert _snapshot(project) == before and _records(project) == records
        assert not ProjectLayout(project).dense.exists()


def test_a_disk_that_fills_up_during_a_stage_names_it_and_the_run_resumes_with_space(scene, mountable, capsys):
    mvs = type(stage_named("mvs"))
    with small_fs(mountable / "fs", 64 << 20) as fs:
        project = _after_sfm(scene, fs, capsys)
        before, records = _snapshot(project), _records(project)
        used = 64 * 2**20 - free_bytes(fs)
        resize(fs, used + (3 << 19))  # 1.5 MB free: the depth maps and the fused cloud of tiny need ~2.5 MB
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(mvs, "expected_bytes", lambda self, ctx: 0)  # an estimate that is too low
            assert run_cli(["mvs", str(project)]) == EXIT_DISK_SPACE
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert err.startswith(f"hybridsplat: error: {ProjectLayout(project).dense}/"), err  # the file it wrote
        assert "stage mvs ran out of disk space while writing" in err and "No space left on device" in err, err
        assert "partial outputs were removed; the earlier stages are as they were" in err
        assert _snapshot(project) == before and _records(project) == records  # as before the stage
        assert not [p for p in project.rglob("*") if ".tmp" in p.name], "a temporary file was left"
        resize(fs, 64 << 20)
        assert run_cli(["mvs", str(project)]) == 0, capsys.readouterr().err
        assert Manifest(ProjectLayout(project).manifest).stages["mvs"].bytes_written > 1 << 20


def test_a_read_only_file_system_is_named(scene, mountable, capsys):
    with small_fs(mountable / "fs", 64 << 20) as fs:
        project = _after_sfm(scene, fs, capsys)
        subprocess.run(["mount", "-o", "remount,ro", str(fs)], check=True)
        assert run_cli(["mvs", str(project)]) == EXIT_REFUSED
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"hybridsplat: error: {project / '.hybridsplat.lock.json'}: cannot take the project's")
        assert "write lock: read-only file system" in err
        code = run_cli(["status", str(project)])  # a reader still reads
        assert code == 0 and "sfm        current" in capsys.readouterr().out


def _unprivileged() -> list[str] | None:
    """A command prefix that runs a program as a user without root's override of permissions, or None."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        return None
    prefix = [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups"]
    probe = start_cli("--version", user=prefix)
    return prefix if probe.wait(timeout=120) == 0 else None


@pytest.fixture
def shared_tmp():
    """A folder the unprivileged user can reach (pytest's tmp_path lies under a folder only its owner enters)."""
    folder = Path(tempfile.mkdtemp(prefix="hybridsplat-perm-"))
    folder.chmod(0o755)
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def test_permission_denied_on_the_project_folder_and_in_a_stage(shared_tmp):
    user = _unprivileged()
    if user is None:
        pytest.skip("running as root without a way (setpriv) to run as an unprivileged user")
    scene, project = generate_scene("tiny", shared_tmp / "scene", seed=0), shared_tmp / "p"
    assert run_cli(["sfm", str(scene), "--out", str(project)]) == 0
    for path in shared_tmp.rglob("*"):
        path.chmod(0o755 if path.is_dir() else 0o644)
    os.chmod(project, 0o755)  # not writable by the other user
    proc = start_cli("mvs", str(project), user=user)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == EXIT_REFUSED, err
    assert err.strip() == (
        f"hybridsplat: error: {project / '.hybridsplat.lock.json'}: cannot take the project's write lock: "
        "permission denied (is the project folder writable by this user?)"
    ), err
    os.chmod(project, 0o777)  # the folder is writable, but a stale output of mvs in it is not
    stale = ProjectLayout(project).dense / "stale"
    stale.mkdir(parents=True)
    (stale / "depth.bin").write_bytes(b"x")
    os.chmod(stale, 0o555)
    proc = start_cli("mvs", str(project), user=user)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == EXIT_REFUSED, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "stage mvs: permission denied" in lines[0] and str(stale) in lines[0], err


@pytest.mark.parametrize(
    ("number", "words"),
    [(errno.EMFILE, "too many open files in this process"), (errno.EROFS, "read-only file system")],
)
def test_os_refusals_in_a_stage_name_the_stage_and_the_file(tmp_path, number, words):
    err = OSError(number, os.strerror(number), str(tmp_path / "dense" / "x.bin"))
    wrapped = RuntimeError("a library's own words")
    wrapped.__cause__ = err
    told = explain_failure("mvs", wrapped, tmp_path, [])
    assert isinstance(told, FileSystemRefusedError) and told.errno == number
    assert told.one_line().startswith(f"{tmp_path / 'dense' / 'x.bin'}: stage mvs: {words}")
    assert explain_failure("mvs", KeyboardInterrupt(), tmp_path, []) is None
    assert explain_failure("mvs", ValueError("not an OS error"), tmp_path, []) is None
