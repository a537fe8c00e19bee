"""The optional photometric loss (1 − λ) · SmoothL1 + λ · (1 − MS-SSIM), averaged over mask pixels.

The industrial digital-twin 3DGS study trains with SmoothL1 + MS-SSIM instead of 3DGS's L1 + SSIM (sharper edges on
machined parts). MS-SSIM follows Wang et al. 2003 as pytorch-msssim implements it (11-tap Gaussian window σ 1.5,
*valid* convolution, 2× average pooling between 5 scales, weights 0.0448 / 0.2856 / 0.3001 / 0.2363 / 0.1333,
negative per-scale values clamped to 0): ``Π_{j<5} cs_j^{w_j} · ssim_5^{w_5}`` per channel, averaged over the
channels; with a mask, each scale's map is
averaged over the mask pooled to that scale (a pixel counts when at least half of it was in the mask) and cropped
like the valid convolution; a scale at which no mask pixel is left (a region smaller than its window) counts as
1, i.e. is left out. Written here because the masked average is the point (pytorch-msssim averages over the
whole image); with no mask it equals pytorch-msssim's ``ms_ssim`` (the test holds them together).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from core.errors import ConfigError
from fusion.train.loss import LossTerms

MS_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
WINDOW = 11
SIGMA = 1.5
C1, C2 = 0.01**2, 0.03**2


def _window(dtype: torch.dtype) -> torch.Tensor:
    x = torch.arange(WINDOW, dtype=torch.float64) - WINDOW // 2
    g = torch.exp(-(x**2) / (2 * SIGMA**2))
    return (g / g.sum()).to(dtype)


def _blur_valid(x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """(1, C, H, W) → (1, C, H − 10, W − 10): separable Gaussian, valid convolution."""
    c = x.shape[1]
    x = F.conv2d(x, g.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)
    return F.conv2d(x, g.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)


def _ssim_cs(x: torch.Tensor, y: torch.Tensor, g: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-pixel SSIM and contrast-structure maps (1, C, H − 10, W − 10) of (1, C, H, W) images in [0, 1]."""
    mu_x, mu_y = _blur_valid(x, g), _blur_valid(y, g)
    sxx = _blur_valid(x * x, g) - mu_x * mu_x
    syy = _blur_valid(y * y, g) - mu_y * mu_y
    sxy = _blur_valid(x * y, g) - mu_x * mu_y
    cs = (2 * sxy + C2) / (sxx + syy + C2)
    lum = (2 * mu_x * mu_y + C1) / (mu_x * mu_x + mu_y * mu_y + C1)
    return lum * cs, cs


def masked_ms_ssim(x: torch.Tensor, y: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """MS-SSIM (0-d) of (H, W, 3) images in [0, 1], each scale averaged over ``mask`` (H, W) bool (all pixels when
    None). The shorter side must exceed 160 px (5 scales of an 11-px valid window)."""
    h, w = x.shape[:2]
    if min(h, w) <= (WINDOW - 1) * 2 ** (len(MS_WEIGHTS) - 1):
        raise ConfigError(f"MS-SSIM needs images larger than 160 px on the shorter side, got {w}×{h}")
    g = _window(x.dtype)
    a, b = x.permute(2, 0, 1)[None], y.permute(2, 0, 1)[None]
    m = None if mask is None else mask.to(x.dtype)[None, None]
    values = []
    for level in range(len(MS_WEIGHTS)):
        ssim, cs = _ssim_cs(a, b, g)
        mp = ssim if level == len(MS_WEIGHTS) - 1 else cs  # (1, C, h, w)
        if m is None:
            v = mp.mean(dim=(0, 2, 3))
        else:
            r = WINDOW // 2
            crop = (m[..., r : m.shape[2] - r, r : m.shape[3] - r] >= 0.5).to(x.dtype)
            count = crop.sum()
            v = (mp * crop).sum(dim=(0, 2, 3)) / count.clamp_min(1.0)
            if float(count) == 0:  # the region is smaller than this scale's window: the scale is left out (1)
                v = torch.ones_like(v)
        values.append(torch.relu(v))  # (C,)
        if level < len(MS_WEIGHTS) - 1:
            pad = [a.shape[2] % 2, a.shape[3] % 2]  # as pytorch-msssim: zero padding counted in the mean
            a, b = F.avg_pool2d(a, 2, padding=pad), F.avg_pool2d(b, 2, padding=pad)
            if m is not None:
                m = F.avg_pool2d(m, 2, padding=pad)
    weights = torch.tensor(MS_WEIGHTS, dtype=x.dtype)[:, None]
    return torch.prod(torch.stack(values) ** weights, dim=0).mean()  # per channel, then the channels' mean


def smoothl1_msssim_loss(
    rendered: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor | None = None,
    ssim_lambda: float = 0.2,
    beta: float = 0.05,
) -> LossTerms:
    """(1 − λ) · SmoothL1(β) + λ · (1 − MS-SSIM) over the mask pixels (all when None); images (H, W, 3) in [0, 1].

    ``LossTerms.l1`` holds the SmoothL1 mean and ``LossTerms.ssim`` the MS-SSIM. An empty mask gives a zero loss.
    """
    per_pixel = F.smooth_l1_loss(rendered, target, reduction="none", beta=beta).mean(dim=-1)
    if mask is None:
        l1 = per_pixel.mean()
    else:
        wts = mask.to(rendered.dtype)
        l1 = (per_pixel * wts).sum() / wts.sum().clamp_min(1.0)
    if mask is not None and not bool(mask.any()):
        ms = torch.ones((), dtype=rendered.dtype) + 0.0 * rendered.sum()
    else:
        ms = masked_ms_ssim(rendered, target, mask) if ssim_lambda > 0 else torch.ones((), dtype=rendered.dtype)
    loss = (1.0 - ssim_lambda) * l1 + ssim_lambda * (1.0 - ms)
    return LossTerms(loss, l1.detach(), ms.detach())
