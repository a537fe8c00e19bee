"""Projection, SH colour and opacity of 3D Gaussians in numba, with a hand-written backward (the ``cpu`` backend).

The same maths as :func:`fusion.render.projection.project_gaussians`, :func:`fusion.render.sh.sh_to_colour` and a
sigmoid, which stay as the readable autograd twins (the ``reference`` backend uses them, the tests compare against
them and gsplat's PyTorch projection). Written by hand because the PyTorch version is ~60 small tensor operations
forward and as many backward, whose per-call overhead and memory traffic dominated a training step at 50 k
Gaussians; here one pass per Gaussian does everything, forward and backward, on both cores.

Every Gaussian is computed in float64 whatever the input dtype (outputs and gradients are returned in the input
dtype), with the clamps of the twin: Jacobian at the mean clamped to 1.3× the field of view, determinant clamped
to 1e-12, culled Gaussians (behind the near plane) projected with z = 1 so that everything stays finite.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from numba import njit
from torch.autograd.function import once_differentiable

from fusion.render.sh_basis import sh_basis_grad, sh_basis_into
from fusion.render.threads import run_threads
from fusion.render.types import EPS2D, EXTENT_SIGMA, NEAR_PLANE


@dataclass(frozen=True)
class ProjectedSplats:
    """Screen-space Gaussians of one camera with their colours and opacities (N rows, dtype of the inputs).

    means2d (N, 2) px, conics (N, 3) (a, b, c) as in :class:`fusion.render.projection.Projection`, depths (N,)
    camera z (m), colours (N, 3) RGB ``max(SH + 0.5, 0)``, opacities (N,) sigmoid of the logits: differentiable.
    extents (N, 2) px (3σ box half-widths) and visible (N,) bool: detached.
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    colours: torch.Tensor
    opacities: torch.Tensor
    extents: torch.Tensor
    visible: torch.Tensor


def _camera_vector(viewmat: torch.Tensor, K: torch.Tensor) -> np.ndarray:
    """(16,) float64: R row-major (9), t (3), fx, fy, cx, cy."""
    vm = viewmat.detach().cpu().double().numpy()
    k = K.detach().cpu().double().numpy()
    return np.concatenate([vm[:3, :3].reshape(-1), vm[:3, 3], [k[0, 0], k[1, 1], k[0, 2], k[1, 2]]])


@njit(inline="always", cache=True)
def _limits(cam, width, height):  # pragma: no cover - numba
    fx, fy, cx, cy = cam[12], cam[13], cam[14], cam[15]
    lim_x_pos = (width - cx) / fx + 0.3 * (0.5 * width / fx)
    lim_x_neg = cx / fx + 0.3 * (0.5 * width / fx)
    lim_y_pos = (height - cy) / fy + 0.3 * (0.5 * height / fy)
    lim_y_neg = cy / fy + 0.3 * (0.5 * height / fy)
    return lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg


@njit(inline="always", cache=True)
def _rotation(qw, qx, qy, qz):  # pragma: no cover - numba
    """Rotation matrix (row-major 9-tuple) of the unit quaternion (w, x, y, z)."""
    return (
        1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy - qw * qz), 2.0 * (qx * qz + qw * qy),
        2.0 * (qx * qy + qw * qz), 1.0 - 2.0 * (qx * qx + qz * qz), 2.0 * (qy * qz - qw * qx),
        2.0 * (qx * qz - qw * qy), 2.0 * (qy * qz + qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy),
    )  # fmt: skip


# The one SH basis (fusion/render/sh_basis.py), compiled for scalars.
_sh_basis = njit(inline="always", cache=True)(sh_basis_into)
_sh_basis_grad = njit(inline="always", cache=True)(sh_basis_grad)


@njit(nogil=True, cache=True)
def _forward_kernel(
    means, quats, log_scales, logits, sh_dc, sh_rest, degree, cam, width, height, near, eps2d, extent_sigma,
    th, n_threads,
    means2d, conics, depths, extents, visible, colours, opacities,
):  # pragma: no cover - numba  # fmt: skip
    n = means.shape[0]
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = cam[0], cam[1], cam[2], cam[3], cam[4], cam[5], cam[6], cam[7], cam[8]
    t0, t1, t2 = cam[9], cam[10], cam[11]
    fx, fy, cx, cy = cam[12], cam[13], cam[14], cam[15]
    # Camera centre -Rᵀ t (for the SH view directions).
    c0 = -(r00 * t0 + r10 * t1 + r20 * t2)
    c1 = -(r01 * t0 + r11 * t1 + r21 * t2)
    c2 = -(r02 * t0 + r12 * t1 + r22 * t2)
    lxp, lxn, lyp, lyn = _limits(cam, width, height)
    basis = np.empty(16, np.float64)
    for i in range(n * th // n_threads, n * (th + 1) // n_threads):
        mx, my, mz = np.float64(means[i, 0]), np.float64(means[i, 1]), np.float64(means[i, 2])
        x = r00 * mx + r01 * my + r02 * mz + t0
        y = r10 * mx + r11 * my + r12 * mz + t1
        z = r20 * mx + r21 * my + r22 * mz + t2
        in_front = z > near
        zs = z if in_front else 1.0
        u = fx * x / zs + cx
        v = fy * y / zs + cy
        tx = zs * min(max(x / zs, -lxn), lxp)
        ty = zs * min(max(y / zs, -lyn), lyp)
        j00 = fx / zs
        j02 = -fx * tx / (zs * zs)
        j11 = fy / zs
        j12 = -fy * ty / (zs * zs)

        qw, qx, qy, qz = np.float64(quats[i, 0]), np.float64(quats[i, 1]), np.float64(quats[i, 2]), quats[i, 3]
        qinv = 1.0 / max(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-12)
        q00, q01, q02, q10, q11, q12, q20, q21, q22 = _rotation(qw * qinv, qx * qinv, qy * qinv, qz * qinv)
        s0 = math.exp(log_scales[i, 0])
        s1 = math.exp(log_scales[i, 1])
        s2 = math.exp(log_scales[i, 2])
        # M = R_view R_q S; jm0 = j00 M[0] + j02 M[2], jm1 = j11 M[1] + j12 M[2].
        m00 = (r00 * q00 + r01 * q10 + r02 * q20) * s0
        m01 = (r00 * q01 + r01 * q11 + r02 * q21) * s1
        m02 = (r00 * q02 + r01 * q12 + r02 * q22) * s2
        m10 = (r10 * q00 + r11 * q10 + r12 * q20) * s0
        m11 = (r10 * q01 + r11 * q11 + r12 * q21) * s1
        m12 = (r10 * q02 + r11 * q12 + r12 * q22) * s2
        m20 = (r20 * q00 + r21 * q10 + r22 * q20) * s0
        m21 = (r20 * q01 + r21 * q11 + r22 * q21) * s1
        m22 = (r20 * q02 + r21 * q12 + r22 * q22) * s2
        a0, a1, a2 = j00 * m00 + j02 * m20, j00 * m01 + j02 * m21, j00 * m02 + j02 * m22
        b0, b1, b2 = j11 * m10 + j12 * m20, j11 * m11 + j12 * m21, j11 * m12 + j12 * m22
        sxx = a0 * a0 + a1 * a1 + a2 * a2 + eps2d
        sxy = a0 * b0 + a1 * b1 + a2 * b2
        syy = b0 * b0 + b1 * b1 + b2 * b2 + eps2d
        det = max(sxx * syy - sxy * sxy, 1e-12)
        means2d[i, 0] = u
        means2d[i, 1] = v
        conics[i, 0] = syy / det
        conics[i, 1] = -sxy / det
        conics[i, 2] = sxx / det
        depths[i] = z
        ex = extent_sigma * math.sqrt(sxx)
        ey = extent_sigma * math.sqrt(syy)
        extents[i, 0] = ex
        extents[i, 1] = ey
        visible[i] = (
            in_front
            and (u + ex > 0.0)
            and (u - ex < width)
            and (v + ey > 0.0)
            and (v - ey < height)
            and math.isfinite(u)
            and math.isfinite(v)
        )

        dx, dy, dz = mx - c0, my - c1, mz - c2
        dinv = 1.0 / max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
        _sh_basis(degree, dx * dinv, dy * dinv, dz * dinv, basis)
        for ch in range(3):
            acc = basis[0] * sh_dc[i, 0, ch]
            for k in range(1, (degree + 1) * (degree + 1)):
                acc += basis[k] * sh_rest[i, k - 1, ch]
            colours[i, ch] = max(acc + 0.5, 0.0)
        opacities[i] = 1.0 / (1.0 + math.exp(-np.float64(logits[i])))


@njit(nogil=True, cache=True)
def _backward_kernel(
    means, quats, log_scales, logits, sh_dc, sh_rest, degree, cam, width, height, near, eps2d,
    g_means2d, g_conics, g_depths, g_colours, g_opacities,
    th, n_threads,
    g_means, g_quats, g_log_scales, g_logits, g_sh_dc, g_sh_rest,
):  # pragma: no cover - numba  # fmt: skip
    n = means.shape[0]
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = cam[0], cam[1], cam[2], cam[3], cam[4], cam[5], cam[6], cam[7], cam[8]
    t0, t1, t2 = cam[9], cam[10], cam[11]
    fx, fy = cam[12], cam[13]
    c0 = -(r00 * t0 + r10 * t1 + r20 * t2)
    c1 = -(r01 * t0 + r11 * t1 + r21 * t2)
    c2 = -(r02 * t0 + r12 * t1 + r22 * t2)
    lxp, lxn, lyp, lyn = _limits(cam, width, height)
    basis = np.empty(16, np.float64)
    g_basis = np.empty(16, np.float64)
    n_coeffs = (degree + 1) * (degree + 1)
    for i in range(n * th // n_threads, n * (th + 1) // n_threads):
        # -- forward again (cheap, and exact) -------------------------------------------------------------
        mx, my, mz = np.float64(means[i, 0]), np.float64(means[i, 1]), np.float64(means[i, 2])
        x = r00 * mx + r01 * my + r02 * mz + t0
        y = r10 * mx + r11 * my + r12 * mz + t1
        z = r20 * mx + r21 * my + r22 * mz + t2
        in_front = z > near
        zs = z if in_front else 1.0
        rx = x / zs
        ry = y / zs
        rxc = min(max(rx, -lxn), lxp)
        ryc = min(max(ry, -lyn), lyp)
        tx = zs * rxc
        ty = zs * ryc
        zz2 = zs * zs
        j00 = fx / zs
        j02 = -fx * tx / zz2
        j11 = fy / zs
        j12 = -fy * ty / zz2

        qw, qx, qy, qz = np.float64(quats[i, 0]), np.float64(quats[i, 1]), np.float64(quats[i, 2]), quats[i, 3]
        qnorm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qinv = 1.0 / max(qnorm, 1e-12)
        nw, nx, ny, nz = qw * qinv, qx * qinv, qy * qinv, qz * qinv
        q00, q01, q02, q10, q11, q12, q20, q21, q22 = _rotation(nw, nx, ny, nz)
        s0 = math.exp(log_scales[i, 0])
        s1 = math.exp(log_scales[i, 1])
        s2 = math.exp(log_scales[i, 2])
        # A = R_view R_q; M = A S.
        A00, A01, A02 = (
            r00 * q00 + r01 * q10 + r02 * q20,
            r00 * q01 + r01 * q11 + r02 * q21,
            r00 * q02 + r01 * q12 + r02 * q22,
        )
        A10, A11, A12 = (
            r10 * q00 + r11 * q10 + r12 * q20,
            r10 * q01 + r11 * q11 + r12 * q21,
            r10 * q02 + r11 * q12 + r12 * q22,
        )
        A20, A21, A22 = (
            r20 * q00 + r21 * q10 + r22 * q20,
            r20 * q01 + r21 * q11 + r22 * q21,
            r20 * q02 + r21 * q12 + r22 * q22,
        )  # noqa: E501
        m00, m01, m02 = A00 * s0, A01 * s1, A02 * s2
        m10, m11, m12 = A10 * s0, A11 * s1, A12 * s2
        m20, m21, m22 = A20 * s0, A21 * s1, A22 * s2
        a0, a1, a2 = j00 * m00 + j02 * m20, j00 * m01 + j02 * m21, j00 * m02 + j02 * m22
        b0, b1, b2 = j11 * m10 + j12 * m20, j11 * m11 + j12 * m21, j11 * m12 + j12 * m22
        sxx = a0 * a0 + a1 * a1 + a2 * a2 + eps2d
        sxy = a0 * b0 + a1 * b1 + a2 * b2
        syy = b0 * b0 + b1 * b1 + b2 * b2 + eps2d
        det_raw = sxx * syy - sxy * sxy
        det = max(det_raw, 1e-12)

        # -- conics -> 2D covariance -------------------------------------------------------------------------
        ga, gb, gc = np.float64(g_conics[i, 0]), np.float64(g_conics[i, 1]), np.float64(g_conics[i, 2])
        g_sxx = gc / det
        g_syy = ga / det
        g_sxy = -gb / det
        if det_raw >= 1e-12:
            g_det = -(ga * syy - gb * sxy + gc * sxx) / (det * det)
            g_sxx += g_det * syy
            g_syy += g_det * sxx
            g_sxy -= 2.0 * g_det * sxy
        # Σ2d = (a·a, a·b, b·b) with a = J M row 0, b = row 1.
        ga0, ga1, ga2 = 2.0 * g_sxx * a0 + g_sxy * b0, 2.0 * g_sxx * a1 + g_sxy * b1, 2.0 * g_sxx * a2 + g_sxy * b2
        gb0, gb1, gb2 = 2.0 * g_syy * b0 + g_sxy * a0, 2.0 * g_syy * b1 + g_sxy * a1, 2.0 * g_syy * b2 + g_sxy * a2
        g_j00 = ga0 * m00 + ga1 * m01 + ga2 * m02
        g_j02 = ga0 * m20 + ga1 * m21 + ga2 * m22
        g_j11 = gb0 * m10 + gb1 * m11 + gb2 * m12
        g_j12 = gb0 * m20 + gb1 * m21 + gb2 * m22
        gm00, gm01, gm02 = j00 * ga0, j00 * ga1, j00 * ga2
        gm10, gm11, gm12 = j11 * gb0, j11 * gb1, j11 * gb2
        gm20, gm21, gm22 = j02 * ga0 + j12 * gb0, j02 * ga1 + j12 * gb1, j02 * ga2 + j12 * gb2
        # M = A S: scales, then A = R_view R_q -> g_Rq = R_viewᵀ g_A.
        g_log_scales[i, 0] = (gm00 * A00 + gm10 * A10 + gm20 * A20) * s0
        g_log_scales[i, 1] = (gm01 * A01 + gm11 * A11 + gm21 * A21) * s1
        g_log_scales[i, 2] = (gm02 * A02 + gm12 * A12 + gm22 * A22) * s2
        gA00, gA01, gA02 = gm00 * s0, gm01 * s1, gm02 * s2
        gA10, gA11, gA12 = gm10 * s0, gm11 * s1, gm12 * s2
        gA20, gA21, gA22 = gm20 * s0, gm21 * s1, gm22 * s2
        G00 = r00 * gA00 + r10 * gA10 + r20 * gA20
        G01 = r00 * gA01 + r10 * gA11 + r20 * gA21
        G02 = r00 * gA02 + r10 * gA12 + r20 * gA22
        G10 = r01 * gA00 + r11 * gA10 + r21 * gA20
        G11 = r01 * gA01 + r11 * gA11 + r21 * gA21
        G12 = r01 * gA02 + r11 * gA12 + r21 * gA22
        G20 = r02 * gA00 + r12 * gA10 + r22 * gA20
        G21 = r02 * gA01 + r12 * gA11 + r22 * gA21
        G22 = r02 * gA02 + r12 * gA12 + r22 * gA22
        gnw = 2.0 * (-nz * G01 + ny * G02 + nz * G10 - nx * G12 - ny * G20 + nx * G21)
        gnx = 2.0 * (ny * G01 + nz * G02 + ny * G10 - 2.0 * nx * G11 - nw * G12 + nz * G20 + nw * G21 - 2.0 * nx * G22)
        gny = 2.0 * (-2.0 * ny * G00 + nx * G01 + nw * G02 + nx * G10 + nz * G12 - nw * G20 + nz * G21 - 2.0 * ny * G22)
        gnz = 2.0 * (-2.0 * nz * G00 - nw * G01 + nx * G02 + nw * G10 - 2.0 * nz * G11 + ny * G12 + nx * G20 + ny * G21)
        if qnorm >= 1e-12:  # d(q/|q|) = (I - n nᵀ) / |q|
            dot = nw * gnw + nx * gnx + ny * gny + nz * gnz
            gnw, gnx, gny, gnz = gnw - nw * dot, gnx - nx * dot, gny - ny * dot, gnz - nz * dot
        g_quats[i, 0] = gnw * qinv
        g_quats[i, 1] = gnx * qinv
        g_quats[i, 2] = gny * qinv
        g_quats[i, 3] = gnz * qinv

        # -- Jacobian and mean ------------------------------------------------------------------------------
        gu, gv = np.float64(g_means2d[i, 0]), np.float64(g_means2d[i, 1])
        g_zs = -g_j00 * fx / zz2 - g_j11 * fy / zz2
        g_zs += 2.0 * (g_j02 * fx * tx + g_j12 * fy * ty) / (zz2 * zs)
        g_tx = -g_j02 * fx / zz2
        g_ty = -g_j12 * fy / zz2
        g_zs += g_tx * rxc + g_ty * ryc
        g_rx = g_tx * zs if (rx >= -lxn) and (rx <= lxp) else 0.0
        g_ry = g_ty * zs if (ry >= -lyn) and (ry <= lyp) else 0.0
        g_x = (g_rx + gu * fx) / zs
        g_y = (g_ry + gv * fy) / zs
        g_zs -= (g_rx + gu * fx) * x / zz2 + (g_ry + gv * fy) * y / zz2
        g_z = np.float64(g_depths[i]) + (g_zs if in_front else 0.0)
        gmx = r00 * g_x + r10 * g_y + r20 * g_z
        gmy = r01 * g_x + r11 * g_y + r21 * g_z
        gmz = r02 * g_x + r12 * g_y + r22 * g_z

        # -- SH colour ----------------------------------------------------------------------------------------
        dx, dy, dz = mx - c0, my - c1, mz - c2
        dnorm = math.sqrt(dx * dx + dy * dy + dz * dz)
        dinv = 1.0 / max(dnorm, 1e-12)
        ux, uy, uz = dx * dinv, dy * dinv, dz * dinv
        _sh_basis(degree, ux, uy, uz, basis)
        g_basis[:] = 0.0
        for ch in range(3):
            acc = basis[0] * sh_dc[i, 0, ch]
            for k in range(1, n_coeffs):
                acc += basis[k] * sh_rest[i, k - 1, ch]
            g = np.float64(g_colours[i, ch]) if acc + 0.5 >= 0.0 else 0.0
            g_sh_dc[i, 0, ch] = g * basis[0]
            for k in range(1, n_coeffs):
                g_sh_rest[i, k - 1, ch] = g * basis[k]
                g_basis[k] += g * sh_rest[i, k - 1, ch]
        if degree >= 1:
            gux, guy, guz = _sh_basis_grad(degree, ux, uy, uz, g_basis)
            if dnorm >= 1e-12:  # d(d/|d|) = (I - u uᵀ) / |d|
                dot = ux * gux + uy * guy + uz * guz
                gux, guy, guz = gux - ux * dot, guy - uy * dot, guz - uz * dot
            gmx += gux * dinv
            gmy += guy * dinv
            gmz += guz * dinv
        g_means[i, 0] = gmx
        g_means[i, 1] = gmy
        g_means[i, 2] = gmz

        o = 1.0 / (1.0 + math.exp(-np.float64(logits[i])))
        g_logits[i] = np.float64(g_opacities[i]) * o * (1.0 - o)


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy())


class _ProjectCPU(torch.autograd.Function):
    """(means, quats, log_scales, logits, sh_dc, sh_rest) -> (means2d, conics, depths, colours, opacities,
    extents, visible); the last two are not differentiable."""

    @staticmethod
    def forward(ctx, means, quats, log_scales, logits, sh_dc, sh_rest, cam, width, height, degree, near, eps2d):  # type: ignore[override]
        dtype = means.dtype
        n = means.shape[0]
        ins = (_np(means), _np(quats), _np(log_scales), _np(logits), _np(sh_dc), _np(sh_rest))
        np_dtype = ins[0].dtype
        outs = (
            np.empty((n, 2), np_dtype),
            np.empty((n, 3), np_dtype),
            np.empty(n, np_dtype),
            np.empty((n, 2), np_dtype),
            np.empty(n, np.bool_),
            np.empty((n, 3), np_dtype),
            np.empty(n, np_dtype),
        )
        if n:
            args = (*ins, degree, cam, float(width), float(height), float(near), float(eps2d), EXTENT_SIGMA)
            run_threads(_forward_kernel, args, outs, "project fwd")
        ctx.ins = ins
        ctx.config = (degree, cam, float(width), float(height), float(near), float(eps2d))
        means2d, conics, depths, extents, visible, colours, opacities = (torch.from_numpy(a) for a in outs)
        ctx.mark_non_differentiable(extents, visible)
        ctx.dtype = dtype
        return means2d, conics, depths, colours, opacities, extents, visible

    @staticmethod
    @once_differentiable
    def backward(ctx, g_means2d, g_conics, g_depths, g_colours, g_opacities, _g_extents, _g_visible):  # type: ignore[override]
        ins = ctx.ins
        np_dtype = ins[0].dtype
        n = ins[0].shape[0]
        grads_in = tuple(
            np.ascontiguousarray(g.numpy(), np_dtype) for g in (g_means2d, g_conics, g_depths, g_colours, g_opacities)
        )
        outs = (
            np.empty((n, 3), np_dtype),
            np.empty((n, 4), np_dtype),
            np.empty((n, 3), np_dtype),
            np.empty(n, np_dtype),
            np.empty(ins[4].shape, np_dtype),
            np.zeros(ins[5].shape, np_dtype),
        )
        if n:
            run_threads(_backward_kernel, (*ins, *ctx.config, *grads_in), outs, "project bwd")
        return (*(torch.from_numpy(a) for a in outs), None, None, None, None, None, None)


def project_splats_cpu(
    means: torch.Tensor,
    quats: torch.Tensor,
    log_scales: torch.Tensor,
    logit_opacities: torch.Tensor,
    sh_dc: torch.Tensor,
    sh_rest: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    sh_degree: int,
    *,
    near_plane: float = NEAR_PLANE,
    eps2d: float = EPS2D,
) -> ProjectedSplats:
    """Project N Gaussians and evaluate their colours and opacities in one numba pass (both cores), differentiably.

    means (N, 3) in the frame of ``viewmat`` (4×4 world-to-camera, OpenCV axes), quats (N, 4) wxyz unnormalised,
    log_scales (N, 3) log σ, logit_opacities (N,), sh_dc (N, 1, 3), sh_rest (N, K - 1, 3) with
    K ≥ (sh_degree + 1)² (coefficients beyond the degree are ignored and get zero gradient), K (3, 3) pinhole with
    pixel centres at +0.5. All parameter tensors share one float dtype; outputs and gradients are in it.
    Equals ``project_gaussians`` + ``sh_to_colour(cat(sh_dc, sh_rest), means - camera centre, sh_degree)`` +
    ``sigmoid(logit_opacities)``.
    """
    if not 0 <= sh_degree <= 3 or sh_rest.shape[1] < (sh_degree + 1) ** 2 - 1:
        raise ValueError(f"SH degree {sh_degree} needs {(sh_degree + 1) ** 2} coefficients, got {sh_rest.shape[1] + 1}")
    cam = _camera_vector(viewmat, K)
    outs = _ProjectCPU.apply(
        means, quats, log_scales, logit_opacities, sh_dc, sh_rest, cam, width, height, sh_degree, near_plane, eps2d
    )
    means2d, conics, depths, colours, opacities, extents, visible = outs
    return ProjectedSplats(means2d, conics, depths, colours, opacities, extents, visible)
