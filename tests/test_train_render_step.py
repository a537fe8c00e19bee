"""render_step (fusion/train/render.py): the cpu path (numba projection + rasteriser) against the reference path
(PyTorch projection + tile renderer, autograd), with frozen context and active tiles, images and gradients."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from fusion.render.projection import project_gaussians
from fusion.render.synthetic import random_scene
from fusion.train.loss import masked_photometric_loss
from fusion.train.params import ContextGaussians, make_parameters
from fusion.train.render import project_context, render_step
from fusion.train.views import TrainView, active_tile_prefix, pixels_within_reach


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
    tensors = scene.trainable
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


def _masked_scene(w: int = 96, h: int = 64):
    scene = random_scene(1500, w, h, seed=5, sh_degree=1)
    mask = np.zeros((h, w), bool)
    mask[20:34, 30:52] = True  # a blob far from the image border: most tiles and pixels are out of reach
    mask[50:53, 5:9] = True
    view = TrainView("v", torch.rand(h, w, 3, generator=torch.Generator().manual_seed(2)), torch.from_numpy(mask),
                     torch.zeros((h, w), dtype=torch.bool), scene.viewmat, scene.K, w, h, int(mask.sum()),
                     active_tile_prefix(mask), pixels_within_reach(mask))  # fmt: skip
    tensors = scene.trainable
    return view, tensors, mask


def test_rendering_only_the_loss_pixels_leaves_loss_and_gradients_unchanged() -> None:
    """The L1 + D-SSIM loss reads the pixels within the SSIM window's reach of the mask only: compositing just those
    gives the same loss and the same gradients as compositing every pixel, and the other pixels stay empty."""
    view, tensors, mask = _masked_scene()
    bg = torch.tensor([0.2, 0.1, 0.3])
    out = {}
    for only in (False, True):
        params = make_parameters(tensors)
        res = render_step(params, view, None, 1, bg, "cpu", loss_pixels_only=only)
        terms = masked_photometric_loss(res.colour, view.image, view.loss_mask, 0.2)
        terms.loss.backward()
        out[only] = (res, float(terms.loss), {k: p.grad.clone() for k, p in params.items()}, res.means2d.grad)
    (full, loss_full, g_full, m_full), (part, loss_part, g_part, m_part) = out[False], out[True]
    assert loss_part == pytest.approx(loss_full, rel=1e-6)
    live = torch.from_numpy(view.render_pixels)
    assert 0.05 < float(live.float().mean()) < 0.6
    assert torch.equal(part.colour[live], full.colour[live])
    assert float(part.alpha[~live].abs().max()) == 0.0 and float(full.alpha[~live].max()) > 0.1
    outside = part.colour.detach()[~live].numpy()
    np.testing.assert_allclose(outside, np.broadcast_to(bg.numpy(), outside.shape))
    for name, g in g_full.items():
        assert float(g.abs().max()) > 0 or name == "sh_rest"
        np.testing.assert_allclose(g_part[name].numpy(), g.numpy(), rtol=1e-5, atol=1e-7 * float(g.abs().max()))
    np.testing.assert_allclose(m_part.numpy(), m_full.numpy(), rtol=1e-5, atol=1e-7 * float(m_full.abs().max()))
    # The reach is what makes it exact: compositing the mask pixels alone changes the SSIM term's gradient.
    narrow = replace(view, render_pixels=mask)
    params = make_parameters(tensors)
    res = render_step(params, narrow, None, 1, bg, "cpu", loss_pixels_only=True)
    masked_photometric_loss(res.colour, view.image, view.loss_mask, 0.2).loss.backward()
    assert not np.allclose(params["means"].grad.numpy(), g_full["means"].numpy(), rtol=1e-3)


def test_loss_pixels_only_matches_between_cpu_and_reference() -> None:
    view, tensors, _ = _masked_scene(64, 48)
    weights = torch.rand(48, 64, 3, generator=torch.Generator().manual_seed(3))
    grads = {}
    for backend in ("reference", "cpu"):
        params = make_parameters(tensors)
        res = render_step(params, view, None, 1, torch.tensor([0.1, 0.2, 0.3]), backend, loss_pixels_only=True)
        ((res.colour * weights).sum() + res.alpha.sum()).backward()
        grads[backend] = (res.colour.detach(), res.alpha.detach(), params["means"].grad, params["sh_dc"].grad)
    (ref_c, ref_a, *ref_g), (cpu_c, cpu_a, *cpu_g) = grads["reference"], grads["cpu"]
    np.testing.assert_allclose(cpu_c.numpy(), ref_c.numpy(), atol=1e-4)
    np.testing.assert_allclose(cpu_a.numpy(), ref_a.numpy(), atol=1e-3)  # both stop below T = 1e-4, in other order
    assert float(cpu_a[~torch.from_numpy(view.render_pixels)].abs().max()) == 0.0
    for a, b in zip(ref_g, cpu_g, strict=True):
        assert float(a.norm()) > 0 and float((a - b).norm() / a.norm()) < 1e-3


def test_context_projection_of_flat_surfels_is_float64_accurate() -> None:
    """MVS Gaussians are flat surfels: their 2D covariance's determinant cancels, and a float32 projection loses up
    to percents of the conic (and its float32 products were not reproducible from process to process). The cached
    context projection must match a float64 projection to float32 rounding."""
    w, h = 96, 72
    scene = random_scene(800, w, h, seed=5, sh_degree=0)
    log_scales = scene.log_scales.clone()
    log_scales[:, :2] += 3.0  # tens of pixels across
    log_scales[:, 2] = log_scales[:, :2].min(dim=1).values - 6.0  # and e⁶ ≈ 400× thinner than wide
    context = ContextGaussians(scene.means, scene.quats, log_scales, scene.logit_opacities, scene.sh_coeffs)
    view = TrainView("v", torch.zeros(h, w, 3), None, torch.zeros((h, w), dtype=torch.bool), scene.viewmat, scene.K,
                     w, h, w * h, None)  # fmt: skip
    cache = project_context(context, view)
    assert cache is not None and len(cache) > 100
    idx = cache.index
    inputs = (scene.means, scene.quats, log_scales, scene.viewmat, scene.K)
    exact = project_gaussians(*(t.double() for t in inputs), w, h)
    single = project_gaussians(*inputs, w, h)

    def error(conics: torch.Tensor) -> np.ndarray:
        """Per Gaussian: the largest conic error relative to the row's largest exact entry."""
        ref = exact.conics[idx]
        return ((conics.double() - ref).abs().amax(dim=1) / ref.abs().amax(dim=1)).numpy()

    assert error(single.conics[idx]).max() > 1e-4  # the case is hard: plain float32 arithmetic fails it
    # float32 inputs (and σ = exp(log σ) in float32) amplified by the same cancellation
    assert error(cache.conics).max() < 1e-5
    np.testing.assert_allclose(cache.extents.numpy(), exact.extents[idx].numpy(), rtol=1e-6)
    np.testing.assert_allclose(cache.means2d.numpy(), exact.means2d[idx].numpy(), rtol=1e-6, atol=1e-4)
