"""Our 3DGS PLY and .splat load in PlayCanvas' splat-transform (an independent reader, the one behind SuperSplat)
and its CSV dump holds our numbers. Skips when node or the npm package are absent; install with
``scripts/check_splat_transform.sh`` (or point ``HYBRIDSPLAT_SPLAT_TRANSFORM`` at the ``splat-transform`` binary)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from npm_readers import splat_transform

from core.gaussians import GaussianSet
from core.io.gaussian_ply import gaussian_property_names
from core.pointcloud import PointCloud
from fusion.convert import points_to_gaussians
from fusion.export import ExportOptions, export_gaussian_ply, export_splat

C0 = 0.28209479177387814


def _splat_transform() -> str:
    return splat_transform()


def _run(st: str, src: Path, dst: Path) -> tuple[int, str, dict[str, np.ndarray]]:
    """Exit code, log and CSV columns of ``splat-transform src dst.csv`` (empty columns when it failed)."""
    proc = subprocess.run([st, "-w", str(src), str(dst)], capture_output=True, text=True, timeout=120)
    if proc.returncode != 0 or not dst.is_file():
        return proc.returncode, proc.stdout + proc.stderr, {}
    header = dst.read_text().splitlines()[0].split(",")
    table = np.loadtxt(dst, delimiter=",", skiprows=1, ndmin=2)
    return proc.returncode, proc.stdout + proc.stderr, {name: table[:, i] for i, name in enumerate(header)}


def _to_csv(st: str, src: Path, dst: Path, degree: int = 0) -> dict[str, np.ndarray]:
    """splat-transform must read ``src`` as 3DGS: exit 0, no complaint, every 3DGS property in its CSV dump.

    (v2.x refuses PLY files with missing properties; v3.x reads them as a generic table and drops the Gaussian
    columns, so the property check on its output is what catches a bad file with either version.)"""
    rc, log, col = _run(st, src, dst)
    assert rc == 0, f"splat-transform rejected {src.name}:\n{log}"
    assert "missing" not in log.lower() and "unsupported" not in log.lower(), log
    wanted = [n for n in gaussian_property_names(degree) if n not in ("nx", "ny", "nz")]
    absent = [n for n in wanted if n not in col]
    assert not absent, f"splat-transform did not read {absent} from {src.name}"
    return col


def _scene(mode: str) -> GaussianSet:
    rng = np.random.default_rng(11)
    n = 3000
    uv = rng.random((n, 2)) * 3
    world = np.c_[uv, 0.1 * np.cos(2 * uv[:, 1])] + [432100.0, 5200000.0, 250.0]
    cloud = PointCloud.from_world(world, colors=rng.integers(0, 256, (n, 3)))
    return points_to_gaussians(cloud, mode)


@pytest.mark.parametrize("mode", ["paper", "adaptive"])
def test_3dgs_ply_loads_in_splat_transform_with_our_numbers(tmp_path, mode):
    st = _splat_transform()
    gs = _scene(mode)
    gs = gs.with_sh_degree(3)
    gs.sh_rest[:] = np.random.default_rng(1).normal(size=gs.sh_rest.shape) * 0.05  # exercise f_rest order
    export_gaussian_ply(tmp_path / "g.ply", gs, ExportOptions(min_opacity=0))
    col = _to_csv(st, tmp_path / "g.ply", tmp_path / "g.csv", degree=3)
    assert len(col["x"]) == len(gs)
    np.testing.assert_array_equal(np.c_[col["x"], col["y"], col["z"]], gs.means.astype(np.float32))
    np.testing.assert_array_equal(col["opacity"], gs.logit_opacities)
    np.testing.assert_array_equal(np.c_[col["scale_0"], col["scale_1"], col["scale_2"]], gs.log_scales)
    np.testing.assert_array_equal(np.c_[col["rot_0"], col["rot_1"], col["rot_2"], col["rot_3"]], gs.quats)
    for c in range(3):
        np.testing.assert_array_equal(col[f"f_dc_{c}"], gs.sh_dc[:, c])
        for j in range(15):
            np.testing.assert_array_equal(col[f"f_rest_{c * 15 + j}"], gs.sh_rest[:, j, c])


def test_splat_file_loads_in_splat_transform_with_our_colours_and_scales(tmp_path):
    st = _splat_transform()
    gs = _scene("adaptive")
    export_splat(tmp_path / "g.splat", gs, ExportOptions(min_opacity=0))
    col = _to_csv(st, tmp_path / "g.splat", tmp_path / "g.csv")
    assert len(col["x"]) == len(gs)
    xyz = np.c_[col["x"], col["y"], col["z"]].astype(np.float32)
    # records are sorted by importance: map them back by their (unique) float32 positions
    key = {tuple(p): i for i, p in enumerate(gs.means.astype(np.float32))}
    order = np.array([key[tuple(p)] for p in xyz])
    g = gs.subset(order)
    scales = np.exp(np.c_[col["scale_0"], col["scale_1"], col["scale_2"]])
    np.testing.assert_allclose(scales, np.exp(g.log_scales.astype(np.float64)), rtol=1e-5)
    rgb_theirs = np.rint((0.5 + C0 * np.c_[col["f_dc_0"], col["f_dc_1"], col["f_dc_2"]]) * 255)
    rgb_ours = np.clip(np.rint((0.5 + C0 * g.sh_dc.astype(np.float64)) * 255), 0, 255)
    np.testing.assert_array_equal(rgb_theirs, rgb_ours)


def test_splat_transform_rejects_a_ply_missing_a_property(tmp_path):
    """Negative control: the check above fails for a 3DGS PLY without rot_3."""
    import plyfile

    st = _splat_transform()
    gs = _scene("paper")
    export_gaussian_ply(tmp_path / "g.ply", gs, ExportOptions(min_opacity=0))
    v = plyfile.PlyData.read(str(tmp_path / "g.ply"))["vertex"].data
    names = [n for n in v.dtype.names if n != "rot_3"]
    bad = np.empty(len(v), dtype=[(n, "<f4") for n in names])
    for n in names:
        bad[n] = v[n]
    plyfile.PlyData([plyfile.PlyElement.describe(bad, "vertex")]).write(str(tmp_path / "bad.ply"))
    with pytest.raises(AssertionError):
        _to_csv(st, tmp_path / "bad.ply", tmp_path / "bad.csv")
