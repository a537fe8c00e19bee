"""The σ model of splat-surface points (fusion.splat_surface.sigma_model): the spread of the agreeing views misses
a bias all views share; the footprint, roughness and anchor terms make σ grow with it. Checked on a layer rendered
at a known offset from its anchor surface (the views agree exactly, the bias is known) and on an analytic plane
with known noise (the 95 % interval holds its share of the true errors)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_splat_surface import all_masks, layer
from test_train_trainer import ring_cameras

from core.errors import ConfigError
from fusion.splat_surface import (
    SIGMA_ANCHOR,
    SIGMA_FOOTPRINT,
    SIGMA_ROUGHNESS,
    SplatSurfaceOptions,
    sigma_model,
    splat_surface_points,
)


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def plane_anchors(z: float = 0.0, half: float = 0.6, n_side: int = 120) -> np.ndarray:
    """(n², 3) anchor points on the plane z = ``z`` (an MVS surface around and under the layer)."""
    g = np.linspace(-half, half, n_side)
    x, y = np.meshgrid(g, g)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)


def test_sigma_grows_with_a_bias_all_views_share() -> None:
    """A flat layer rendered at z = b above its anchor surface z = 0: every view renders the same biased surface,
    so the spread is at its floor whatever b is; the model's σ grows with b and its 95 % interval covers it."""
    cams = ring_cameras(6, width=96, height=72)
    anchors = plane_anchors()
    medians, spreads = [], []
    for bias in (0.0, 0.01, 0.03):
        pts = splat_surface_points(layer(bias), cams, all_masks(cams), anchors=anchors)
        assert len(pts) > 1000 and np.abs(pts.positions[:, 2] - bias).max() < 1e-4
        medians.append(float(np.median(pts.sigma)))
        spreads.append(float(np.median(pts.spread)))
        assert np.all(pts.sigma >= pts.spread) and pts.footprint.shape == (len(pts),)
        if bias > 0:
            assert np.mean(bias <= 1.96 * pts.sigma) >= 0.9
    assert spreads[0] == pytest.approx(spreads[2], rel=0.05)  # the views cannot see the bias
    assert medians[0] < medians[1] < medians[2]
    # the spread alone (every constant 0) is what the views see
    off = SplatSurfaceOptions(sigma_footprint=0.0, sigma_roughness=0.0, sigma_anchor=0.0)
    bare = splat_surface_points(layer(0.03), cams, all_masks(cams), options=off, anchors=anchors)
    assert np.array_equal(bare.sigma, bare.spread) and np.median(bare.sigma) < 0.01


def test_calibration_on_a_plane_with_known_noise() -> None:
    """Points on z = 0 with normal noise N(0, η) (η = 2 mm), anchors on the exact plane, no spread and a small
    footprint: the model's ±1.96σ holds at least 90 % of the true errors, and σ stays of the order of η."""
    rng = np.random.default_rng(0)
    eta = 0.002
    xy = rng.uniform(-0.5, 0.5, (20000, 2))
    err = rng.normal(0.0, eta, len(xy))
    pos = np.column_stack([xy, err])
    normals = np.tile([0.0, 0.0, 1.0], (len(pos), 1))
    opts = SplatSurfaceOptions()
    sigma = sigma_model(pos, normals, np.zeros(len(pos)), np.full(len(pos), 1e-4), plane_anchors(), opts)
    coverage = float(np.mean(np.abs(err) <= 1.96 * sigma))
    assert coverage >= 0.9, coverage
    assert np.median(sigma) < 4 * eta
    # without anchors the roughness term alone still sees the noise
    rough = sigma_model(pos, normals, np.zeros(len(pos)), np.zeros(len(pos)), None, opts)
    if opts.sigma_roughness > 0:
        assert np.median(rough) > 0.5 * opts.sigma_roughness * eta


def test_the_model_terms_and_bad_constants() -> None:
    from fusion.merge_options import MergeOptions

    merge = MergeOptions()  # the option stays off by default; its support radius chosen on seed 12
    assert merge.splat_surface is False and merge.splat_surface_support == 2.0
    opts = SplatSurfaceOptions()
    assert (opts.sigma_footprint, opts.sigma_roughness, opts.sigma_anchor) == (
        SIGMA_FOOTPRINT, SIGMA_ROUGHNESS, SIGMA_ANCHOR)  # fmt: skip
    pos = np.zeros((1, 3))
    n = np.array([[0.0, 0.0, 1.0]])
    only_fp = SplatSurfaceOptions(sigma_footprint=2.0, sigma_roughness=0.0, sigma_anchor=0.0)
    assert sigma_model(pos, n, np.array([0.003]), np.array([0.002]), None, only_fp)[0] == pytest.approx(0.005)
    only_anchor = SplatSurfaceOptions(sigma_footprint=0.0, sigma_roughness=0.0, sigma_anchor=1.0)
    anchors = plane_anchors(z=-0.004, n_side=20)
    assert sigma_model(pos, n, np.zeros(1), np.zeros(1), anchors, only_anchor)[0] == pytest.approx(0.004)
    assert len(sigma_model(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0), anchors, opts)) == 0
    for bad in ({"sigma_footprint": -1.0}, {"sigma_anchor": -0.1}, {"sigma_neighbours": 0}):
        with pytest.raises(ConfigError):
            SplatSurfaceOptions(**bad)
