"""Pieces of the cpu rasteriser (fusion/render/cpu.py) against brute force: depth order, tile lists, the
transposed per-Gaussian index."""

from __future__ import annotations

import numpy as np
import pytest

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
