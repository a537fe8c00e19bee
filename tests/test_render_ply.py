"""A 3DGS PLY written by the toolkit, rendered by the toolkit, against an independent reading and renderer.

The independent side reads the file with plyfile and json only (its own idea of property names, quaternion
order, log-scales, logit opacities and channel-major f_rest) and renders with the float64 brute-force oracle
in world coordinates (~5e6 m, no local origin), so conventions and the large-coordinate path are both checked.
"""

from __future__ import annotations

import json

import numpy as np
import plyfile
import pytest
import torch

from core.cameras import Camera, View
from core.gaussians import GaussianSet
from core.io import gaussian_ply
from fusion.render import render_brute_force, render_gaussian_set
from fusion.render.synthetic import random_scene

ORIGIN = np.array([512345.678, 5212345.123, 234.5])


def _independent_read(path):
    """(means_world, quats_wxyz, log_scales, logit_opacities, sh (N, K, 3)) straight from the file."""
    v = plyfile.PlyData.read(str(path))["vertex"].data
    names = v.dtype.names
    sidecar = path.with_name(path.stem + ".origin.json")
    origin = np.array(json.loads(sidecar.read_text())["origin"]) if sidecar.exists() else np.zeros(3)
    means = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64) + origin
    quats = np.stack([v[f"rot_{i}"] for i in range(4)], axis=1).astype(np.float64)  # w, x, y, z
    log_scales = np.stack([v[f"scale_{i}"] for i in range(3)], axis=1).astype(np.float64)
    n_rest = sum(1 for n in names if n.startswith("f_rest_")) // 3
    dc = np.stack([v[f"f_dc_{c}"] for c in range(3)], axis=1)
    # f_rest is channel-major: all R coefficients, then all G, then all B.
    rest = np.zeros((len(v), n_rest, 3))
    for c in range(3):
        for j in range(n_rest):
            rest[:, j, c] = v[f"f_rest_{c * n_rest + j}"]
    sh = np.concatenate([dc[:, None, :], rest], axis=1).astype(np.float64)
    return means, quats, log_scales, np.asarray(v["opacity"], np.float64), sh


@pytest.mark.parametrize("sh_degree", [0, 3])
def test_written_ply_renders_like_independent_reader(tmp_path, sh_degree):
    scene = random_scene(150, 48, 36, seed=41, sh_degree=sh_degree, dtype=torch.float64)
    gs = GaussianSet(
        means=scene.means.numpy(),
        log_scales=scene.log_scales.numpy(),
        quats=scene.quats.numpy(),
        logit_opacities=scene.logit_opacities.numpy(),
        sh_dc=scene.sh_coeffs[:, 0].numpy(),
        sh_rest=scene.sh_coeffs[:, 1:].numpy(),
        origin=ORIGIN,
    )
    path = tmp_path / "splats.ply"
    gaussian_ply.write_gaussian_ply(path, gs)

    # Cameras live in another local frame (origin shifted by delta) than the Gaussians.
    delta = np.array([12.0, -7.5, 3.25])
    R, t = scene.viewmat[:3, :3].numpy(), scene.viewmat[:3, 3].numpy()
    view = View.from_matrix(1, "img.png", 1, np.concatenate([R, (t + R @ delta)[:, None]], axis=1))
    K = scene.K.numpy()
    camera = Camera.pinhole(K[0, 0], K[1, 1], K[0, 2], K[1, 2], 48, 36)
    bg = np.array([0.05, 0.5, 0.95])

    ours = render_gaussian_set(
        gaussian_ply.read_gaussian_ply(path), camera, view, cameras_origin=ORIGIN + delta, background=bg,
        backend="cpu",
    ).to_numpy()  # fmt: skip

    means_w, quats, log_scales, logits, sh = _independent_read(path)
    viewmat_w = np.eye(4)
    viewmat_w[:3, :3] = view.rotation
    viewmat_w[:3, 3] = view.translation - view.rotation @ (ORIGIN + delta)
    colour, alpha, depth = render_brute_force(
        means_w, quats, log_scales, logits, sh, viewmat_w, camera.K(), 48, 36, background=bg
    )
    assert alpha.mean() > 0.3
    np.testing.assert_allclose(ours.colour, colour, atol=1e-4)
    np.testing.assert_allclose(ours.alpha, alpha, atol=1e-4)
    covered = alpha > 1e-2
    np.testing.assert_allclose(ours.depth[covered], depth[covered], rtol=1e-4)
