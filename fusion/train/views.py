"""Training views: photos, masks and cameras at the training resolution, in the training frame.

The training frame is the cameras' local frame shifted by a float64 ``centre`` (so float32 keeps precision):
``x_train = x_local − centre`` and each view's world-to-camera matrix becomes ``[R | R·centre + t]``.

Per view: the loss pixels (mask minus a seeded hold-out share kept for early stopping), the hold-out pixels, the
pixels worth rendering (those within the SSIM window's reach of a mask pixel: the L1 + D-SSIM loss reads no other)
and the 16×16 tiles holding them; Gaussians whose 3σ box touches none of those tiles are culled for that view.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from core.cameras import Cameras
from core.errors import ConfigError, DataError
from fusion.render.types import TILE_SIZE

SSIM_REACH = 5  # half of the 11-pixel SSIM window: pixels this close to the mask influence the loss


@dataclass(frozen=True)
class TrainView:
    """One training photo at the training resolution.

    image: (H, W, 3) float32 in [0, 1]. loss_mask: (H, W) bool, the pixels in the loss (None: every pixel);
    holdout_mask: (H, W) bool, a seeded share of the mask pixels kept out of the loss. viewmat: (4, 4)
    float32 training frame → camera (OpenCV axes). K: (3, 3) float32 pinhole, pixel centres at +0.5.
    tile_prefix: (tiles_y + 1, tiles_x + 1) int64 2-D prefix sum of the active-tile map, None = all tiles active.
    render_pixels: (H, W) bool numpy, the pixels within ``SSIM_REACH`` of the mask (the only ones the L1 + D-SSIM
    loss reads), None = every pixel.
    """

    name: str
    image: torch.Tensor
    loss_mask: torch.Tensor | None
    holdout_mask: torch.Tensor
    viewmat: torch.Tensor
    K: torch.Tensor
    width: int
    height: int
    mask_pixels: int
    tile_prefix: np.ndarray | None
    render_pixels: np.ndarray | None = None

    @property
    def camera_centre(self) -> torch.Tensor:
        R, t = self.viewmat[:3, :3], self.viewmat[:3, 3]
        return -R.T @ t


def resize_image(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W, C) float image resized to ``size`` = (width, height) with area averaging (cv2.INTER_AREA)."""
    if (image.shape[1], image.shape[0]) == size:
        return image
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def resize_mask(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W) bool mask resized to (width, height): a pixel is in when at least half its area was."""
    if (mask.shape[1], mask.shape[0]) == size:
        return mask.astype(bool)
    return resize_image(mask.astype(np.float32), size) >= 0.5


def pixels_within_reach(mask: np.ndarray, reach: int = SSIM_REACH) -> np.ndarray:
    """(H, W) bool: the pixels within ``reach`` px (Chebyshev distance: the square SSIM window) of a mask pixel."""
    return cv2.dilate(mask.astype(np.uint8), np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)) > 0


def active_tile_prefix(mask: np.ndarray, reach: int = SSIM_REACH, tile: int = TILE_SIZE) -> np.ndarray:
    """2-D prefix sum (ty + 1, tx + 1) of the tiles holding a pixel within ``reach`` px of the mask."""
    h, w = mask.shape
    grown = pixels_within_reach(mask, reach)
    ty, tx = (h + tile - 1) // tile, (w + tile - 1) // tile
    padded = np.zeros((ty * tile, tx * tile), bool)
    padded[:h, :w] = grown
    tiles = padded.reshape(ty, tile, tx, tile).any(axis=(1, 3))
    prefix = np.zeros((ty + 1, tx + 1), np.int64)
    prefix[1:, 1:] = tiles.cumsum(0).cumsum(1)
    return prefix


def boxes_touch_tiles(
    means2d: torch.Tensor, extents: torch.Tensor, prefix: np.ndarray, tile: int = TILE_SIZE
) -> torch.Tensor:
    """(N,) bool: the pixel box mean ± extent (N, 2 each, px) overlaps an active tile of the prefix map."""
    ty, tx = prefix.shape[0] - 1, prefix.shape[1] - 1
    m = means2d.detach().double()
    e = extents.detach().double()
    x0 = torch.floor((m[:, 0] - e[:, 0]) / tile).clamp(0, tx - 1).long()
    x1 = torch.floor((m[:, 0] + e[:, 0]) / tile).clamp(0, tx - 1).long()
    y0 = torch.floor((m[:, 1] - e[:, 1]) / tile).clamp(0, ty - 1).long()
    y1 = torch.floor((m[:, 1] + e[:, 1]) / tile).clamp(0, ty - 1).long()
    p = torch.from_numpy(prefix)
    count = p[y1 + 1, x1 + 1] - p[y0, x1 + 1] - p[y1 + 1, x0] + p[y0, x0]
    return count > 0


def prepare_views(
    cameras: Cameras,
    images: Mapping[str, np.ndarray],
    masks: Mapping[str, np.ndarray] | None,
    centre: np.ndarray,
    *,
    downscale: int = 1,
    holdout_fraction: float = 0.05,
    seed: int = 0,
) -> list[TrainView]:
    """Training views for every image name in ``images`` (sorted by name).

    images: name → (H, W, 3) uint8 or float in [0, 1] at the camera's size. masks: name → (H, W) bool (True = the
    region to train), or None to train on whole images; views whose mask is empty are left out. ``downscale``: an
    integer factor applied to photos, masks and intrinsics. ``holdout_fraction`` of each view's mask pixels (seeded)
    is kept out of the loss for early stopping.
    """
    if downscale < 1:
        raise ConfigError(f"downscale must be an integer >= 1, got {downscale}")
    if not 0.0 <= holdout_fraction < 1.0:
        raise ConfigError(f"holdout_fraction must lie in [0, 1), got {holdout_fraction}")
    by_name = {v.name: v for v in cameras}
    rng = np.random.default_rng(seed)
    centre = np.asarray(centre, np.float64)
    views: list[TrainView] = []
    for name in sorted(images):
        if name not in by_name:
            raise DataError(f"image {name!r} has no camera in the model")
        view = by_name[name]
        cam = cameras.camera_of(view)
        if cam.model.has_distortion:
            raise ConfigError(f"camera of {name!r} has distortion ({cam.model.value}): train on undistorted images")
        img = np.asarray(images[name])
        if img.shape[:2] != (cam.height, cam.width):
            raise DataError(f"image {name!r} is {img.shape[1]}×{img.shape[0]}, its camera {cam.width}×{cam.height}")
        img = img.astype(np.float32) / 255.0 if img.dtype == np.uint8 else img.astype(np.float32)
        small = cam.scaled(1.0 / downscale) if downscale != 1 else cam
        size = (small.width, small.height)
        img = resize_image(img[..., :3], size)
        h, w = img.shape[:2]
        if masks is not None:
            if name not in masks:
                continue
            m = np.asarray(masks[name]).astype(bool)
            if m.shape != (cam.height, cam.width):
                raise DataError(f"mask of {name!r} is {m.shape[1]}×{m.shape[0]}, its camera {cam.width}×{cam.height}")
            m = resize_mask(m, size)
            if not m.any():
                continue
        else:
            m = np.ones((h, w), bool)
        inside = np.flatnonzero(m.reshape(-1))
        n_hold = int(round(holdout_fraction * len(inside)))
        hold = np.zeros(h * w, bool)
        hold[rng.choice(inside, size=n_hold, replace=False)] = True
        hold = hold.reshape(h, w)
        R = view.rotation
        vm = np.eye(4)
        vm[:3, :3] = R
        vm[:3, 3] = R @ centre + view.translation
        K = small.K()
        views.append(
            TrainView(
                name=name,
                image=torch.from_numpy(np.ascontiguousarray(img)),
                loss_mask=None if (masks is None and n_hold == 0) else torch.from_numpy(m & ~hold),
                holdout_mask=torch.from_numpy(hold),
                viewmat=torch.from_numpy(vm.astype(np.float32)),
                K=torch.from_numpy(np.asarray(K, np.float32)),
                width=w,
                height=h,
                mask_pixels=int(m.sum()),
                tile_prefix=None if masks is None else active_tile_prefix(m),
                render_pixels=None if masks is None else pixels_within_reach(m),
            )
        )
    return views
