"""The SSIM window and constants shared by the photometric loss and its fused CPU kernels.

One place for what :mod:`fusion.train.loss` (PyTorch twin) and :mod:`fusion.train.loss_cpu` (numba kernels) must
agree on: the 11-tap Gaussian window with σ 1.5 px (Wang et al. 2004, as in 3DGS) and the stabilising constants
C1 = (0.01 L)², C2 = (0.03 L)² for images in [0, 1] (L = 1). Both modules import from here, and
:mod:`fusion.train.loss` imports :mod:`fusion.train.loss_cpu`, never the other way round.
"""

from __future__ import annotations

import torch

SSIM_WINDOW = 11  # taps (px)
SSIM_SIGMA = 1.5  # px
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2

_TAPS: dict[torch.dtype, torch.Tensor] = {}


def gaussian_taps(dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """The normalised 1-D Gaussian window (11,) with σ 1.5 used by SSIM (computed in float64, then cast)."""
    if dtype not in _TAPS:
        x = torch.arange(SSIM_WINDOW, dtype=torch.float64) - SSIM_WINDOW // 2
        g = torch.exp(-(x**2) / (2 * SSIM_SIGMA**2))
        _TAPS[dtype] = (g / g.sum()).to(dtype)
    return _TAPS[dtype]
