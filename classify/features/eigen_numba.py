"""Covariance eigen analysis of k-NN neighbourhoods as a threaded numba kernel (the fast backend).

Written by hand because the libraries do not fit: pgeof 0.3.4's ``compute_features`` disagrees with LAPACK on
the middle eigenvalue on near-planar neighbourhoods (its λ1 and normal agree), and jakteristics only searches fixed
radii (no k-NN lists) and is slower here (figures in docs/experiments/2026-11-27-domain-defaults.md).
The kernel computes each covariance in float64 about the neighbourhood mean, its eigenvalues in closed form
(trigonometric solution of the characteristic cubic, Smith 1961) and the normal as the eigenvector of the
smallest eigenvalue (largest cross product of two rows of C − λ3·I). ``eigen_numpy`` is its twin in the tests.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _eig3(c00, c01, c02, c11, c12, c22, out_w, out_n):  # pragma: no cover - compiled
    p1 = c01 * c01 + c02 * c02 + c12 * c12
    q = (c00 + c11 + c22) / 3.0
    if p1 <= 1e-300:
        a, b, c = c00, c11, c22
        # Diagonal: sort descending; normal is the axis of the smallest.
        w = [a, b, c]
        order = [0, 1, 2]
        for i in range(3):
            for j in range(2 - i):
                if w[order[j]] < w[order[j + 1]]:
                    order[j], order[j + 1] = order[j + 1], order[j]
        out_w[0], out_w[1], out_w[2] = w[order[0]], w[order[1]], w[order[2]]
        out_n[0] = out_n[1] = out_n[2] = 0.0
        out_n[order[2]] = 1.0
        return
    p2 = (c00 - q) ** 2 + (c11 - q) ** 2 + (c22 - q) ** 2 + 2.0 * p1
    p = math.sqrt(p2 / 6.0)
    b00, b11, b22 = (c00 - q) / p, (c11 - q) / p, (c22 - q) / p
    b01, b02, b12 = c01 / p, c02 / p, c12 / p
    det = b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)
    r = det / 2.0
    r = min(1.0, max(-1.0, r))
    phi = math.acos(r) / 3.0
    w1 = q + 2.0 * p * math.cos(phi)
    w3 = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    w2 = 3.0 * q - w1 - w3
    out_w[0], out_w[1], out_w[2] = w1, w2, w3
    # Eigenvector of w3: the largest cross product of two rows of (C - w3 I).
    r0 = (c00 - w3, c01, c02)
    r1 = (c01, c11 - w3, c12)
    r2 = (c02, c12, c22 - w3)
    best = -1.0
    for a_, b_ in ((r0, r1), (r0, r2), (r1, r2)):
        x = a_[1] * b_[2] - a_[2] * b_[1]
        y = a_[2] * b_[0] - a_[0] * b_[2]
        z = a_[0] * b_[1] - a_[1] * b_[0]
        m = x * x + y * y + z * z
        if m > best:
            best = m
            out_n[0], out_n[1], out_n[2] = x, y, z
    if best > 0:
        s = 1.0 / math.sqrt(best)
        out_n[0] *= s
        out_n[1] *= s
        out_n[2] *= s
    else:
        out_n[0], out_n[1], out_n[2] = 0.0, 0.0, 1.0


@numba.njit(parallel=True, cache=True, nogil=True)
def _eigen_kernel(points, neighbours, with_self, offset, values, normals):  # pragma: no cover - compiled
    n, m = neighbours.shape
    k = m + 1 if with_self else m
    first = -1 if with_self else 0  # j = -1 stands for the point itself
    for i in numba.prange(n):
        mx = my = mz = 0.0
        for j in range(first, m):
            t = offset + i if j < 0 else neighbours[i, j]
            mx += points[t, 0]
            my += points[t, 1]
            mz += points[t, 2]
        mx /= k
        my /= k
        mz /= k
        c00 = c01 = c02 = c11 = c12 = c22 = 0.0
        for j in range(first, m):
            t = offset + i if j < 0 else neighbours[i, j]
            dx = points[t, 0] - mx
            dy = points[t, 1] - my
            dz = points[t, 2] - mz
            c00 += dx * dx
            c01 += dx * dy
            c02 += dx * dz
            c11 += dy * dy
            c12 += dy * dz
            c22 += dz * dz
        _eig3(c00 / k, c01 / k, c02 / k, c11 / k, c12 / k, c22 / k, values[i], normals[i])
        for j in range(3):
            if values[i, j] < 0.0:
                values[i, j] = 0.0


def eigen_numba(
    points: np.ndarray, neighbours: np.ndarray, with_self: bool = False, offset: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (N, 3) descending (metres², covariance divided by k) and smallest-eigenvector normals (N, 3)
    of ``points`` (M, 3) float64 over ``neighbours`` (N, k) int64; same contract as ``eigen_numpy`` (with_self:
    row i's own point ``offset + i`` belongs to its neighbourhood too, without being listed)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    nb = np.ascontiguousarray(neighbours, dtype=np.int64)
    values = np.empty((len(nb), 3))
    normals = np.empty((len(nb), 3))
    _eigen_kernel(pts, nb, bool(with_self), int(offset), values, normals)
    return values, normals


@numba.njit(parallel=True, cache=True, nogil=True)
def _smooth_rows_kernel(p, nb, out):  # pragma: no cover - compiled
    n, m = nb.shape
    c = p.shape[1]
    for i in numba.prange(n):
        for j in range(c):
            out[i, j] = p[i, j]
        for t in range(m):
            q = nb[i, t]
            for j in range(c):
                out[i, j] += p[q, j]
        for j in range(c):
            out[i, j] /= m + 1


def smooth_rows(p: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Per row i of ``p`` (N, C) float32: the mean of rows i and ``neighbours[i]`` ((N, m) int64), (N, C) float32."""
    out = np.empty_like(p)
    _smooth_rows_kernel(p, neighbours, out)
    return out
