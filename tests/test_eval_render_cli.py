"""Rendering products at held-out views (through fusion.render) and the ``eval`` / ``report`` commands."""

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from core.cameras import Camera, Cameras, View
from core.gaussians import GaussianSet
from core.io import read_point_cloud, write_point_cloud
from core.io.images import write_image
from core.pointcloud import PointCloud
from eval.c2c import nearest_distances

LPIPS_WEIGHTS = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "lpips" / "alexnet_lpips_v0.1.npz"


@dataclass
class Out:
    returncode: int
    stdout: str
    stderr: str


@pytest.fixture()
def run_cli(capsys):
    """The CLI's entry point in-process (a subprocess costs seconds of imports per call)."""
    from hybridsplat.cli import main

    def run(*args):
        capsys.readouterr()
        try:
            main([str(a) for a in args])
            code = 0
        except SystemExit as ex:
            code = int(ex.code or 0)
        captured = capsys.readouterr()
        return Out(code, captured.out, captured.err)

    return run


def test_cli_subprocess_help():
    out = subprocess.run([sys.executable, "-m", "hybridsplat", "eval", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "c2c" in out.stdout and "images" in out.stdout


def _scene(origin):
    rng = np.random.default_rng(0)
    n = 400
    means = np.c_[rng.uniform(-1, 1, (n, 2)), rng.uniform(-0.2, 0.2, n)]
    gs = GaussianSet(
        means=means,
        log_scales=np.full((n, 3), np.log(0.05)),
        quats=np.tile([1.0, 0, 0, 0], (n, 1)),
        logit_opacities=np.full(n, 2.0),
        sh_dc=rng.normal(0, 1, (n, 3)),
        origin=origin,
    )
    cam = Camera.pinhole(60.0, 60.0, 32.0, 24.0, 64, 48)
    # camera 4 m above, looking down (-z): world-to-camera rotation flips y and z
    views = {i: View(i, f"v{i}.png", 1, np.array([0.0, 1.0, 0.0, 0.0]), np.array([0.1 * i, 0.0, 4.0])) for i in (1, 2)}
    return gs, Cameras({1: cam}, views, origin)


def test_evaluate_gaussians_against_own_renders(tmp_path):
    from eval.render_eval import evaluate_gaussians, render_view

    origin = np.array([500_000.0, 4_000_000.0, 10.0])
    gs, cams = _scene(origin)
    views = list(cams.views.values())
    (tmp_path / "photos").mkdir()
    for v in views:
        img = render_view(gs, cams, v)
        assert img.shape == (48, 64, 3) and img.max() > 0.05
        write_image(tmp_path / "photos" / v.name, img)
    res = evaluate_gaussians(gs, cams, views, tmp_path / "photos", out_dir=tmp_path, name="merged")
    # photos are the 8-bit renders: the only error is quantisation (<= 0.5/255 per channel)
    assert res.full.mean.psnr > 48.0 and res.full.mean.ssim > 0.999
    assert (tmp_path / "plots" / "render_merged_v1.png").is_file()
    shifted = GaussianSet(gs.means + [0.05, 0, 0], gs.log_scales, gs.quats, gs.logit_opacities, gs.sh_dc, origin=origin)
    worse = evaluate_gaussians(shifted, cams, views, tmp_path / "photos")
    assert worse.full.mean.psnr < res.full.mean.psnr - 10


def test_cli_c2c_json_and_outputs(tmp_path, run_cli):
    rng = np.random.default_rng(1)
    origin = np.array([700_000.0, 5_300_000.0, 80.0])
    ref = PointCloud(rng.uniform(0, 5, (3000, 3)), origin)
    cmp = PointCloud(rng.uniform(0, 5, (1000, 3)), origin)
    write_point_cloud(tmp_path / "ref.las", ref)
    write_point_cloud(tmp_path / "cmp.ply", cmp)
    out = run_cli("eval", "c2c", tmp_path / "cmp.ply", tmp_path / "ref.las", "--tau", "0.1", "--json",
                  tmp_path / "s.json", "--out", tmp_path / "out.las", "--plots", tmp_path / "plots")  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert "rmse" in out.stdout and "F-score" in out.stdout
    s = json.loads((tmp_path / "s.json").read_text())
    # truth from the files as read back (LAS holds mm, PLY float32 local coordinates)
    a, b = read_point_cloud(tmp_path / "cmp.ply"), read_point_cloud(tmp_path / "ref.las")
    d = np.sqrt(((a.world_positions[:, None] - b.world_positions[None]) ** 2).sum(-1)).min(1)
    back = np.sqrt(((b.world_positions[:, None] - a.world_positions[None]) ** 2).sum(-1)).min(1)
    for key, value in (("count", 1000), ("mean", d.mean()), ("std", d.std()), ("median", np.median(d)),
                       ("rmse", np.sqrt((d**2).mean())), ("p95", np.percentile(d, 95)), ("max", d.max()),
                       ("precision", (d < 0.1).mean()), ("recall", (back < 0.1).mean())):  # fmt: skip
        assert s[key] == pytest.approx(value, abs=1e-9), key
    p, r = (d < 0.1).mean(), (back < 0.1).mean()
    assert s["completeness"] == s["recall"] and s["fscore"] == pytest.approx(2 * p * r / (p + r))
    written = read_point_cloud(tmp_path / "out.las")
    np.testing.assert_allclose(
        written.fields["c2c"], nearest_distances(a.positions, b.with_origin(a.origin).positions), atol=1e-9
    )
    assert (tmp_path / "plots" / "cmp_c2c_hist.svg").is_file()


def test_cli_errors_are_one_line(tmp_path, run_cli):
    out = run_cli("eval", "c2c", tmp_path / "missing.ply", tmp_path / "missing2.ply")
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and "missing.ply" in out.stderr
    write_point_cloud(tmp_path / "a.ply", PointCloud(np.zeros((3, 3))))
    out = run_cli("eval", "c2c", tmp_path / "a.ply", tmp_path / "a.ply", "--tau", "-1")
    assert out.returncode == 2 and "tau" in out.stderr


def test_cli_images_and_report(tmp_path, run_cli):
    rng = np.random.default_rng(2)
    for sub in ("r", "p"):
        (tmp_path / sub).mkdir()
    photo = rng.random((64, 64, 3))
    write_image(tmp_path / "p" / "a.png", photo)
    write_image(tmp_path / "r" / "a.png", np.clip(photo + 0.05, 0, 1))
    args = ["eval", "images", tmp_path / "r", tmp_path / "p", "--json", tmp_path / "i.json"]
    if LPIPS_WEIGHTS.is_file():
        args += ["--lpips-weights", LPIPS_WEIGHTS]
    else:
        args += ["--no-lpips"]
    out = run_cli(*args)
    assert out.returncode == 0, out.stderr
    data = json.loads((tmp_path / "i.json").read_text())
    assert data["full"]["views"] == 1 and data["masked"] is None
    assert data["full"]["psnr"] == pytest.approx(26.0, abs=0.2)  # +0.05 on most channels, clipped at 1
    if LPIPS_WEIGHTS.is_file():
        assert data["full"]["lpips"] > 0
    out = run_cli("report", tmp_path)
    assert out.returncode == 0, out.stderr
    rep = json.loads((tmp_path / "report" / "report.json").read_text())
    assert rep["products"]["mvs"]["skipped"] is True


def test_cli_render_scores_a_gaussian_ply(tmp_path, run_cli):
    from core.io.colmap import write_model
    from core.io.gaussian_ply import write_gaussian_ply
    from eval.render_eval import render_view

    gs, cams = _scene(np.zeros(3))
    write_gaussian_ply(tmp_path / "merged.ply", gs)
    write_model(tmp_path / "sparse", cams)
    (tmp_path / "photos").mkdir()
    view = cams.views[1]
    write_image(tmp_path / "photos" / view.name, render_view(gs, cams, view))  # only v1 has a photo
    out = run_cli("eval", "render", tmp_path / "merged.ply", tmp_path / "sparse", tmp_path / "photos", "--no-lpips",
                  "--json", tmp_path / "r.json")  # fmt: skip
    assert out.returncode == 0, out.stderr
    data = json.loads((tmp_path / "r.json").read_text())
    assert [v["view"] for v in data["per_view"]] == ["v1.png"] and data["full"]["psnr"] > 45
    out = run_cli("eval", "render", tmp_path / "merged.ply", tmp_path / "sparse", tmp_path / "sparse", "--no-lpips")
    assert out.returncode == 2 and "no image" in out.stderr
