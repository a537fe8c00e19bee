"""Finite-difference checks (float64) of every differentiable parameter, for the reference and cpu backends.

The cpu backend's backward is hand-written (fusion/render/cpu.py); torch.autograd.gradcheck compares it with
central differences of the forward in float64. Scenes are tiny so the Jacobian is cheap; a pixel lying within
~1e-6 of a cut (3σ edge, alpha 1/255, T 1e-4) would make differences jump, which fixed seeds avoid.
"""

from __future__ import annotations

import pytest
import torch

from fusion.render import render
from fusion.render.synthetic import random_scene

PARAMS = ["means", "quats", "log_scales", "logit_opacities", "sh_coeffs"]


@pytest.mark.parametrize(
    "fast", [pytest.param(True, id="fast"), pytest.param(False, id="full", marks=pytest.mark.slow)]
)
@pytest.mark.parametrize("backend", ["reference", "cpu"])
@pytest.mark.parametrize("index", range(len(PARAMS)), ids=PARAMS)
def test_gradcheck_float64(backend, index, fast):
    """``fast`` checks random projections vᵀ J u of the Jacobian (a few renders); ``full`` every column."""
    scene = random_scene(6, 14, 10, seed=21, sh_degree=2, sigma_px=(1.0, 2.5), dtype=torch.float64)
    params = list(scene.params)
    bg = torch.tensor([0.3, 0.1, 0.2], dtype=torch.float64)
    weights = torch.rand(10, 14, 5, generator=torch.Generator().manual_seed(1), dtype=torch.float64)

    def f(x: torch.Tensor) -> torch.Tensor:
        args = params[:index] + [x] + params[index + 1 :]
        res = render(*args, *scene.camera, background=bg, backend=backend)
        image = torch.cat([res.colour, res.alpha[..., None], res.depth[..., None]], dim=-1)
        return (image * weights).sum(dim=-1)  # keeps the Jacobian small: one row per pixel

    x = params[index].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(f, (x,), eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=fast)


def test_gradients_nonzero_where_visible():
    """Every visible Gaussian with a drawn pixel gets a gradient on every parameter (cpu backend)."""
    scene = random_scene(50, 48, 32, seed=22, sh_degree=1)
    params = [p.clone().requires_grad_(True) for p in scene.params]
    res = render(*params, *scene.camera, backend="cpu")
    res.colour.sum().backward()
    vis = res.visible
    for name, p in zip(PARAMS, params, strict=True):
        per_gaussian = p.grad.reshape(len(vis), -1).abs().sum(dim=1)
        assert (per_gaussian[~vis] == 0).all(), name
        assert (per_gaussian[vis] > 0).float().mean() > 0.9, name
