"""Photometric training loss: 0.8 · L1 + 0.2 · (1 − SSIM), averaged over mask pixels (3DGS's loss, masked).

SSIM is computed on the full images (the 11×11 window, σ 1.5, needs context across the mask border; zero padding
as in the original 3DGS code, so the map has the image's size) and its map is averaged inside the mask. Both terms
are divided by the number of mask pixels, not the image size: dividing by the image size would scale the gradient
by the mask's share of the image and silently lower the learning rate of small regions.

:func:`masked_photometric_loss` runs the fused numba forward + backward of :mod:`fusion.train.loss_cpu` on CPU
tensors; :func:`masked_photometric_loss_reference` is its readable PyTorch autograd twin (used on other devices and
by the tests). In the twin, the five local statistics SSIM needs (μx, μy, E[x²], E[y²], E[xy]) of all channels are
blurred together as one (15, H, W) stack by two matrix products with banded (H, H) and (W, W) Gaussian matrices (zero
padding is built into the band). Written here rather than taken from a package because the masked average is the
point (the ones in pytorch-msssim / torchmetrics average over the whole image). The window and constants live in
:mod:`fusion.train.ssim_window`, shared with the kernels (this module imports them; they never import it).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from fusion.train.loss_cpu import masked_photometric_cpu
from fusion.train.ssim_window import SSIM_C1, SSIM_C2, SSIM_WINDOW, gaussian_taps

_BANDS: dict[tuple[int, torch.dtype], torch.Tensor] = {}


def blur_matrix(n: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """(n, n) banded matrix B with ``(B v)[i] = Σ_k taps[k] v[i + k − 5]`` (zeros beyond the ends); symmetric."""
    key = (n, dtype)
    if key not in _BANDS:
        idx = torch.arange(n)
        offset = idx[None, :] - idx[:, None]
        band = torch.zeros((n, n), dtype=dtype)
        near = offset.abs() <= SSIM_WINDOW // 2
        band[near] = gaussian_taps(dtype)[offset[near] + SSIM_WINDOW // 2]
        _BANDS[key] = band
    return _BANDS[key]


def ssim_map(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM (H, W) averaged over channels, images (H, W, C) in [0, 1], zero-padded 11×11 σ 1.5 window."""
    c = x.shape[-1]
    h, w = x.shape[0], x.shape[1]
    xc = x.permute(2, 0, 1)
    yc = y.permute(2, 0, 1)
    stats = torch.cat([xc, yc, xc * xc, yc * yc, xc * yc], dim=0)  # (5C, H, W)
    blurred = blur_matrix(h, x.dtype) @ stats @ blur_matrix(w, x.dtype)  # B_h is symmetric: rows, then columns
    mu_x, mu_y, e_xx, e_yy, e_xy = blurred.split(c, dim=0)
    mu_xx, mu_yy, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
    num = (2 * mu_xy + SSIM_C1) * (2 * (e_xy - mu_xy) + SSIM_C2)
    den = (mu_xx + mu_yy + SSIM_C1) * ((e_xx - mu_xx) + (e_yy - mu_yy) + SSIM_C2)
    return (num / den).mean(dim=0)


@dataclass(frozen=True)
class LossTerms:
    """The loss and its parts (0-d tensors; ``loss`` carries the graph, the others are detached)."""

    loss: torch.Tensor
    l1: torch.Tensor
    ssim: torch.Tensor


def masked_photometric_loss(
    rendered: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor | None = None,
    ssim_lambda: float = 0.2,
) -> LossTerms:
    """(1 − λ) · L1 + λ · (1 − SSIM), both averaged over the pixels where ``mask`` is true (all pixels when None).

    rendered, target: (H, W, 3) float images in [0, 1]; mask: (H, W) bool or None. An empty mask gives a zero
    loss (with a graph, so ``backward`` is harmless). CPU tensors take the fused numba kernels (gradient to
    ``rendered`` only), others :func:`masked_photometric_loss_reference`.
    """
    if rendered.device.type != "cpu" or ssim_lambda <= 0 or target.requires_grad:
        return masked_photometric_loss_reference(rendered, target, mask, ssim_lambda)
    if mask is None:
        key = (rendered.shape[0], rendered.shape[1], rendered.dtype)
        if key not in _ONES:
            _ONES[key] = torch.ones(key[:2], dtype=rendered.dtype)
        weights, count, empty = _ONES[key], float(key[0] * key[1]), False
    else:
        weights = mask.to(rendered.dtype)
        n = float(weights.sum())
        count, empty = max(n, 1.0), n == 0.0
    loss, l1, ssim = masked_photometric_cpu(rendered, target.to(rendered.dtype), weights, count, ssim_lambda, empty)
    return LossTerms(loss, l1, ssim)


_ONES: dict[tuple[int, int, torch.dtype], torch.Tensor] = {}


def masked_photometric_loss_reference(
    rendered: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor | None = None,
    ssim_lambda: float = 0.2,
) -> LossTerms:
    """The PyTorch autograd twin of :func:`masked_photometric_loss` (same arguments and result)."""
    l1_map = (rendered - target).abs().mean(dim=-1)
    s_map = ssim_map(rendered, target) if ssim_lambda > 0 else None
    if mask is None:
        l1 = l1_map.mean()
        ssim = s_map.mean() if s_map is not None else torch.ones((), dtype=rendered.dtype)
    else:
        w = mask.to(rendered.dtype)
        count = w.sum().clamp_min(1.0)
        l1 = (l1_map * w).sum() / count
        ssim = (s_map * w).sum() / count if s_map is not None else torch.ones((), dtype=rendered.dtype)
        if not bool(mask.any()):
            ssim = ssim + 1.0  # 1 − SSIM = 0 on an empty mask
    loss = (1.0 - ssim_lambda) * l1 + ssim_lambda * (1.0 - ssim)
    return LossTerms(loss, l1.detach(), ssim.detach())
