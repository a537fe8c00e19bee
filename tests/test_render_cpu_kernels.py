"""Pieces of the cpu rasteriser (fusion/render/cpu.py) against brute force: depth order, tile lists, the
transposed per-Gaussian index."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fusion.render.cpu import bin_gaussians, depth_order


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_depth_order_is_numpys_stable_argsort(dtype) -> None:
    rng = np.random.default_rng(0)
    d = rng.uniform(0.01, 50.0, 20_000).astype(dtype)
    d[::7] = d[3]  # ties keep their input order
    d[1::11] = rng.choice([1e-3, 1e3, 2.0], size=len(d[1::11]))
    np.testing.assert_array_equal(depth_order(d), np.argsort(d, kind="stable"))
    np.testing.assert_array_equal(depth_order(d[:0]), np.zeros(0, np.int64))
    with_negative = d.copy()
    with_negative[5] = -1.0  # not a visible Gaussian's depth, but still sorted correctly
    np.testing.assert_array_equal(depth_order(with_negative), np.argsort(with_negative, kind="stable"))


def test_tile_lists_and_transposed_index_match_brute_force() -> None:
    rng = np.random.default_rng(1)
    n, w, h = 3000, 100, 70
    means2d = rng.uniform(-10, 110, (n, 2)).astype(np.float32)
    extents = rng.uniform(0.5, 20, (n, 2)).astype(np.float32)
    depths = rng.uniform(1, 5, n).astype(np.float32)
    visible = rng.uniform(size=n) < 0.9
    bins = bin_gaussians(means2d, extents, depths, visible, w, h)
    tx, ty = 7, 5
    order = np.argsort(depths, kind="stable")
    for t in range(tx * ty):
        x0, y0 = (t % tx) * 16, (t // tx) * 16
        expected = [
            g
            for g in order
            if visible[g]
            and np.floor((means2d[g, 0] + extents[g, 0]) / 16) >= x0 // 16
            and np.floor((means2d[g, 0] - extents[g, 0]) / 16) <= x0 // 16
            and np.floor((means2d[g, 1] + extents[g, 1]) / 16) >= y0 // 16
            and np.floor((means2d[g, 1] - extents[g, 1]) / 16) <= y0 // 16
        ]
        np.testing.assert_array_equal(bins.ids[bins.offsets[t] : bins.offsets[t + 1]], expected)
    # The transposed index: a permutation of the entries; each Gaussian's slots hold exactly its entries, in
    # increasing entry order.
    entry_at = np.argsort(bins.slot_of)
    assert sorted(bins.slot_of.tolist()) == list(range(len(bins.ids)))
    for p, g in enumerate(bins.sorted_ids):
        entries = entry_at[bins.g_offsets[p] : bins.g_offsets[p + 1]]
        assert (bins.ids[entries] == g).all() and (np.diff(entries) > 0).all()
        assert len(entries) == int((bins.ids == g).sum())
    assert set(bins.sorted_ids.tolist()) <= set(np.flatnonzero(visible).tolist())


def _random_conics(rng, n):
    """Inverse covariances of random anisotropic 2-D Gaussians (σ 0.3-12 px, any angle), float32."""
    s = rng.uniform(0.3, 12.0, (n, 2))
    ang = rng.uniform(0, np.pi, n)
    c, si = np.cos(ang), np.sin(ang)
    sxx = (c * s[:, 0]) ** 2 + (si * s[:, 1]) ** 2 + 0.3
    syy = (si * s[:, 0]) ** 2 + (c * s[:, 1]) ** 2 + 0.3
    sxy = c * si * (s[:, 0] ** 2 - s[:, 1] ** 2)
    det = sxx * syy - sxy * sxy
    conics = np.stack([syy / det, -sxy / det, sxx / det], axis=1).astype(np.float32)
    extents = (3.0 * np.sqrt(np.stack([sxx, syy], axis=1))).astype(np.float32)
    return conics, extents


def _min_q_on_rect(m, conic, x0, x1, y0, y1) -> float:
    """min of dᵀ C d over the rectangle [x0, x1] × [y0, y1] of points (d = point − m): 0 inside, else the least of
    the four edges' minima (a 1-D quadratic each, clamped to the edge)."""
    a, b, c = conic
    if x0 <= m[0] <= x1 and y0 <= m[1] <= y1:
        return 0.0
    best = np.inf
    for dx in (x0 - m[0], x1 - m[0]):
        dy = np.clip(-b * dx / c, y0 - m[1], y1 - m[1])
        best = min(best, a * dx * dx + 2 * b * dx * dy + c * dy * dy)
    for dy in (y0 - m[1], y1 - m[1]):
        dx = np.clip(-b * dy / a, x0 - m[0], x1 - m[0])
        best = min(best, a * dx * dx + 2 * b * dx * dy + c * dy * dy)
    return best


def test_ellipse_tile_lists_keep_every_drawn_pixel_and_only_box_tiles() -> None:
    """With conics, a Gaussian is listed in every tile holding a pixel centre inside its 3σ ellipse (brute force
    over every pixel centre) and only in tiles whose rectangle of pixel centres meets the ellipse grown by the
    safety margin (exact minimum of the quadratic form over the rectangle); the lists are sub-lists of the box
    lists, in the same depth order, and the transposed index stays consistent."""
    rng = np.random.default_rng(2)
    n, w, h = 1500, 100, 70
    means2d = rng.uniform(-10, 110, (n, 2)).astype(np.float32)
    conics, extents = _random_conics(rng, n)
    depths = rng.uniform(1, 5, n).astype(np.float32)
    visible = rng.uniform(size=n) < 0.9
    box = bin_gaussians(means2d, extents, depths, visible, w, h)
    ell = bin_gaussians(means2d, extents, depths, visible, w, h, conics=conics)
    assert len(ell.ids) < 0.95 * len(box.ids)
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    tiles_x, tiles_y = 7, 5
    tile_of = (ys // 16).astype(int) * tiles_x + (xs // 16).astype(int)
    m, c = means2d.astype(np.float64), conics.astype(np.float64)
    for g in np.flatnonzero(visible):
        dx, dy = xs - m[g, 0], ys - m[g, 1]
        q = c[g, 0] * dx * dx + 2 * c[g, 1] * dx * dy + c[g, 2] * dy * dy
        must = set(np.unique(tile_of[q <= 9.0]).tolist())  # tiles where the kernels can draw g
        may = {
            t
            for t in range(tiles_x * tiles_y)
            if _min_q_on_rect(m[g], c[g], (t % tiles_x) * 16 + 0.5, min((t % tiles_x) * 16 + 16, w) - 0.5,
                              (t // tiles_x) * 16 + 0.5, min((t // tiles_x) * 16 + 16, h) - 0.5)
            <= 9.0 * 1.01 + 0.05 + 1e-9
        }  # fmt: skip
        listed = {t for t in range(len(ell.offsets) - 1) if g in ell.ids[ell.offsets[t] : ell.offsets[t + 1]]}
        in_box = {t for t in range(len(box.offsets) - 1) if g in box.ids[box.offsets[t] : box.offsets[t + 1]]}
        assert must <= listed <= may and listed <= in_box, g
    for t in range(len(ell.offsets) - 1):
        sub = ell.ids[ell.offsets[t] : ell.offsets[t + 1]]
        full = box.ids[box.offsets[t] : box.offsets[t + 1]]
        np.testing.assert_array_equal(sub, full[np.isin(full, sub)])
    entry_at = np.argsort(ell.slot_of)
    assert sorted(ell.slot_of.tolist()) == list(range(len(ell.ids)))
    for p, g in enumerate(ell.sorted_ids):
        entries = entry_at[ell.g_offsets[p] : ell.g_offsets[p + 1]]
        assert (ell.ids[entries] == g).all() and len(entries) == int((ell.ids == g).sum())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_ellipse_tile_lists_change_nothing_in_images_and_gradients(dtype) -> None:
    """The rasteriser with ellipse-culled tile lists and units gives bitwise the box's image and gradients."""
    from fusion.render import cpu, render
    from fusion.render.synthetic import random_scene

    scene = random_scene(3000, 80, 56, seed=9, sh_degree=1, sigma_px=(0.3, 9.0), dtype=dtype)
    weights = torch.rand(56, 80, 3, generator=torch.Generator().manual_seed(1), dtype=dtype)
    results = []
    try:
        for tiles, units in ((False, False), (True, False), (False, True), (True, True)):
            cpu.ELLIPSE_TILES[0], cpu.ELLIPSE_UNITS[0] = tiles, units
            params = [p.clone().requires_grad_(True) for p in scene.params]
            res = render(*params, *scene.camera, backend="cpu")
            res.means2d.retain_grad()
            ((res.colour * weights).sum() + 0.1 * res.depth.sum() + res.alpha.sum()).backward()
            results.append([res.colour, res.alpha, res.depth, res.means2d.grad] + [p.grad for p in params])
    finally:
        cpu.ELLIPSE_TILES[0], cpu.ELLIPSE_UNITS[0] = True, True
    for other in results[1:]:
        for a, b in zip(results[0], other, strict=True):
            assert torch.equal(a, b)
