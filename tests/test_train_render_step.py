"""render_step (fusion/train/render.py): the cpu path (numba projection + rasteriser) against the reference path
(PyTorch projection + tile renderer, autograd), with frozen context and active tiles, images and gradients."""

from __future__ import annotations

import numpy as np
import torch

from fusion.render.synthetic import random_scene
from fusion.train.params import ContextGaussians, make_parameters
from fusion.train.render import project_context, render_step
from fusion.train.views import TrainView, active_tile_prefix


def test_cpu_step_equals_reference_step() -> None:
    w, h = 80, 56
    scene = random_scene(1200, w, h, seed=3, sh_degree=2)
    ctx_scene = random_scene(600, w, h, seed=4, sh_degree=0)
    # One camera for both sets: the context is re-expressed in the trainable scene's world frame.
    R1, t1 = ctx_scene.viewmat[:3, :3], ctx_scene.viewmat[:3, 3]
    R0, t0 = scene.viewmat[:3, :3], scene.viewmat[:3, 3]
    ctx_means = ((ctx_scene.means @ R1.T + t1) - t0) @ R0
    context = ContextGaussians(
        ctx_means, ctx_scene.quats, ctx_scene.log_scales, ctx_scene.logit_opacities, ctx_scene.sh_coeffs
    )  # quats stay in the other frame: only consistency between the two paths matters here
    mask = np.zeros((h, w), bool)
    mask[10:40, 5:50] = True
    view = TrainView("v", torch.rand(h, w, 3, generator=torch.Generator().manual_seed(0)), torch.from_numpy(mask),
                     torch.zeros((h, w), dtype=torch.bool), scene.viewmat, scene.K, w, h, int(mask.sum()),
                     active_tile_prefix(mask))  # fmt: skip
    cache = project_context(context, view)
    assert cache is not None and 0 < len(cache) < len(context)
    tensors = {
        "means": scene.means,
        "quats": scene.quats,
        "log_scales": scene.log_scales,
        "logit_opacities": scene.logit_opacities,
        "sh_dc": scene.sh_coeffs[:, :1],
        "sh_rest": scene.sh_coeffs[:, 1:],
    }
    weights = torch.rand(h, w, 3, generator=torch.Generator().manual_seed(1))
    out = {}
    for backend in ("reference", "cpu"):
        params = make_parameters(tensors)
        res = render_step(params, view, cache, 1, torch.tensor([0.1, 0.2, 0.3]), backend)
        ((res.colour * weights).sum() + res.alpha.sum()).backward()
        out[backend] = (res, {k: p.grad for k, p in params.items()}, res.means2d.grad)
    (ref, ref_g, ref_m2), (cpu, cpu_g, cpu_m2) = out["reference"], out["cpu"]
    assert torch.equal(ref.visible, cpu.visible) and 0 < int(cpu.visible.sum()) < len(cpu.visible)
    np.testing.assert_allclose(cpu.colour.detach().numpy(), ref.colour.detach().numpy(), atol=1e-4)
    np.testing.assert_allclose(cpu.alpha.detach().numpy(), ref.alpha.detach().numpy(), atol=1e-4)
    for name in ref_g:
        a, b = ref_g[name], cpu_g[name]
        if name == "sh_rest":  # degree 1 of 2: coefficients 4..8 get no gradient on either path
            assert float(b[:, 3:].abs().max()) == 0.0 and float(a[:, 3:].abs().max()) == 0.0
        rel = float((a - b).norm() / a.norm())
        assert rel < 1e-3, f"{name}: relative gradient difference {rel:.2e}"
    rel = float((ref_m2 - cpu_m2).norm() / ref_m2.norm())
    assert rel < 1e-3, f"means2d: relative gradient difference {rel:.2e}"
