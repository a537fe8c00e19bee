"""An LPIPS term for the last part of training, restricted to a view's loss pixels.

LPIPS is a patch metric (AlexNet features, receptive fields of up to ~200 px), so it cannot be "averaged over the
mask" pixel by pixel the way L1 and SSIM are. Per view this module takes the bounding box of the loss pixels (grown
by ``margin`` px for context, at least :data:`MIN_SIZE` px on each side, clipped to the image) and builds two
images of the crop that differ only on the loss pixels:

- outside the view's mask both carry the photo (pixels that are not in the region: real context, equal in both),
- on the hold-out pixels of the mask (early stopping, kept out of every loss) both carry a fill interpolated from
  the photo's surrounding loss pixels, so neither the photo's hold-out values nor a gradient reach them,
- on the loss pixels, the render in one and the photo in the other.

The network's per-layer distance maps are then averaged over the loss pixels (the ``mask`` argument of
:meth:`eval.lpips.LPIPS.forward`, the same weighting as the masked LPIPS of the evaluation), not over the crop: a
mean over the crop would scale the term by the mask's share of the box, the masked-loss pitfall of
``shared/notes/splat-training.md``. Compositing and the masked mean together make the gradient exactly zero outside
the loss pixels. The network is frozen (its weights are plain tensors, never handed to the optimiser); the gradient
goes into the rendered image and from there through the renderer's backward.

The network is passed in (an :class:`eval.lpips.LPIPS` built by the caller, e.g. the train stage): fusion does not
import eval (eval renders through fusion), and there is one LPIPS implementation in the project.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
import torch

from fusion.train.views import TrainView

MIN_SIZE = 32  # AlexNet's five layers need at least 32 × 32 input pixels
FILL_RADIUS = 3  # hold-out pixels are filled with the mean of the loss pixels within this many pixels


class PerceptualNetwork(Protocol):
    """What the term needs of :class:`eval.lpips.LPIPS`: ``(B,)`` distances of (B, 3, H, W) images in [-1, 1],
    spatial means weighted by ``mask`` (B, 1, H, W) in [0, 1]; differentiable w.r.t. ``x``."""

    def __call__(self, x: torch.Tensor, y: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor: ...


@dataclass(frozen=True)
class PerceptualCrop:
    """One view's LPIPS inputs (fixed for the whole training).

    rows, cols: the crop's [start, stop) pixel ranges. loss: (h, w, 1) bool, the loss pixels in the crop.
    fill: (h, w, 3) float, what both images carry off the loss pixels (photo / hold-out fill). target: (1, 3, h, w)
    the photo side in [-1, 1]. weight: (1, 1, h, w) float, the loss pixels as LPIPS's spatial weight.
    """

    rows: tuple[int, int]
    cols: tuple[int, int]
    loss: torch.Tensor
    fill: torch.Tensor
    target: torch.Tensor
    weight: torch.Tensor


def crop_span(lo: int, hi: int, margin: int, size: int) -> tuple[int, int]:
    """[start, stop) around the pixel range [lo, hi) grown by ``margin``, at least ``MIN_SIZE`` long (when ``size``
    allows), inside [0, size)."""
    start, stop = max(0, lo - margin), min(size, hi + margin)
    need = min(MIN_SIZE, size)
    if stop - start < need:
        start = min(max(0, (start + stop) // 2 - need // 2), size - need)
        stop = start + need
    return start, stop


def prepare_crop(view: TrainView, margin: int = 16) -> PerceptualCrop | None:
    """The crop of ``view`` for :func:`perceptual_loss`; None when the view has no loss pixel."""
    h, w = view.height, view.width
    loss_full = np.ones((h, w), bool) if view.loss_mask is None else view.loss_mask.numpy()
    if not loss_full.any():
        return None
    ys, xs = np.nonzero(loss_full)
    r0, r1 = crop_span(int(ys.min()), int(ys.max()) + 1, margin, h)
    c0, c1 = crop_span(int(xs.min()), int(xs.max()) + 1, margin, w)
    photo = view.image.numpy()[r0:r1, c0:c1].astype(np.float64)
    loss = loss_full[r0:r1, c0:c1]
    hold = view.holdout_mask.numpy()[r0:r1, c0:c1] & ~loss
    fill = photo.copy()
    if hold.any():
        # normalised convolution: the mean of the photo over the loss pixels near each hold-out pixel
        k = 2 * FILL_RADIUS + 1
        wts = cv2.boxFilter(loss.astype(np.float64), -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
        sums = cv2.boxFilter(photo * loss[..., None], -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
        mean = photo[loss].mean(axis=0)
        near = np.where(wts[..., None] > 0, sums / np.maximum(wts[..., None], 1e-12), mean)
        fill[hold] = near[hold]
    dtype = view.image.dtype
    fill_t = torch.from_numpy(fill).to(dtype)
    loss_t = torch.from_numpy(loss)[..., None]
    target = torch.where(loss_t, torch.from_numpy(photo).to(dtype), fill_t)
    return PerceptualCrop(
        rows=(r0, r1),
        cols=(c0, c1),
        loss=loss_t,
        fill=fill_t,
        target=(target.permute(2, 0, 1)[None] * 2.0 - 1.0).contiguous(),
        weight=loss_t.permute(2, 0, 1)[None].to(dtype).contiguous(),
    )


def perceptual_loss(rendered: torch.Tensor, crop: PerceptualCrop, network: PerceptualNetwork) -> torch.Tensor:
    """0-d LPIPS of the render against the photo on ``crop``'s loss pixels (see the module docstring).

    rendered: (H, W, 3) float image in [0, 1] (the full training render; gradients flow back into it, and only at
    the loss pixels).
    """
    (r0, r1), (c0, c1) = crop.rows, crop.cols
    part = torch.where(crop.loss, rendered[r0:r1, c0:c1], crop.fill.to(rendered.dtype))
    x = part.permute(2, 0, 1)[None] * 2.0 - 1.0
    return network(x, crop.target.to(rendered.dtype), crop.weight.to(rendered.dtype))[0]
