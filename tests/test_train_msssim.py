"""The optional SmoothL1 + MS-SSIM training loss: MS-SSIM against pytorch-msssim, masking, gradients."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.errors import ConfigError
from fusion.train.msssim import masked_ms_ssim, smoothl1_msssim_loss


def pair(seed: int, h: int = 176, w: int = 200) -> tuple[torch.Tensor, torch.Tensor]:
    """A smooth random image and a noisy copy (float64, (H, W, 3) in [0, 1])."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(0, 1, (h // 8 + 1, w // 8 + 1, 3))
    img = np.kron(base, np.ones((8, 8, 1)))[:h, :w]
    noisy = np.clip(img + rng.normal(0, 0.1, img.shape), 0, 1)
    return torch.from_numpy(img), torch.from_numpy(noisy)


@pytest.mark.parametrize("size", [(176, 200), (171, 203)])  # even and odd sizes (the pooling pads odd ones)
def test_unmasked_ms_ssim_matches_pytorch_msssim(size) -> None:
    pm = pytest.importorskip("pytorch_msssim", reason="pytorch-msssim is the reference (a dev dependency)")
    x, y = pair(0, *size)
    ours = float(masked_ms_ssim(x, y))
    ref = float(pm.ms_ssim(x.permute(2, 0, 1)[None], y.permute(2, 0, 1)[None], data_range=1.0))
    assert ours == pytest.approx(ref, rel=1e-6)  # its Gaussian window is built in float32
    assert float(masked_ms_ssim(x, x)) == pytest.approx(1.0)


def test_mask_selects_the_region_that_is_averaged() -> None:
    x, y = pair(1)
    z = x.clone()
    z[:, 100:] = y[:, 100:]  # the right half is noisy, the left half exact
    left = torch.zeros(x.shape[:2], dtype=torch.bool)
    left[:, :60] = True  # well inside the exact half: windows of every scale stay there
    assert float(masked_ms_ssim(x, z, left)) == pytest.approx(1.0, abs=1e-6)
    right = torch.zeros_like(left)
    right[:, 110:] = True
    noisy, whole = float(masked_ms_ssim(x, z, right)), float(masked_ms_ssim(x, z))
    assert noisy < whole < 1.0 - 1e-3  # the noisy half alone scores below the image that mixes both halves


def test_loss_terms_and_gradient_stay_inside_the_mask() -> None:
    x, y = pair(2)
    mask = torch.zeros(x.shape[:2], dtype=torch.bool)
    mask[40:120, 40:150] = True
    r = y.clone().requires_grad_(True)
    terms = smoothl1_msssim_loss(r, x, mask, ssim_lambda=0.2, beta=0.05)
    d = (y - x).abs()
    sl1 = torch.where(d < 0.05, 0.5 * d * d / 0.05, d - 0.025).mean(-1)
    assert float(terms.l1) == pytest.approx(float(sl1[mask].mean()), rel=1e-9)
    terms.loss.backward()
    far = torch.ones_like(mask)
    far[20:140, 20:170] = False  # 20 px beyond the mask: only the coarse scales' windows (16-px pixels) reach there
    inside = float(r.grad[mask].abs().max())
    assert inside > 0 and float(r.grad[far].abs().max()) < 1e-2 * inside
    empty = smoothl1_msssim_loss(y, x, torch.zeros_like(mask))
    assert float(empty.loss) == 0.0
    with pytest.raises(ConfigError):
        masked_ms_ssim(x[:100], y[:100])
