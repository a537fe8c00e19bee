"""The one SH basis (fusion/render/sh_basis.py) against independent truth: its constants against their closed forms
in 50-digit decimal arithmetic, its values against scipy's complex spherical harmonics (real combinations, the
Condon–Shortley phase kept), its gradient against autograd; and every user of it (torch, numba, glTF, oracle) gives
the same values."""

from __future__ import annotations

from decimal import Decimal, localcontext

import numpy as np
import pytest
import torch
from scipy.special import sph_harm_y

from fusion.render.sh_basis import SH_C0, SH_C1, SH_C2, SH_C3, sh_basis_grad, sh_basis_into

PI_50 = Decimal("3.14159265358979323846264338327950288419716939937510")


def _closed(num: int, den: int) -> float:
    """sqrt(num / (den π)) to 50 digits, rounded once to the nearest double."""
    with localcontext() as ctx:
        ctx.prec = 50
        return float((Decimal(num) / (Decimal(den) * PI_50)).sqrt())


def test_constants_are_the_correctly_rounded_closed_forms():
    assert SH_C0 == _closed(1, 4)
    assert SH_C1 == _closed(3, 4)
    c15_4, c15_16 = _closed(15, 4), _closed(15, 16)
    assert SH_C2 == (c15_4, -c15_4, _closed(5, 16), -c15_4, c15_16)
    c35, c21 = _closed(35, 32), _closed(21, 32)
    assert SH_C3 == (-c35, _closed(105, 4), -c21, _closed(7, 16), -c21, _closed(105, 16), -c35)


def _directions(n: int, seed: int) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _scipy_real_sh(degree: int, d: np.ndarray) -> np.ndarray:
    """(M, (degree+1)²) real SH from scipy's complex Y_l^m (Condon–Shortley phase included): √2 Im Y_l^|m| for
    m < 0, Y_l^0, √2 Re Y_l^m for m > 0, index l² + l + m."""
    theta = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    phi = np.arctan2(d[:, 1], d[:, 0])
    cols = []
    for ell in range(degree + 1):
        for m in range(-ell, ell + 1):
            y = sph_harm_y(ell, abs(m), theta, phi)
            cols.append(np.sqrt(2.0) * (y.imag if m < 0 else y.real) if m else y.real)
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_basis_matches_scipy_spherical_harmonics(degree):
    d = _directions(500, seed=degree)
    out = np.empty(((degree + 1) ** 2, len(d)))
    sh_basis_into(degree, d[:, 0], d[:, 1], d[:, 2], out)
    np.testing.assert_allclose(out.T, _scipy_real_sh(degree, d), rtol=0, atol=1e-14)


def test_every_user_evaluates_the_same_basis():
    """torch (reference backend), numba (cpu backend), glTF's SH rotation and the brute-force oracle's colour all
    give the numpy values of the shared basis, at degree 3."""
    from fusion.gltf_splats import sh_basis as gltf_basis
    from fusion.render.brute_force import _sh_rgb
    from fusion.render.project_cpu import _sh_basis
    from fusion.render.sh import sh_basis as torch_basis

    d = _directions(64, seed=7)
    ref = np.empty((16, len(d)))
    sh_basis_into(3, d[:, 0], d[:, 1], d[:, 2], ref)
    ref = ref.T
    np.testing.assert_allclose(torch_basis(3, torch.from_numpy(d)).numpy(), ref, rtol=0, atol=1e-15)
    np.testing.assert_allclose(gltf_basis(d, 3), ref, rtol=0, atol=1e-15)
    row = np.empty(16)
    for i in range(4):
        _sh_basis(3, d[i, 0], d[i, 1], d[i, 2], row)
        np.testing.assert_allclose(row, ref[i], rtol=0, atol=1e-15)
    coeffs = np.random.default_rng(1).normal(size=(16, 3))
    np.testing.assert_allclose(_sh_rgb(coeffs, d[0], 3), np.maximum(ref[0] @ coeffs + 0.5, 0.0), atol=1e-14)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_gradient_matches_autograd(degree):
    """sh_basis_grad (the numba backward's) == autograd of sh_basis_into through torch, components independent."""
    d = torch.from_numpy(_directions(200, seed=10 + degree)).requires_grad_(True)
    k = (degree + 1) ** 2
    w = torch.from_numpy(np.random.default_rng(degree).normal(size=(k, 200)))
    terms: list = [None] * k
    sh_basis_into(degree, d[:, 0], d[:, 1], d[:, 2], terms)
    total = sum((terms[j] * w[j]).sum() for j in range(1, k))
    total.backward()
    dd = d.detach()
    gx, gy, gz = sh_basis_grad(degree, dd[:, 0], dd[:, 1], dd[:, 2], w)
    torch.testing.assert_close(torch.stack([gx, gy, gz], dim=1), d.grad, rtol=1e-13, atol=1e-13)
