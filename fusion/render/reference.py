"""The ``reference`` backend: a tile-based rasteriser in plain PyTorch, differentiated by autograd.

Readable rather than fast; the ``cpu`` backend is tested against it. Each 16×16 tile holds a depth-sorted,
padded list of the Gaussians whose 3σ box touches it. Lists are walked in chunks of ``chunk`` entries: inside a
chunk the transmittance is a cumulative product, and only tiles that still have entries and unfinished pixels
take part in the next chunk.
"""

from __future__ import annotations

import numpy as np
import torch

from fusion.render.types import ALPHA_MAX, ALPHA_MIN, POWER_MIN, T_MIN, TILE_SIZE


def tile_lists(
    means2d: torch.Tensor,
    extents: torch.Tensor,
    depths: torch.Tensor,
    visible: torch.Tensor,
    tiles_x: int,
    tiles_y: int,
    tile_size: int = TILE_SIZE,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth-sorted Gaussian ids per tile, padded with -1: (n_tiles, L) int64, and list lengths (n_tiles,)."""
    with torch.no_grad():
        ids = torch.nonzero(visible).squeeze(1)
        ids = ids[torch.sort(depths[ids], stable=True).indices]
        lo = torch.floor((means2d[ids] - extents[ids]) / tile_size).long()
        hi = torch.floor((means2d[ids] + extents[ids]) / tile_size).long()
        tx0, ty0 = lo[:, 0].clamp(0, tiles_x - 1), lo[:, 1].clamp(0, tiles_y - 1)
        tx1, ty1 = hi[:, 0].clamp(0, tiles_x - 1), hi[:, 1].clamp(0, tiles_y - 1)
        nx, ny = tx1 - tx0 + 1, ty1 - ty0 + 1
        # One row per (Gaussian, tile) pair, Gaussians in depth order.
        pair_g = torch.repeat_interleave(torch.arange(len(ids)), nx * ny)
        first = torch.cumsum(nx * ny, 0) - nx * ny
        local = torch.arange(len(pair_g)) - first[pair_g]
        tile = (ty0[pair_g] + local // nx[pair_g]) * tiles_x + tx0[pair_g] + local % nx[pair_g]
        # Stable sort by tile keeps depth order within each tile.
        by_tile = torch.sort(tile, stable=True).indices
        tile, gid = tile[by_tile], ids[pair_g[by_tile]]
        n_tiles = tiles_x * tiles_y
        lengths = torch.bincount(tile, minlength=n_tiles)
        starts = torch.cumsum(lengths, 0) - lengths
        pos = torch.arange(len(tile)) - starts[tile]
        lists = torch.full((n_tiles, int(lengths.max()) if len(tile) else 0), -1, dtype=torch.long)
        lists[tile, pos] = gid
    return lists, lengths


def rasterize_reference(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    features: torch.Tensor,
    extents: torch.Tensor,
    depths: torch.Tensor,
    visible: torch.Tensor,
    width: int,
    height: int,
    tile_size: int = TILE_SIZE,
    chunk: int = 32,
    pixels: np.ndarray | None = None,
) -> torch.Tensor:
    """Front-to-back composite of features (N, C) into an (H, W, C + 1) image, accumulated alpha last.

    Same contract as :func:`fusion.render.cpu.rasterize_cpu` (which takes C from 1 to 8), ``pixels`` included:
    the pixels outside it are rendered and then zeroed.
    """
    args = (means2d, conics, opacities, features, extents, depths, visible, width, height, tile_size, chunk)
    return _composite(*args, pixels)


def _composite(
    means2d, conics, opacities, features, extents, depths, visible, width, height, tile_size, chunk, pixels
) -> torch.Tensor:  # fmt: skip
    """The tile loop of :func:`rasterize_reference`."""
    features = torch.cat([features, torch.ones_like(features[:, :1])], dim=1)
    tiles_x = (width + tile_size - 1) // tile_size
    tiles_y = (height + tile_size - 1) // tile_size
    n_tiles, n_feat = tiles_x * tiles_y, features.shape[1]
    lists, lengths = tile_lists(means2d, extents, depths, visible, tiles_x, tiles_y, tile_size)

    # Pixel centres of every tile: (n_tiles, P, 2) with P = tile_size².
    dtype = means2d.dtype
    ty, tx = torch.meshgrid(torch.arange(tiles_y), torch.arange(tiles_x), indexing="ij")
    py, px = torch.meshgrid(torch.arange(tile_size), torch.arange(tile_size), indexing="ij")
    cols = tx.reshape(-1, 1) * tile_size + px.reshape(1, -1)
    rows = ty.reshape(-1, 1) * tile_size + py.reshape(1, -1)
    centres = torch.stack([cols, rows], dim=-1).to(dtype) + 0.5

    T = torch.ones(n_tiles, tile_size * tile_size, dtype=dtype)
    acc = torch.zeros(n_tiles, tile_size * tile_size, n_feat, dtype=dtype)
    for s in range(0, lists.shape[1], chunk):
        active = torch.nonzero((lengths > s) & (T.detach().amax(dim=1) >= T_MIN)).squeeze(1)
        if len(active) == 0:
            break
        ids = lists[active, s : s + chunk]  # (A, C)
        real = ids >= 0
        g = ids.clamp_min(0)
        d = centres[active][:, :, None, :] - means2d[g][:, None, :, :]  # (A, P, C, 2)
        dx, dy = d[..., 0], d[..., 1]
        con = conics[g][:, None]  # (A, 1, C, 3)
        power = -0.5 * (con[..., 0] * dx * dx + con[..., 2] * dy * dy) - con[..., 1] * dx * dy
        alpha = (opacities[g][:, None] * torch.exp(power)).clamp(max=ALPHA_MAX)
        keep = real[:, None] & (power <= 0) & (power >= POWER_MIN) & (alpha >= ALPHA_MIN)
        alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
        T_in = T[active][:, :, None]
        # A pixel composites an entry only while its transmittance after it stays >= T_MIN; transmittance only
        # decreases, so the entries it composites are a prefix of its list.
        within = (T_in * torch.cumprod(1 - alpha, dim=-1)).detach() >= T_MIN
        alpha = torch.where(within, alpha, torch.zeros_like(alpha))
        trans = torch.cumprod(1 - alpha, dim=-1)
        T_before = T_in * torch.cat([torch.ones_like(trans[..., :1]), trans[..., :-1]], dim=-1)
        weights = alpha * T_before  # (A, P, C)
        acc = acc.index_add(0, active, torch.einsum("apc,acf->apf", weights, features[g]))
        T = T.index_copy(0, active, T_in[..., 0] * trans[..., -1])

    image = acc.reshape(tiles_y, tiles_x, tile_size, tile_size, n_feat).permute(0, 2, 1, 3, 4)
    image = image.reshape(tiles_y * tile_size, tiles_x * tile_size, n_feat)[:height, :width]
    if pixels is not None:
        mask = torch.from_numpy(np.asarray(pixels, bool))
        image = image * mask.to(dtype)[..., None]
    return image
