"""Geometric losses (fusion/train/geometry_loss.py) against analytic truth, masks and float64 gradchecks."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from fusion.train.geometry_loss import (
    depth_normal_consistency,
    flatness_loss,
    mvs_depth_loss,
    normal_from_depth,
    pixel_rays,
)

W, H = 40, 30
K = torch.tensor([[50.0, 0.0, 20.0], [0.0, 45.0, 15.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


def plane_depth(normal: np.ndarray, point: np.ndarray) -> torch.Tensor:
    """(H, W) z-depth of the plane through ``point`` with ``normal`` (camera frame) along every pixel ray."""
    n = torch.from_numpy(normal)
    return float(n @ torch.from_numpy(point)) / (pixel_rays(K, W, H, torch.float64) @ n)


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("normal", [[0, 0, -1], [0.4, -0.3, -1], [-0.8, 0.2, -0.5]], ids=["fronto", "tilt", "steep"])
def test_normal_from_depth_of_a_plane_is_exact(normal):
    """Back-projected central differences of a plane lie in the plane: its normal to 1e-9, facing the camera,
    every pixel but the border valid."""
    n = unit(normal)
    depth = plane_depth(n, np.array([0.1, -0.2, 3.0]))
    assert bool((depth > 0).all())
    out, valid = normal_from_depth(depth, K)
    assert bool(valid[1:-1, 1:-1].all()) and not bool(valid[0].any() | valid[-1].any())
    assert not bool(valid[:, 0].any() | valid[:, -1].any())
    torch.testing.assert_close(out[valid], torch.from_numpy(n).expand(int(valid.sum()), 3), rtol=0, atol=1e-9)
    assert bool((out[~valid] == 0).all())


def test_normal_from_depth_of_a_sphere():
    """A sphere's depth map: normals of (P − C)/r within 0.5° (median) and 2° (max, near the silhouette, where the
    surface turns fastest between pixels) by central differences (O(h²) error)."""
    centre, radius = torch.tensor([0.2, 0.1, 4.0], dtype=torch.float64), 1.5
    rays = pixel_rays(K, W, H, torch.float64)
    # nearest intersection of t·ray with the sphere: |t r − c|² = R²
    a = (rays * rays).sum(-1)
    b = -2 * (rays @ centre)
    c = float(centre @ centre) - radius**2
    disc = b * b - 4 * a * c
    hit = disc > 0
    t = torch.where(hit, (-b - disc.clamp_min(0).sqrt()) / (2 * a), torch.zeros_like(a))
    out, valid = normal_from_depth(t, K, hit, max_relative_step=0.05)
    truth = (t[..., None] * rays - centre) / radius
    angle = torch.rad2deg(torch.arccos((out * truth).sum(-1).clamp(-1, 1)))
    assert int(valid.sum()) > 200
    assert float(angle[valid].median()) < 0.5 and float(angle[valid].max()) < 2.0


def test_normal_from_depth_masks_holes_and_edges_without_nan():
    depth = plane_depth(unit([0.2, 0.1, -1]), np.array([0.0, 0.0, 2.0])).clone()
    depth[10, 10] = 0.0  # a hole
    depth[:, 30:] *= 1.5  # a depth edge
    depth.requires_grad_(True)
    out, valid = normal_from_depth(depth, K, max_relative_step=0.1)
    for r, c in [(10, 10), (9, 10), (11, 10), (10, 9), (10, 11)]:
        assert not bool(valid[r, c])
    assert not bool(valid[:, 29:31].any()) and bool(valid[5:25, 31:38].all())
    out.sum().backward()
    assert bool(torch.isfinite(out).all()) and bool(torch.isfinite(depth.grad).all())


def test_normal_from_depth_gradcheck():
    gen = torch.Generator().manual_seed(0)
    base = plane_depth(unit([0.3, -0.2, -1]), np.array([0.0, 0.0, 2.0]))[:8, :9]
    k = K.clone()
    depth = (base + 0.05 * torch.rand(8, 9, generator=gen, dtype=torch.float64)).requires_grad_(True)
    weights = torch.rand(8, 9, 3, generator=gen, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda d: (normal_from_depth(d, k)[0] * weights).sum(), (depth,))


def test_depth_normal_consistency_values_masks_and_gradients():
    a = torch.zeros(2, 3, 3, dtype=torch.float64)
    a[..., 2] = -0.5  # premultiplied by alpha 0.5: normalised inside
    b = torch.zeros_like(a)
    b[0, :, 2] = -1.0  # agree: 0
    b[1, 0, 0] = 1.0  # perpendicular: 1
    b[1, 1, 2] = 1.0  # opposite: 2
    mask = torch.ones(2, 3)
    expected = (0 + 0 + 0 + 1 + 2 + 0) / 5  # pixel (1, 2) has a zero depth normal: weight 0
    assert math.isclose(float(depth_normal_consistency(a, b, mask)), expected, rel_tol=1e-12)
    mask[1] = 0.0
    assert float(depth_normal_consistency(a, b, mask)) == 0.0
    empty = depth_normal_consistency(a.requires_grad_(True), b, torch.zeros(2, 3))
    empty.backward()
    assert float(empty.detach()) == 0.0 and bool(torch.isfinite(a.grad).all())
    gen = torch.Generator().manual_seed(1)
    x = torch.randn(4, 5, 3, generator=gen, dtype=torch.float64, requires_grad=True)
    y = torch.randn(4, 5, 3, generator=gen, dtype=torch.float64, requires_grad=True)
    w = torch.rand(4, 5, generator=gen, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p, q: depth_normal_consistency(p, q, w), (x, y))


def test_flatness_loss():
    log_scales = torch.log(torch.tensor([[0.1, 0.02, 0.3], [0.5, 0.4, 0.05]], dtype=torch.float64))
    log_scales.requires_grad_(True)
    loss = flatness_loss(log_scales, "min")
    assert math.isclose(float(loss.detach()), (0.02 + 0.05) / 2, rel_tol=1e-12)
    loss.backward()
    grad = log_scales.grad
    assert bool((grad[0, [0, 2]] == 0).all()) and bool((grad[1, :2] == 0).all())
    assert math.isclose(float(grad[0, 1]), 0.01, rel_tol=1e-12)  # d(σ/2)/d log σ = σ/2
    ratio = flatness_loss(log_scales.detach(), "ratio")
    assert math.isclose(float(ratio), (0.02 / 0.1 + 0.05 / 0.4) / 2, rel_tol=1e-12)
    assert float(flatness_loss(torch.zeros(0, 3))) == 0.0
    with pytest.raises(ValueError, match="mode"):
        flatness_loss(log_scales, "max")  # type: ignore[arg-type]


@pytest.mark.parametrize("kind", ["log", "inverse"])
def test_mvs_depth_loss(kind):
    depth = torch.tensor([[2.0, 4.0], [1.0, 0.0]], dtype=torch.float64, requires_grad=True)
    prior = torch.tensor([[2.0, 2.0], [0.0, 3.0]], dtype=torch.float64)
    weight = torch.tensor([[1.0, 3.0], [1.0, 1.0]], dtype=torch.float64)
    loss = mvs_depth_loss(depth, prior, weight, kind=kind)
    # (1, 0) has no prior, (1, 1) no rendered depth: weight 0
    err = math.log(2.0) if kind == "log" else 0.25
    assert math.isclose(float(loss.detach()), 3 * err / 4, rel_tol=1e-12)
    loss.backward()
    assert bool(torch.isfinite(depth.grad).all()) and float(depth.grad[1].abs().max()) == 0.0
    valid = torch.tensor([[True, False], [True, True]])
    assert float(mvs_depth_loss(depth.detach(), prior, weight, valid, kind=kind)) == 0.0
