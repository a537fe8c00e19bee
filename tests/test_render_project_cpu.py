"""The numba projection + SH + opacity (fusion/render/project_cpu.py) against its PyTorch autograd twin.

Forward values and every parameter's gradient (for random output weights) are compared in float64, where the two
differ only by rounding, and in float32 (production) to float32 rounding; a float64 gradcheck checks the hand-written
backward against finite differences of the numba forward itself.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fusion.render.project_cpu import project_splats_cpu
from fusion.render.projection import project_gaussians
from fusion.render.sh import sh_to_colour
from fusion.render.synthetic import random_scene

PARAMS = ["means", "quats", "log_scales", "logit_opacities", "sh_dc", "sh_rest"]


def _scene(dtype, degree, n=400, seed=3):
    scene = random_scene(n, 64, 48, seed=seed, sh_degree=3, depth_range=(0.3, 8.0), dtype=dtype)
    means = scene.means.clone()
    # Some Gaussians behind the near plane and far outside the view (exercise culling and the Jacobian clamp),
    # one with a tiny quaternion.
    R, t = scene.viewmat[:3, :3], scene.viewmat[:3, 3]
    cam = means @ R.T + t
    m = n // 40
    cam[:m, 2] = -cam[:m, 2]
    cam[m : 3 * m, 0] *= 4.0
    means = (cam - t) @ R
    quats = scene.quats.clone()
    if n > 100:
        quats[3 * m] *= 1e-8
    k = (degree + 1) ** 2
    return [
        means,
        quats,
        scene.log_scales,
        scene.logit_opacities,
        scene.sh_coeffs[:, :1].contiguous(),
        scene.sh_coeffs[:, 1:k].contiguous(),
    ], scene


def _twin(means, quats, log_scales, logits, sh_dc, sh_rest, scene, degree):
    proj = project_gaussians(means, quats, log_scales, scene.viewmat, scene.K, scene.width, scene.height)
    centre = -scene.viewmat[:3, :3].T @ scene.viewmat[:3, 3]
    colours = sh_to_colour(torch.cat([sh_dc, sh_rest], dim=1), means - centre, degree)
    return proj.means2d, proj.conics, proj.depths, colours, torch.sigmoid(logits), proj.extents, proj.visible


def _numba(means, quats, log_scales, logits, sh_dc, sh_rest, scene, degree):
    p = project_splats_cpu(
        means, quats, log_scales, logits, sh_dc, sh_rest, scene.viewmat, scene.K, scene.width, scene.height, degree
    )
    return p.means2d, p.conics, p.depths, p.colours, p.opacities, p.extents, p.visible


def _run(fn, params, scene, degree, weights):
    leaves = [p.clone().requires_grad_(True) for p in params]
    outs = fn(*leaves, scene, degree)
    loss = sum((o * w).sum() for o, w in zip(outs[:5], weights, strict=True))
    loss.backward()
    return outs, [p.grad for p in leaves]


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
def test_matches_autograd_twin(degree, dtype):
    params, scene = _scene(dtype, degree)
    gen = torch.Generator().manual_seed(degree)
    shapes = [(len(params[0]), 2), (len(params[0]), 3), (len(params[0]),), (len(params[0]), 3), (len(params[0]),)]
    weights = [torch.randn(s, generator=gen, dtype=torch.float64).to(dtype) for s in shapes]
    weights[1] = weights[1] * 1e-2  # conic gradients are large for small Gaussians
    ref_out, ref_grads = _run(_twin, params, scene, degree, weights)
    out, grads = _run(_numba, params, scene, degree, weights)
    rtol = 1e-9 if dtype == torch.float64 else 2e-4
    vis = ref_out[6]
    assert torch.equal(out[6], vis) and 100 < int(vis.sum()) < len(vis) - 30
    for name, a, b in zip(
        ["means2d", "conics", "depths", "colours", "opacities", "extents"], ref_out, out, strict=False
    ):
        a, b = a.detach().double()[vis], b.detach().double()[vis]
        np.testing.assert_allclose(b.numpy(), a.numpy(), rtol=rtol, atol=rtol * float(a.abs().max()), err_msg=name)
    for name, a, b in zip(PARAMS, ref_grads, grads, strict=True):
        rel = float((a.double() - b.double()).norm() / a.double().norm().clamp_min(1e-30))
        bound = 1e-9 if dtype == torch.float64 else 1e-4
        assert rel < bound, f"{name}: relative gradient difference {rel:.2e}"
        assert a.norm() > 0 or name == "sh_rest"


@pytest.mark.parametrize("degree", [0, 3])
def test_gradcheck_float64(degree):
    params, scene = _scene(torch.float64, degree, n=80, seed=5)
    gen = torch.Generator().manual_seed(7)
    shapes = [(80, 2), (80, 3), (80,), (80, 3), (80,)]
    weights = [torch.randn(s, generator=gen, dtype=torch.float64) for s in shapes]
    weights[1] = weights[1] * 1e-2

    def f(*leaves):
        outs = _numba(*leaves, scene, degree)
        return sum((o * w).sum() for o, w in zip(outs[:5], weights, strict=True))

    leaves = [p.clone().requires_grad_(True) for p in params]
    if degree == 0:
        leaves[5] = leaves[5].detach()  # empty
    assert torch.autograd.gradcheck(f, tuple(leaves), eps=1e-6, atol=1e-5, rtol=1e-5)
