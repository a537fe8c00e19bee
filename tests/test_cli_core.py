"""The CLI's contract: --help/--version, and one line on stderr with exit code 2 for bad input."""

import subprocess
import sys

import numpy as np
import plyfile
import pytest

from core import PointCloud
from core.io.gaussian_ply import gaussian_property_names
from core.io.ply import write_ply


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "hybridsplat", *map(str, args)], capture_output=True, text=True)


def test_version_and_help():
    out = run_cli("--version")
    assert out.returncode == 0 and out.stdout.startswith("hybridsplat ")
    out = run_cli("--help")
    assert out.returncode == 0 and "info" in out.stdout
    out = run_cli("info", "--help")
    assert out.returncode == 0 and "COLMAP" in out.stdout


def _bad_files(tmp_path):
    pc = PointCloud(np.random.default_rng(0).normal(size=(100, 3)))
    write_ply(tmp_path / "truncated.ply", pc)
    data = (tmp_path / "truncated.ply").read_bytes()
    (tmp_path / "truncated.ply").write_bytes(data[:-200])
    v = np.zeros(2, dtype=[("a", "f4")])
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")]).write(str(tmp_path / "noxyz.ply"))
    v = np.array([(np.nan, 0.0, 0.0)], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")]).write(str(tmp_path / "nan.ply"))
    (tmp_path / "badheader.las").write_bytes(b"NOPE" + bytes(400))
    names = [k for k in gaussian_property_names(0) if k != "f_dc_1"] + ["f_dc_x"]
    arr = np.zeros(2, dtype=[(k, "<f4") for k in names])
    arr["f_dc_0"] = 1
    plyfile.PlyData([plyfile.PlyElement.describe(arr, "vertex")]).write(str(tmp_path / "splat_nodc.ply"))
    return ["truncated.ply", "noxyz.ply", "nan.ply", "badheader.las", "splat_nodc.ply", "missing.laz"]


def test_bad_inputs_exit_2_with_one_line(tmp_path):
    for name in _bad_files(tmp_path):
        out = run_cli("info", tmp_path / name)
        lines = out.stderr.strip().splitlines()
        assert out.returncode == 2, (name, out.stderr)
        assert len(lines) == 1 and name in lines[0] and "Traceback" not in out.stderr, (name, out.stderr)


@pytest.mark.parametrize("flag", ["--debug"])
def test_debug_shows_traceback(tmp_path, flag):
    out = run_cli(flag, "info", tmp_path / "missing.ply")
    assert out.returncode != 0 and "Traceback" in out.stderr
