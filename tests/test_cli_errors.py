"""Issue 12, case by case: each bad input or interruption the issue lists, as a user meets it on the CLI.

In-process where that is faithful (``hybridsplat.cli.main`` with captured stderr); in a subprocess for
signals and for memory/time blow-ups (limits as in ``tests/fuzz/harness.py``).
"""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import time

import numpy as np
import plyfile
import pytest
from fuzz.cases import UTM, colmap_model, gaussian_ply, gaussians, las_file, truncate
from fuzz.harness import REPO, run_cli


def _cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    from hybridsplat.cli import main

    try:
        main([str(a) for a in argv])
        code = 0
    except SystemExit as ex:
        code = int(ex.code or 0)
    return code, capsys.readouterr().err


def _one_error_line(err: str, name: str) -> str:
    lines = [line for line in err.strip().splitlines() if line.startswith("hybridsplat: error:")]
    assert "Traceback" not in err, err
    assert len(lines) == 1 and name in lines[0], err
    return lines[0]


# -- usage ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "word"),
    [
        (["convert", "--bogus"], "--bogus"),
        (["convert"], "cloud"),
        (["convert", "x.ply", "--out", "y.ply", "--mode", "zz"], "zz"),
    ],
    ids=["unknown-option", "missing-argument", "invalid-choice"],
)
def test_usage_errors_give_usage_line_and_exit_2(argv, word, capsys) -> None:
    code, err = _cli(argv, capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert lines[0].startswith("Usage: hybridsplat convert")
    assert len(lines) == 2
    _one_error_line(err, word)


def test_debug_shows_traceback_for_toolkit_errors(tmp_path) -> None:
    code, _, err, _, _ = run_cli(["--debug", "info", str(tmp_path / "none.ply")], tmp_path)
    assert code != 0 and "Traceback" in err and "InputFileError" in err


# -- readers: tracebacks and silent successes of the issue ------------------------------------------------
def test_ply_with_xyz_as_lists(tmp_path, capsys) -> None:
    p = tmp_path / "lists.ply"
    p.write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar float x\nproperty list uchar float y\n"
        "property list uchar float z\nend_header\n1 0.5 1 0.5 1 0.5\n"
    )
    code, err = _cli(["info", p], capsys)
    assert code == 2
    assert "list" in _one_error_line(err, "lists.ply")


def test_ply_header_declaring_2e31_vertices_is_refused_at_once(tmp_path) -> None:
    p = tmp_path / "huge.ply"
    p.write_text(f"ply\nformat ascii 1.0\nelement vertex {2**31}\nproperty float x\nproperty float y\n"
                 "property float z\nend_header\n0 0 0\n")  # fmt: skip
    code, _, err, seconds, _ = run_cli(["info", str(p)], tmp_path)  # 2 GB address-space limit, as the fuzz suite
    assert code == 2, err
    assert "2147483648" in _one_error_line(err, "huge.ply")


@pytest.mark.parametrize("how", ["truncated", "count-larger", "count-mismatch"])
def test_las_problems_are_not_read_as_fewer_points(tmp_path, capsys, how) -> None:
    p = las_file(tmp_path / "c.las", n=50)
    data = bytearray(p.read_bytes())
    if how == "truncated":
        data = data[:-30]  # one record of 30 bytes missing
    elif how == "count-larger":
        struct.pack_into("<Q", data, 247, 51)
    else:
        struct.pack_into("<I", data, 107, 49)
    p.write_bytes(bytes(data))
    code, err = _cli(["info", p], capsys)
    assert code == 2
    _one_error_line(err, "c.las")


def test_truncated_laz(tmp_path, capsys) -> None:
    p = las_file(tmp_path / "c.laz", n=2000)
    truncate(p, p.stat().st_size // 2)
    code, err = _cli(["info", p], capsys)
    assert code == 2
    _one_error_line(err, "c.laz")


def test_truncated_cameras_bin_is_not_a_zero_pinhole(tmp_path, capsys) -> None:
    model = colmap_model(tmp_path / "sparse")
    truncate(model / "cameras.bin", (model / "cameras.bin").stat().st_size - 8)
    code, err = _cli(["info", model], capsys)
    assert code == 2
    assert "truncated" in _one_error_line(err, "cameras.bin")


def test_truncated_points3d_bin_fails_fast_and_small(tmp_path) -> None:
    """The issue's 7.9 KB points3D.bin ran > 60 s and > 17 GB inside pycolmap; now a clean error."""
    import pycolmap

    opts = pycolmap.SyntheticDatasetOptions()
    opts.num_points3D = 200
    rec = pycolmap.synthesize_dataset(opts)
    model = tmp_path / "sparse"
    model.mkdir()
    rec.write_binary(str(model))
    truncate(model / "points3D.bin", 7900)
    code, _, err, seconds, peak_mb = run_cli(["info", str(model)], tmp_path, timeout=60)
    assert code == 2, err
    _one_error_line(err, "points3D.bin")
    assert peak_mb < 2048


def test_truncated_images_bin_before_mvs(tmp_path) -> None:
    """`hybridsplat mvs` reads the sparse model through recon.model / recon.workspace: pre-scanned too."""
    from core.errors import FormatError
    from recon.model import read_reconstruction

    model = colmap_model(tmp_path / "sparse")
    truncate(model / "images.bin", (model / "images.bin").stat().st_size // 2)
    with pytest.raises(FormatError, match="images.bin"):
        read_reconstruction(model)


def test_sidecar_that_is_a_folder(tmp_path, capsys) -> None:
    gs = gaussian_ply(tmp_path / "g.ply")
    (tmp_path / "g.origin.json").mkdir()
    code, err = _cli(["export", gs, "--out", tmp_path / "o.splat"], capsys)
    assert code == 2
    _one_error_line(err, "g.origin.json")
    assert not (tmp_path / "o.splat").exists()


@pytest.mark.parametrize("prop", ["scale_0", "opacity"])
def test_inf_in_3dgs_ply_is_refused(tmp_path, capsys, prop) -> None:
    p = gaussian_ply(tmp_path / "g.ply")
    ply = plyfile.PlyData.read(str(p), mmap=False)
    ply["vertex"].data[prop][2] = np.inf
    ply.write(str(p))
    code, err = _cli(["export", p, "--out", tmp_path / "o.splat"], capsys)
    assert code == 2
    _one_error_line(err, "g.ply")
    assert not (tmp_path / "o.splat").exists()


def test_inf_scale_in_splat_file_is_refused(tmp_path) -> None:
    from core.errors import DataError
    from fusion.splat_format import SPLAT_RECORD, read_splat

    rec = np.zeros(3, SPLAT_RECORD)
    rec["scale"] = 0.1
    rec["scale"][1, 0] = np.inf
    p = tmp_path / "x.splat"
    rec.tofile(p)
    with pytest.raises(DataError, match="x.splat"):
        read_splat(p)


def test_mesh_face_index_out_of_range_in_eval(tmp_path, capsys) -> None:
    from core.io.ply import write_ply
    from core.pointcloud import PointCloud

    cloud = write_ply(tmp_path / "c.ply", PointCloud(np.random.default_rng(0).random((30, 3))))
    mesh = tmp_path / "mesh.ply"
    mesh.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 9 2\n"
    )
    code, err = _cli(["eval", "c2c", cloud, mesh, "--json", tmp_path / "r.json"], capsys)
    assert code == 2
    assert "vertex" in _one_error_line(err, "mesh.ply")
    assert not (tmp_path / "r.json").exists()


def test_report_on_metrics_with_wrong_types(tmp_path, capsys) -> None:
    (tmp_path / "eval").mkdir()
    (tmp_path / "eval" / "metrics.json").write_text('{"products": {"mvs": {"c2c": {"mean": "0.1"}}}}')
    code, err = _cli(["report", tmp_path], capsys)
    assert code == 2
    assert "products.mvs.c2c.mean" in _one_error_line(err, "metrics.json")
    assert not (tmp_path / "report" / "report.json").exists()


def test_truncated_lpips_weights(tmp_path, capsys) -> None:
    from core.io.images import write_image

    for sub in ("r", "p"):
        write_image(tmp_path / sub / "v.png", np.full((40, 40, 3), 100, np.uint8))
    w = tmp_path / "w.npz"
    np.savez(w, a=np.zeros((64, 3, 11, 11), np.float32))
    truncate(w, w.stat().st_size // 2)
    code, err = _cli(["eval", "images", tmp_path / "r", tmp_path / "p", "--lpips-weights", w], capsys)
    assert code == 2
    _one_error_line(err, "w.npz")


def test_metrics_json_never_holds_bare_nan(tmp_path) -> None:
    from eval.c2c import DistanceStats
    from eval.metrics_io import C2CSummary, ProductMetrics, write_metrics

    stats = DistanceStats(**{k: float("nan") for k in DistanceStats.__dataclass_fields__})
    path = write_metrics(tmp_path / "metrics.json", {"mvs": ProductMetrics(c2c=C2CSummary(stats=stats))})
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text)["products"]["mvs"]["c2c"]["mean"] is None


# -- outputs ----------------------------------------------------------------------------------------------
def test_output_path_is_an_existing_folder(tmp_path, capsys) -> None:
    gs = gaussian_ply(tmp_path / "g.ply")
    (tmp_path / "o.ply").mkdir()
    code, err = _cli(["export", gs, "--out", tmp_path / "o.ply"], capsys)
    assert code == 2
    _one_error_line(err, "o.ply")


def test_output_folder_is_a_file(tmp_path, capsys) -> None:
    gs = gaussian_ply(tmp_path / "g.ply")
    (tmp_path / "f").write_text("x")
    code, err = _cli(["export", gs, "--out", tmp_path / "f" / "o.ply"], capsys)
    assert code == 2
    _one_error_line(err, str(tmp_path / "f"))


def test_unwritable_output_and_all_or_nothing_export(tmp_path, capsys) -> None:
    """`export` wrote the .ply, then failed on the .las: now neither exists."""
    gs = gaussian_ply(tmp_path / "g.ply")
    code, err = _cli(["export", gs, "--out", tmp_path / "a.ply", "--out", "/proc/hs_no/b.las"], capsys)
    assert code == 2
    _one_error_line(err, "/proc/hs_no")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.ply"]


def test_export_refuses_or_keeps_world_doubles_without_sidecar(tmp_path, capsys) -> None:
    """A 3DGS PLY with double world coordinates (~5e6 m) and no sidecar: the export keeps the millimetres
    (local float32 + float64 origin in the written sidecar) instead of float32 world coordinates."""
    from core.io.gaussian_ply import read_gaussian_ply

    gs = gaussians(20)
    world = gs.means + UTM + [0.1234, 0.5678, 0.0]
    names = [n for n in ("x", "y", "z")]
    p = gaussian_ply(tmp_path / "w.ply", n=20)
    v = plyfile.PlyData.read(str(p), mmap=False)["vertex"].data
    arr = np.empty(len(v), [(n, "<f8") if n in names else (n, "<f4") for n in v.dtype.names])
    for n in v.dtype.names:
        arr[n] = v[n]
    for i, n in enumerate(names):
        arr[n] = world[:, i]
    plyfile.PlyData([plyfile.PlyElement.describe(arr, "vertex")]).write(str(p))
    code, err = _cli(["export", p, "--out", tmp_path / "o.ply"], capsys)
    assert code == 0, err
    back = read_gaussian_ply(tmp_path / "o.ply")
    assert (tmp_path / "o.origin.json").is_file()
    np.testing.assert_allclose(back.world_means, world, atol=1e-3, rtol=0)


# -- interruption -----------------------------------------------------------------------------------------
_SLOW_COMMAND = """
import sys, time
from pathlib import Path
import typer
from core.io.atomic import atomic_path, output_transaction
from hybridsplat.cli import app, main

@app.command("sleepy")
def sleepy(out: Path) -> None:
    with output_transaction():
        with atomic_path(out) as tmp:
            tmp.write_text("partial")
        print("ready", flush=True)
        try:
            time.sleep(60)
        finally:
            Path(str(out) + ".cleanup").write_text("finally ran")

main()
"""


@pytest.mark.parametrize(
    ("sig", "code", "word"), [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")]
)
def test_interrupt_and_terminate(tmp_path, sig, code, word) -> None:
    out = tmp_path / "out.txt"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-c", _SLOW_COMMAND, "sleepy", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as in a foreground terminal
    )
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(0.2)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert word in err and "Traceback" not in err
    assert not out.exists()  # the pending output of the transaction was dropped
    assert (tmp_path / "out.txt.cleanup").read_text() == "finally ran"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt.cleanup"]  # no temporary file left


_SIGNAL_IN_COMPILED_CODE = """
from hybridsplat.cli import Terminated, app, main

@app.command("compiled")
def compiled(which: str) -> None:
    # What numba's dispatcher raises when a signal's handler fires while a kernel runs
    cause = KeyboardInterrupt() if which == "int" else Terminated()
    raise SystemError("CPUDispatcher(<function _bin_kernel>) returned a result with an exception set") from cause

main()
"""


@pytest.mark.parametrize(("which", "code", "word"), [("int", 130, "interrupted"), ("term", 143, "terminated")])
def test_a_signal_reported_by_compiled_code_is_still_an_interruption(which, code, word) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, "-c", _SIGNAL_IN_COMPILED_CODE, "compiled", which],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert done.returncode == code, done.stderr
    assert done.stderr.strip().splitlines()[-1] == f"hybridsplat: {word}"
    assert "internal error" not in done.stderr and "Traceback" not in done.stderr
