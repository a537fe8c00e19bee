"""``hybridsplat render``: PNGs at COLMAP cameras, options and errors."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import torch

from core.cameras import Camera, Cameras, View
from core.gaussians import GaussianSet
from core.io import colmap, gaussian_ply, images
from fusion.render import render_gaussian_set
from fusion.render.synthetic import random_scene


@pytest.fixture()
def project(tmp_path):
    scene = random_scene(400, 40, 30, seed=61, sh_degree=1, dtype=torch.float64)
    gs = GaussianSet(
        means=scene.means.numpy(),
        log_scales=scene.log_scales.numpy(),
        quats=scene.quats.numpy(),
        logit_opacities=scene.logit_opacities.numpy(),
        sh_dc=scene.sh_coeffs[:, 0].numpy(),
        sh_rest=scene.sh_coeffs[:, 1:].numpy(),
    )
    gaussian_ply.write_gaussian_ply(tmp_path / "splats.ply", gs)
    K = scene.K.numpy()
    cam = Camera.pinhole(K[0, 0], K[1, 1], K[0, 2], K[1, 2], 40, 30)
    vm = scene.viewmat[:3].numpy()
    views = {
        1: View.from_matrix(1, "a.jpg", 1, vm),
        2: View.from_matrix(2, "b.jpg", 1, np.concatenate([vm[:, :3], vm[:, 3:] + [[0.1], [0.0], [0.0]]], axis=1)),
    }
    cameras = Cameras({1: cam}, views)
    colmap.write_model(tmp_path / "sparse", cameras)
    return tmp_path, gs, cameras


@dataclass
class Ran:
    returncode: int
    stderr: str


@pytest.fixture()
def run(capsys):
    """Run ``hybridsplat render ARGS`` in-process (as the console script does) and capture its exit code."""
    from hybridsplat.cli import main

    def _run(*args) -> Ran:
        try:
            main(["render", *map(str, args)])
            code = 0
        except SystemExit as ex:
            code = int(ex.code or 0)
        return Ran(code, capsys.readouterr().err)

    return _run


def test_renders_every_view_with_depth_and_alpha(project, run):
    root, gs, cameras = project
    out = root / "renders"
    proc = run(
        root / "splats.ply", "--cameras", root / "sparse", "--out", out, "--depth", "--alpha", "--backend", "cpu"
    )
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in out.iterdir()) == [
        "a.alpha.png", "a.depth.png", "a.png", "b.alpha.png", "b.depth.png", "b.png",
    ]  # fmt: skip
    model, _ = colmap.read_model(root / "sparse")
    view = model.by_name("a.jpg")
    expected = render_gaussian_set(gs, model.camera_of(view), view, backend="cpu").to_numpy()
    written = images.read_image(out / "a.png").astype(np.float64) / 255
    assert np.abs(written - expected.colour).max() <= 0.5 / 255 + 1e-6
    import cv2

    depth_mm = cv2.imread(str(out / "a.depth.png"), cv2.IMREAD_UNCHANGED)
    assert depth_mm.dtype == np.uint16
    assert np.abs(depth_mm / 1000.0 - expected.depth).max() <= 0.0005 + 1e-6


def test_selected_images_and_background(project, run):
    root, _, _ = project
    out = root / "one"
    proc = run(root / "splats.ply", "--cameras", root / "sparse", "--out", out, "--images", "b.jpg",
                "--background", "1,1,1", "--backend", "cpu")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert [p.name for p in out.iterdir()] == ["b.png"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--images", "zzz.jpg"], "images not in the model"),
        (["--backend", "vulkan"], "unknown render backend"),
        (["--background", "2,0"], "--background"),
    ],
)
def test_errors_are_one_line_exit_2(project, run, extra, message):
    root, _, _ = project
    proc = run(root / "splats.ply", "--cameras", root / "sparse", "--out", root / "x", *extra)
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr


def test_missing_ply_is_reported(project, run):
    root, _, _ = project
    proc = run(root / "nope.ply", "--cameras", root / "sparse", "--out", root / "x")
    assert proc.returncode == 2 and "nope.ply" in proc.stderr
