"""Result type, backend names and the rasterisation constants shared by every backend.

Constants follow the original 3DGS code (graphdeco) and gsplat:

- ``EPS2D``: 0.3 px² added to the diagonal of every projected 2D covariance (EWA low-pass filter).
- ``NEAR_PLANE``: Gaussians whose camera-frame z is below 0.01 (scene units, metres) are culled.
- ``EXTENT_SIGMA``: a Gaussian reaches pixels within 3σ (Mahalanobis distance of the pixel centre under the
  dilated 2D covariance). The cut is per pixel, so images do not depend on the tile size.
- ``ALPHA_MAX`` / ``ALPHA_MIN``: per-Gaussian alpha is clamped to 0.99; contributions below 1/255 are skipped.
- ``T_MIN``: a pixel stops compositing before the Gaussian that would bring its transmittance below 1e-4
  (that Gaussian is not composited, as in graphdeco's and gsplat's kernels).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np
import torch

EPS2D = 0.3
NEAR_PLANE = 0.01
EXTENT_SIGMA = 3.0
POWER_MIN = -0.5 * EXTENT_SIGMA**2
ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4
TILE_SIZE = 16


class Backend(str, Enum):
    """Rasteriser implementations behind :func:`fusion.render.render`."""

    AUTO = "auto"
    """``gsplat`` when CUDA and gsplat are available, else ``cpu``."""
    REFERENCE = "reference"
    """Tile-based pure PyTorch with autograd: slow, readable, the twin the fast backends are tested against."""
    CPU = "cpu"
    """numba kernels (both cores) with a hand-written backward."""
    GSPLAT = "gsplat"
    """gsplat's CUDA rasteriser (extra ``cuda``)."""


@dataclass(frozen=True)
class RenderedImage:
    """A render as numpy arrays (no gradients).

    colour: (H, W, 3) float32 linear RGB in [0, 1] (background included).
    alpha: (H, W) float32 accumulated opacity in [0, 1].
    depth: (H, W) float32 expected camera z-depth in metres (alpha-normalised), 0 where alpha is 0.
    """

    colour: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray


@dataclass(frozen=True)
class RenderResult:
    """The output of :func:`fusion.render.render` for one camera (torch tensors, differentiable).

    Attributes
    ----------
    colour: (H, W, 3) RGB, dtype of the inputs; ``background * (1 - alpha)`` included.
    alpha: (H, W) accumulated opacity ``1 - T_final``.
    depth: (H, W) expected z-depth: ``Σ wᵢ zᵢ / max(alpha, 1e-10)`` with ``wᵢ = αᵢ Tᵢ`` and ``zᵢ`` the camera-frame
        z of each mean (metres); 0 where nothing is drawn.
    means2d: (N, 2) projected means in pixels (COLMAP convention: pixel (col, row) has its centre at
        (col + 0.5, row + 0.5)). A non-leaf tensor that feeds the rasteriser: call ``means2d.retain_grad()``
        before ``backward()`` to read the screen-space gradients densification uses.
    radii: (N, 2) int32 pixel half-extents (x, y) of each Gaussian's 3σ box; 0 for culled Gaussians.
    visible: (N,) bool: in front of the near plane and overlapping the image.
    depths: (N,) camera-frame z of each mean (metres).
    backend: the backend that produced the result (``reference``, ``cpu`` or ``gsplat``).
    """

    colour: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    means2d: torch.Tensor
    radii: torch.Tensor
    visible: torch.Tensor
    depths: torch.Tensor
    backend: Backend

    def to_numpy(self) -> RenderedImage:
        """Colour, alpha and depth as float32 numpy arrays (detached, on the CPU)."""

        def arr(t: torch.Tensor) -> np.ndarray:
            return t.detach().to("cpu", torch.float32).numpy()

        return RenderedImage(arr(self.colour), arr(self.alpha), arr(self.depth))
