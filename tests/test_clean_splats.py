"""Cleaning: each removal reason on hand-made splats whose fate is known."""

from __future__ import annotations

import math

import numpy as np

from core.cameras import Camera, Cameras, View
from core.gaussians import GaussianSet
from fusion.clean import CleanOptions, Reason, clean_splats


def one_camera() -> Cameras:
    """A camera at the origin looking down +z (identity pose), 100×80 px, focal 100."""
    cam = Camera.pinhole(100.0, 100.0, 50.0, 40.0, 100, 80)
    return Cameras({1: cam}, {1: View(1, "a.png", 1, np.array([1.0, 0, 0, 0]), np.zeros(3))})


def splats(means: np.ndarray, sigma: float = 0.002, opacity: float = 0.8) -> GaussianSet:
    n = len(means)
    return GaussianSet(
        means,
        np.full((n, 3), math.log(sigma)),
        np.tile([1.0, 0, 0, 0], (n, 1)),
        np.full(n, math.log(opacity / (1 - opacity))),
        np.zeros((n, 3)),
    )


def test_each_reason_is_found_and_counted() -> None:
    cams = one_camera()
    mask = np.zeros((80, 100), bool)
    mask[20:60, 20:80] = True  # pixels 20..79 x 20..59
    rng = np.random.default_rng(0)
    # a dense patch of 200 splats at z = 2 projecting into the mask (x, y within ±0.4 m -> pixels 30..70, 20..60)
    core = np.column_stack([rng.uniform(-0.3, 0.3, 200), rng.uniform(-0.3, 0.3, 200), np.full(200, 2.0)])
    outside = np.array([[0.95, 0.0, 2.0], [-0.95, 0.0, 2.0]])  # project to x = 97.5 / 2.5: outside the mask
    lonely = np.array([[0.0, 0.0, 1.2], [0.01, 0.0, 1.2]])  # a pair floating in front, inside the mask
    gs = GaussianSet.concatenate([splats(core), splats(outside), splats(lonely)])
    faint_idx, big_idx = 5, 6
    gs.logit_opacities[faint_idx] = -6.0
    gs.log_scales[big_idx] = math.log(0.5)
    res = clean_splats(gs, cams, {"a.png": mask}, CleanOptions(min_cluster_size=5, cluster_eps_spacing=5.0))
    assert res.reasons[200] == Reason.OUTSIDE_MASKS and res.reasons[201] == Reason.OUTSIDE_MASKS
    assert res.reasons[faint_idx] == Reason.LOW_OPACITY
    assert res.reasons[big_idx] == Reason.EXTREME_SCALE
    assert res.reasons[202] == Reason.ISOLATED and res.reasons[203] == Reason.ISOLATED
    c = res.counts
    assert (c.outside_masks, c.low_opacity, c.extreme_scale, c.isolated) == (2, 1, 1, 2)
    assert c.kept == 198 == len(res.splats) and c.input == 204


def test_nothing_is_removed_from_a_clean_patch() -> None:
    rng = np.random.default_rng(1)
    core = np.column_stack([rng.uniform(-0.3, 0.3, 100), rng.uniform(-0.3, 0.3, 100), np.full(100, 2.0)])
    mask = np.ones((80, 100), bool)
    res = clean_splats(splats(core), one_camera(), {"a.png": mask})
    assert res.counts.kept == 100 and not res.reasons.any()
