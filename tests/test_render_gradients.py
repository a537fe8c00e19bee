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


def _projected(n: int, w: int, h: int, seed: int, dtype=torch.float64):
    from fusion.render.projection import project_gaussians

    scene = random_scene(n, w, h, seed=seed, sh_degree=0, sigma_px=(1.0, 4.0), dtype=dtype)
    proj = project_gaussians(scene.means, scene.quats, scene.log_scales, scene.viewmat, scene.K, w, h)
    gen = torch.Generator().manual_seed(seed)
    features = torch.rand(n, 4, generator=gen, dtype=dtype)
    opacities = torch.sigmoid(scene.logit_opacities)
    return proj, opacities, features


def test_frozen_gaussians_leave_the_other_gradients_unchanged():
    """Entries of frozen Gaussians are only composited in the backward: the image and every other Gaussian's
    gradients are those of the unflagged pass (float64, to rounding), the frozen rows are zero."""
    from fusion.render.cpu import rasterize_cpu

    w, h = 48, 40
    proj, opacities, features = _projected(400, w, h, seed=23)
    frozen = torch.rand(400, generator=torch.Generator().manual_seed(4)) < 0.4
    weights = torch.rand(h, w, 5, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    out = {}
    for flag in (None, frozen.numpy()):
        leaves = [t.detach().clone().requires_grad_(True) for t in (proj.means2d, proj.conics, opacities, features)]
        image = rasterize_cpu(*leaves, proj.extents, proj.depths, proj.visible, w, h, frozen=flag)
        (image * weights).sum().backward()
        out[flag is None] = (image.detach(), [t.grad for t in leaves])
    (img_all, g_all), (img_frozen, g_frozen) = out[True], out[False]
    assert torch.equal(img_all, img_frozen)
    live = proj.visible & ~frozen
    assert int(live.sum()) > 100 and int((proj.visible & frozen).sum()) > 50
    for a, b in zip(g_all, g_frozen, strict=True):
        assert float(b[frozen].abs().max()) == 0.0 and float(a[frozen & proj.visible].abs().max()) > 0
        torch.testing.assert_close(b[live], a[live], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("index", range(4), ids=["means2d", "conics", "opacities", "features"])
def test_gradcheck_with_a_pixel_map(index):
    """With ``pixels`` the cpu rasteriser is differentiable as the masked full render (float64, finite differences)."""
    import numpy as np

    from fusion.render.cpu import rasterize_cpu

    w, h = 14, 10
    proj, opacities, features = _projected(6, w, h, seed=21)
    pixels = np.zeros((h, w), bool)
    pixels[2:7, 3:12] = True
    pixels[9, 0] = True
    weights = torch.rand(h, w, 5, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    base = [proj.means2d, proj.conics, opacities, features]

    def f(x: torch.Tensor) -> torch.Tensor:
        args = base[:index] + [x] + base[index + 1 :]
        image = rasterize_cpu(*args, proj.extents, proj.depths, proj.visible, w, h, pixels=pixels)
        assert float(image.detach()[~torch.from_numpy(pixels)].abs().max()) == 0.0
        return (image * weights).sum(dim=-1)

    x = base[index].detach().clone().requires_grad_(True)
    assert torch.autograd.gradcheck(f, (x,), eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)
