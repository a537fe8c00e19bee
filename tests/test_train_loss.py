"""The masked training loss against scikit-image's SSIM and a by-hand masked L1."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from fusion.train.loss import masked_photometric_loss, masked_photometric_loss_reference, ssim_map

R = 5  # the window's half width: padding differs between implementations only this close to the border


def images(seed: int, h: int = 40, w: int = 52) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 1, (h, w, 3))
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1)
    return a, b


def test_ssim_map_matches_scikit_image_away_from_the_border() -> None:
    a, b = images(0)
    ours = ssim_map(torch.from_numpy(a), torch.from_numpy(b)).numpy()
    _, ref = structural_similarity(a, b, channel_axis=2, gaussian_weights=True, sigma=1.5,
                                   use_sample_covariance=False, data_range=1.0, full=True)  # fmt: skip
    np.testing.assert_allclose(ours[R:-R, R:-R], ref.mean(axis=2)[R:-R, R:-R], atol=1e-10)


def test_identical_images_have_zero_loss() -> None:
    a, _ = images(1)
    t = torch.from_numpy(a)
    terms = masked_photometric_loss(t, t.clone(), None)
    assert abs(float(terms.loss)) < 1e-12 and abs(float(terms.ssim) - 1) < 1e-12


def test_masked_loss_is_a_mean_over_mask_pixels() -> None:
    a, b = images(2)
    mask = np.zeros(a.shape[:2], bool)
    mask[12:30, 8:20] = True
    ta, tb, tm = torch.from_numpy(a), torch.from_numpy(b), torch.from_numpy(mask)
    terms = masked_photometric_loss(ta, tb, tm, ssim_lambda=0.2)
    l1 = np.abs(a - b).mean(axis=2)[mask].mean()
    _, ref = structural_similarity(a, b, channel_axis=2, gaussian_weights=True, sigma=1.5,
                                   use_sample_covariance=False, data_range=1.0, full=True)  # fmt: skip
    s = ref.mean(axis=2)[mask].mean()  # the mask lies away from the border
    np.testing.assert_allclose(float(terms.l1), l1, rtol=1e-12)
    np.testing.assert_allclose(float(terms.ssim), s, rtol=1e-9)
    np.testing.assert_allclose(float(terms.loss), 0.8 * l1 + 0.2 * (1 - s), rtol=1e-9)


def test_mask_share_does_not_scale_the_gradient() -> None:
    """The same error on a small and a large region gives the same per-pixel gradient magnitude (mean, not sum
    over the image), so small regions are not trained with an effectively smaller learning rate."""
    h, w = 40, 40
    target = torch.zeros((h, w, 3), dtype=torch.float64)
    grads = []
    for size in (6, 24):
        x = torch.full((h, w, 3), 0.3, dtype=torch.float64, requires_grad=True)
        mask = torch.zeros((h, w), dtype=torch.bool)
        mask[10 : 10 + size, 10 : 10 + size] = True
        masked_photometric_loss(x, target, mask, ssim_lambda=0.0).loss.backward()
        grads.append(float(x.grad[mask].abs().sum()))
    np.testing.assert_allclose(grads[0], grads[1], rtol=1e-12)


def test_empty_mask_gives_zero_loss_and_gradient() -> None:
    a, b = images(3)
    x = torch.from_numpy(a).requires_grad_(True)
    terms = masked_photometric_loss(x, torch.from_numpy(b), torch.zeros(a.shape[:2], dtype=torch.bool))
    terms.loss.backward()
    assert float(terms.loss.detach()) == 0.0 and float(x.grad.abs().sum()) == 0.0


# -- the fused numba loss (fusion/train/loss_cpu.py) against its PyTorch autograd twin ----------------------


@pytest.mark.parametrize("masked", [False, True], ids=["whole", "masked"])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
def test_fused_loss_matches_autograd_twin(masked, dtype) -> None:
    """Loss terms and the gradient w.r.t. the render, mask touching the border (zero padding matters there)."""
    a, b = images(4, h=37, w=45)
    mask = None
    if masked:
        rng = np.random.default_rng(5)
        m = rng.uniform(size=a.shape[:2]) < 0.4
        m[:, :3] = True
        mask = torch.from_numpy(m)
    out = {}
    for name, fn in (("twin", masked_photometric_loss_reference), ("fused", masked_photometric_loss)):
        x = torch.from_numpy(a).to(dtype).requires_grad_(True)
        terms = fn(x, torch.from_numpy(b).to(dtype), mask, ssim_lambda=0.2)
        (3.0 * terms.loss).backward()
        out[name] = (terms, x.grad)
    (t_ref, g_ref), (t_new, g_new) = out["twin"], out["fused"]
    tol = 1e-12 if dtype == torch.float64 else 2e-6
    for field in ("loss", "l1", "ssim"):
        np.testing.assert_allclose(
            float(getattr(t_new, field).detach()), float(getattr(t_ref, field).detach()), rtol=tol, err_msg=field
        )
    scale = float(g_ref.abs().max())
    assert scale > 0
    np.testing.assert_allclose(g_new.numpy(), g_ref.numpy(), atol=(1e-12 if dtype == torch.float64 else 1e-5) * scale)


def test_fused_loss_gradcheck() -> None:
    a, b = images(6, h=14, w=17)
    mask = torch.zeros(a.shape[:2], dtype=torch.bool)
    mask[2:12, 0:9] = True
    x = torch.from_numpy(a).requires_grad_(True)
    y = torch.from_numpy(b)
    assert torch.autograd.gradcheck(lambda t: masked_photometric_loss(t, y, mask).loss, (x,), eps=1e-6, atol=1e-8)


def test_fused_loss_is_used_on_cpu() -> None:
    """The CPU path is the numba Function (so the comparisons above test what training runs)."""
    a, b = images(7, h=12, w=12)
    x = torch.from_numpy(a).requires_grad_(True)
    loss = masked_photometric_loss(x, torch.from_numpy(b), None).loss
    assert type(loss.grad_fn).__name__ == "_MaskedPhotometricBackward"
