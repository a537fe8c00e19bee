"""The numba kernels of the CPU MVS against their torch / LAPACK references on random inputs: the matching cost
against ``recon.mvs_cpu.cost_reference``, the normals against the torch plane fit they replaced (float64, LAPACK's
``eigh``), the 3×3 eigen-solver against ``numpy.linalg.eigh``."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from recon.mvs_cpu import _make_level, cost_reference, normals_from_depth, pixel_rays
from recon.mvs_cpu_kernels import INVALID_COST, _jacobi_smallest, _smallest_eigenvector, bordered, ncc_costs

H, W = 200, 72  # reference size, px: 200 rows make two bands of the cost kernel (the band edge is tested)


def _rotation_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


@pytest.fixture(scope="module")
def level():
    """A reference H × W and four textured sources of different sizes, moved sideways and turned."""
    rng = np.random.default_rng(3)

    def texture(h: int, w: int) -> np.ndarray:
        return cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.2)

    K = np.array([[90.0, 0, W / 2], [0, 90.0, H / 2], [0, 0, 1]])
    srcs = [texture(H + 3 * i, W - 5 * i) for i in range(4)]
    rel = []
    for i in range(4):
        m = np.eye(4)
        m[:3, :3] = _rotation_y(0.04 * (i + 1))
        m[:3, 3] = [-0.25 * (i + 1), 0.03 * i, 0.02]
        rel.append(m)
    return _make_level(texture(H, W), srcs, K, [K] * 4, rel, radius=2, best_k=2)


def _float64(level):
    """The level with its tensors in float64: the reference without float32 cancellation in E[x²] − E[x]²."""
    tensors = {
        f.name: getattr(level, f.name).double()
        for f in dataclasses.fields(level)
        if isinstance(getattr(level, f.name), torch.Tensor) and getattr(level, f.name).is_floating_point()
    }
    return dataclasses.replace(level, **tensors)


def _kernel(level, inv: torch.Tensor, threads: int) -> np.ndarray:
    return ncc_costs(
        bordered(level.srcs[:, 0].numpy()),
        level.src_hw,
        level.P.numpy(),
        level.q.numpy(),
        level.ref[0, 0].numpy(),
        level.ref_mu[0, 0].numpy(),
        level.ref_std[0, 0].numpy(),
        inv.numpy(),
        level.radius,
        level.best_k,
        threads,
    )


@pytest.mark.parametrize(("num_hyps", "threads"), [(1, 1), (1, 3), (2, 2), (7, 2)])
def test_ncc_kernel_matches_the_torch_reference(level, num_hyps: int, threads: int):
    rng = np.random.default_rng(num_hyps)
    # smooth hypothesis maps (the windows follow slanted surfaces) over depths 2-10 m, partly leaving the sources
    base = rng.uniform(0.1, 0.5, (num_hyps, 1, 1))
    ramp = np.linspace(-0.05, 0.05, W)[None, None, :]
    inv = torch.from_numpy((base + ramp + 0.01 * rng.random((num_hyps, H, W))).astype(np.float32))
    ours = _kernel(level, inv, threads)
    ref = cost_reference(_float64(level), inv.double()).numpy()
    # float64 sums in both; the kernel rounds its cost to float32 (relative 6e-8 of costs up to 2)
    np.testing.assert_allclose(ours, ref, atol=1e-6)
    assert 0.2 < (ours < INVALID_COST).mean() < 1.0  # both matched and unmatched pixels are compared


def test_ncc_kernel_gives_the_same_bits_with_any_number_of_threads(level):
    inv = torch.full((3, H, W), 0.25) + torch.linspace(0, 0.05, W)
    np.testing.assert_array_equal(_kernel(level, inv, 1), _kernel(level, inv, 3))


def test_ncc_kernel_is_close_to_the_float32_reference_on_textured_windows(level):
    inv = torch.full((3, H, W), 0.25) + torch.linspace(0, 0.05, 3)[:, None, None]
    ours = _kernel(level, inv, 2)
    ref32 = cost_reference(level, inv).numpy()
    matched = (ours < INVALID_COST) & (ref32 < INVALID_COST)
    assert matched.mean() > 0.5
    # float32 box sums lose ~1e-7 of E[x²] against variances ≥ 1e-3 of this texture: costs agree to ~1e-4
    np.testing.assert_allclose(ours[matched], ref32[matched], atol=2e-3)


@pytest.mark.parametrize("solver", [_smallest_eigenvector, _jacobi_smallest])
def test_eigenvector_solvers_match_lapack(solver):
    rng = np.random.default_rng(0)
    a = rng.normal(size=(300, 3, 3))
    cov = a @ a.transpose(0, 2, 1) * 10.0 ** rng.uniform(-6, 6, (300, 1, 1))
    # flat point sets (surface fits): smallest eigenvalue 1e-12 of the others
    q, _ = np.linalg.qr(rng.normal(size=(150, 3, 3)))
    scales = np.array([1e-12, 1.0, 2.0]) * rng.uniform(0.5, 2, (150, 3))
    cov[:150] = np.einsum("nij,nj,nkj->nik", q, scales, q)
    cov[0] = np.diag([0.0, 1.0, 1.0])  # the two larger eigenvalues equal
    _, vecs = np.linalg.eigh(cov)
    vec, scratch = np.empty(3), np.empty((3, 3))
    for m, expected in zip(cov, vecs[:, :, 0], strict=True):
        solver(m.copy(), scratch, vec)
        assert abs(vec @ expected) == pytest.approx(1.0, abs=1e-9)


def _normals_reference(depth: np.ndarray, K: np.ndarray, radius: int, min_points: int = 6) -> np.ndarray:
    """The torch plane fit that ``normals_from_depth`` replaced, in float64 (in float32 its E[XXᵀ] − μμᵀ about the
    image's centre lost up to 20° on 320×240 maps of a 1 m scene)."""
    h, w = depth.shape
    d = torch.from_numpy(depth).double()
    valid = d > 0
    X = pixel_rays(K, h, w).double() * d[..., None]
    k = 2 * radius + 1

    def box(t: torch.Tensor) -> torch.Tensor:  # (H, W, C) window sums, zeros outside
        return F.avg_pool2d(t.permute(2, 0, 1)[None], k, 1, radius, count_include_pad=True)[0].permute(1, 2, 0) * k * k

    sums = box(torch.stack([valid.double(), d * valid], -1))
    mean_d = sums[..., 1] / sums[..., 0].clamp_min(1)
    mw = (valid & ((d - mean_d).abs() <= 0.05 * mean_d.clamp_min(1e-6))).double()[..., None]
    Xc = X - X.mean(dim=(0, 1), keepdim=True)
    n = box(mw)[..., 0].clamp_min(1)
    mu = box(Xc * mw) / n[..., None]
    second = box((Xc[..., :, None] * Xc[..., None, :]).reshape(h, w, 9) * mw).reshape(h, w, 3, 3) / n[..., None, None]
    normal = torch.linalg.eigh(second - mu[..., :, None] * mu[..., None, :])[1][..., 0]
    normal = torch.where(((normal * X).sum(-1) > 0)[..., None], -normal, normal)
    ok = valid & (box(mw)[..., 0] >= min_points)
    return torch.where(ok[..., None], normal, torch.zeros_like(normal)).numpy()


def test_normals_match_the_float64_plane_fit_on_a_bumpy_map():
    rng = np.random.default_rng(1)
    K = np.array([[120.0, 0, 40], [0, 120.0, 30], [0, 0, 1]])
    rows, cols = np.mgrid[0:60, 0:80]
    depth = 3.0 + 0.01 * cols + 0.2 * np.sin(rows / 6.0) + 0.002 * rng.normal(size=(60, 80))
    depth[:, 50:] += 0.5  # a step: windows across it drop the far side
    depth[rng.random((60, 80)) < 0.1] = 0  # holes
    depth = depth.astype(np.float32)
    ours = normals_from_depth(depth, K, radius=2)
    ref = _normals_reference(depth, K, radius=2)
    np.testing.assert_array_equal(np.any(ours != 0, -1), np.any(ref != 0, -1))
    assert np.any(ours != 0, -1).mean() > 0.8
    # float64 in both; ours is rounded to float32 (1e-7)
    np.testing.assert_allclose(ours, ref, atol=1e-5)
