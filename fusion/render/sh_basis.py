"""The real spherical-harmonics basis up to degree 3: one set of constants and one evaluation for every user.

Convention (graphdeco's 3DGS, the KHR_gaussian_splatting spec's Appendix A, gsplat): index k = l² + l + m,
m = -l..l, DC first; Y_l^m = √2 K_l^m P_l^|m|(cos θ) sin(|m| φ) for m < 0, K_l^0 P_l^0(cos θ) for m = 0 and
√2 K_l^m P_l^m(cos θ) cos(m φ) for m > 0, with the Condon–Shortley phase in P (hence the minus signs of the odd m),
K_l^m = sqrt((2l + 1) / (4π) · (l - |m|)! / (l + |m|)!), written as polynomials of the unit direction (x, y, z).

The constants are these normalisations as closed forms, evaluated to 50 digits (mpmath) and rounded to the nearest
double; the tests check each against its closed form. graphdeco's ``utils/sh_utils.py`` (and the copies this
module replaced) carried four of them one unit in the last place off (C2[2], C3[1], C3[2]/C3[4], C3[5]).

The functions are plain arithmetic on their arguments, so the same code serves numpy arrays, torch tensors
(autograd included) and, compiled by numba, scalars (:mod:`fusion.render.project_cpu`). No torch import here:
:mod:`fusion.gltf_splats` and the brute-force oracle use it without torch.
"""

from __future__ import annotations

from typing import Any

SH_C0 = 0.28209479177387814
"""sqrt(1 / (4π)): degree 0."""
SH_C1 = 0.4886025119029199
"""sqrt(3 / (4π)): degree 1, Y = (-C1 y, C1 z, -C1 x)."""
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252, -1.0925484305920792, 0.5462742152960396)
"""Degree 2: sqrt(15 / (4π)) xy, -sqrt(15 / (4π)) yz, sqrt(5 / (16π)) (2z² - x² - y²), -sqrt(15 / (4π)) xz,
sqrt(15 / (16π)) (x² - y²)."""
SH_C3 = (
    -0.5900435899266435,
    2.8906114426405543,
    -0.4570457994644657,
    0.3731763325901154,
    -0.4570457994644657,
    1.4453057213202771,
    -0.5900435899266435,
)
"""Degree 3: -sqrt(35 / (32π)) y (3x² - y²), sqrt(105 / (4π)) xyz, -sqrt(21 / (32π)) y (4z² - x² - y²),
sqrt(7 / (16π)) z (2z² - 3x² - 3y²), -sqrt(21 / (32π)) x (4z² - x² - y²), sqrt(105 / (16π)) z (x² - y²),
-sqrt(35 / (32π)) x (x² - 3y²)."""

_C2_0, _C2_1, _C2_2, _C2_3, _C2_4 = SH_C2
_C3_0, _C3_1, _C3_2, _C3_3, _C3_4, _C3_5, _C3_6 = SH_C3


def sh_basis_into(degree: int, x: Any, y: Any, z: Any, out: Any) -> None:
    """Write Y_k(x, y, z), k < (degree + 1)², into ``out[k]``, for a unit direction (x, y, z).

    x, y, z: floats or arrays (numpy, torch) of one shape; out: anything indexable by k that takes their values
    (a (16,) float64 array in numba, a ((degree + 1)², M) numpy array, a list). out[0] is set to the float
    ``SH_C0`` (broadcast it if the caller needs an array). degree must be 0..3 (not checked: numba calls it per
    Gaussian).
    """
    out[0] = SH_C0
    if degree >= 1:
        out[1] = -SH_C1 * y
        out[2] = SH_C1 * z
        out[3] = -SH_C1 * x
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out[4] = _C2_0 * x * y
        out[5] = _C2_1 * y * z
        out[6] = _C2_2 * (2.0 * zz - xx - yy)
        out[7] = _C2_3 * x * z
        out[8] = _C2_4 * (xx - yy)
        if degree >= 3:
            out[9] = _C3_0 * y * (3.0 * xx - yy)
            out[10] = _C3_1 * x * y * z
            out[11] = _C3_2 * y * (4.0 * zz - xx - yy)
            out[12] = _C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
            out[13] = _C3_4 * x * (4.0 * zz - xx - yy)
            out[14] = _C3_5 * z * (xx - yy)
            out[15] = _C3_6 * x * (xx - 3.0 * yy)


def sh_basis_grad(degree: int, x: Any, y: Any, z: Any, w: Any) -> tuple[Any, Any, Any]:
    """Σ_k w[k] ∇Y_k at (x, y, z): the gradient with respect to the direction's components, held independent
    (the polynomials' derivatives, for the numba backward; autograd differentiates :func:`sh_basis_into`)."""
    gx = 0.0
    gy = 0.0
    gz = 0.0
    if degree >= 1:
        gy -= SH_C1 * w[1]
        gz += SH_C1 * w[2]
        gx -= SH_C1 * w[3]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        gx += _C2_0 * y * w[4]
        gy += _C2_0 * x * w[4]
        gy += _C2_1 * z * w[5]
        gz += _C2_1 * y * w[5]
        gx -= 2.0 * _C2_2 * x * w[6]
        gy -= 2.0 * _C2_2 * y * w[6]
        gz += 4.0 * _C2_2 * z * w[6]
        gx += _C2_3 * z * w[7]
        gz += _C2_3 * x * w[7]
        gx += 2.0 * _C2_4 * x * w[8]
        gy -= 2.0 * _C2_4 * y * w[8]
        if degree >= 3:
            gx += _C3_0 * 6.0 * x * y * w[9]
            gy += _C3_0 * (3.0 * xx - 3.0 * yy) * w[9]
            gx += _C3_1 * y * z * w[10]
            gy += _C3_1 * x * z * w[10]
            gz += _C3_1 * x * y * w[10]
            gx -= _C3_2 * 2.0 * x * y * w[11]
            gy += _C3_2 * (4.0 * zz - xx - 3.0 * yy) * w[11]
            gz += _C3_2 * 8.0 * y * z * w[11]
            gx -= _C3_3 * 6.0 * x * z * w[12]
            gy -= _C3_3 * 6.0 * y * z * w[12]
            gz += _C3_3 * (6.0 * zz - 3.0 * xx - 3.0 * yy) * w[12]
            gx += _C3_4 * (4.0 * zz - 3.0 * xx - yy) * w[13]
            gy -= _C3_4 * 2.0 * x * y * w[13]
            gz += _C3_4 * 8.0 * x * z * w[13]
            gx += _C3_5 * 2.0 * x * z * w[14]
            gy -= _C3_5 * 2.0 * y * z * w[14]
            gz += _C3_5 * (xx - yy) * w[14]
            gx += _C3_6 * (3.0 * xx - 3.0 * yy) * w[15]
            gy -= _C3_6 * 6.0 * x * y * w[15]
    return gx, gy, gz
