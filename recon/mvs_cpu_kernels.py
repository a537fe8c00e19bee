"""The numba kernels of the CPU MVS (see :mod:`recon.mvs_cpu` for the method): matching cost and normals.

``ncc_costs`` fuses, per hypothesis and band of rows, what the torch version did in separate passes over
(sources × hypotheses × H × W) tensors: the warp of every source through each pixel's own inverse-depth hypothesis
(bilinear, zeros outside the source, as ``torch.nn.functional.grid_sample`` with ``align_corners=False``), the
(2r+1)² box sums of x, x² and x·ref (row sums into a ring of 2r + 2 rows, column sums sliding down the band, all in
float64 and in the cache), the zero-mean NCC against the reference's window statistics and the mean of the
``best_k`` lowest source costs. Work is split into interleaved (hypothesis, band) tasks over Python threads
(GIL-free kernels that block rather than spin on shared cores).

``plane_normals`` fits a plane to each window's points from float64 moments and takes the normal in closed form.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from core.knn.threads import run_threads

INVALID_COST = 2.0
"""Cost of a pixel whose warp leaves the source or whose warped window is flat (the NCC cost spans 0..2)."""

_BAND_ROWS = 128
"""Rows per band, about: a band warps r halo rows a side more, and its sums start afresh. Bands depend on the image
height only, so the costs are the same bits with any number of threads."""

_CHUNKS_PER_THREAD = 4
"""Shares of the cost tasks per thread, handed out as threads come free (a core taken by another process then
delays one share, not half of the work)."""

_POOL: list[ThreadPoolExecutor] = []


@numba.njit(nogil=True, cache=True)
def _warp_row(srcs, src_hw, P, q, inv, b, s, i, u, v, x, valid):  # pragma: no cover - numba
    """Source s sampled through hypothesis b at the pixels of row i into x[r : r + W] (x has r zero columns a side);
    valid (W,) = whole bilinear stencil inside the source.

    srcs carry a one-pixel zero border, so every stencil that touches the image reads zeros outside it. u, v: (W,)
    scratch for the row's source coordinates (a loop of their own: it vectorises).
    """
    hs = src_hw[s, 0]
    ws = src_hw[s, 1]
    q0, q1, q2 = np.float64(q[s, 0]), np.float64(q[s, 1]), np.float64(q[s, 2])
    img = srcs[s]
    w = inv.shape[2]
    radius = (x.shape[0] - w) // 2
    inv_row = inv[b, i]
    p0 = P[s, 0, i]
    p1 = P[s, 1, i]
    p2 = P[s, 2, i]
    for j in range(w):
        iv = max(np.float64(inv_row[j]), 1e-8)
        z = p2[j] + q2 * iv
        rz = 1.0 / max(z, 1e-9)
        u[j] = (p0[j] + q0 * iv) * rz
        v[j] = (p1[j] + q1 * iv) * rz
        valid[j] = z > 1e-9 and u[j] >= 0.5 and v[j] >= 0.5 and u[j] <= ws - 0.5 and v[j] <= hs - 0.5
    for j in range(w):
        uj = u[j]
        vj = v[j]
        value = 0.0
        if uj > -0.5 and vj > -0.5 and uj < ws + 0.5 and vj < hs + 0.5:  # also false for NaN
            gx = uj + 0.5  # index in the bordered image: pixel centre c of the source at c + 1
            gy = vj + 0.5
            ix = int(gx)
            iy = int(gy)
            fx = gx - ix
            fy = gy - iy
            top = img[iy, ix] + fx * (img[iy, ix + 1] - img[iy, ix])
            bottom = img[iy + 1, ix] + fx * (img[iy + 1, ix + 1] - img[iy + 1, ix])
            value = top + fy * (bottom - top)
        x[radius + j] = value


@numba.njit(nogil=True, cache=True)
def _row_sums(x, ref_row, hx, hxx, hxr):  # pragma: no cover - numba
    """hx[j], hxx[j], hxr[j] = sums of x, x², x·ref over columns j .. j + 2r of x (zero-padded by r a side)."""
    w = hx.shape[0]
    radius = (x.shape[0] - w) // 2
    hx[:] = 0.0
    hxx[:] = 0.0
    hxr[:] = 0.0
    for d in range(2 * radius + 1):
        for j in range(w):
            value = np.float64(x[j + d])
            hx[j] += value
            hxx[j] += value * value
    for d in range(-radius, radius + 1):
        for j in range(max(0, -d), min(w, w - d)):
            hxr[j] += np.float64(x[radius + j + d]) * ref_row[j + d]


@numba.njit(nogil=True, cache=True)
def _offer(cost, best, i, j):  # pragma: no cover - numba
    """Insert cost into the ascending k lowest costs so far, best[:, i, j]."""
    m = best.shape[0]
    while m > 0 and best[m - 1, i, j] > cost:
        if m < best.shape[0]:
            best[m, i, j] = best[m - 1, i, j]
        m -= 1
    if m < best.shape[0]:
        best[m, i, j] = cost


@numba.njit(nogil=True, cache=True)
def _source_costs(
    srcs, src_hw, P, q, inv, ref, ref_mu, ref_std, inv_count, b, s, r0, r1, radius, best
):  # pragma: no cover - numba  # fmt: skip
    """1 − NCC of source s for rows [r0, r1), offered to best (k, r1 − r0, W).

    Rows are warped once each, in order; their row sums go to a ring of 2r + 2 rows whose column sums slide down
    the band (every buffer stays in the cache).
    """
    h, w = inv.shape[1], inv.shape[2]
    ring = 2 * radius + 2
    x = np.zeros(w + 2 * radius, np.float32)
    u = np.empty(w)
    v = np.empty(w)
    hx = np.empty((ring, w))
    hxx = np.empty((ring, w))
    hxr = np.empty((ring, w))
    valid = np.empty((ring, w), np.bool_)
    sx = np.zeros(w)
    sxx = np.zeros(w)
    sxr = np.zeros(w)
    ra = max(0, r0 - radius)
    added = ra  # next row to warp and add to the column sums
    for i in range(r0, r1):
        while added <= min(h - 1, i + radius):
            slot = added % ring
            _warp_row(srcs, src_hw, P, q, inv, b, s, added, u, v, x, valid[slot])
            _row_sums(x, ref[added], hx[slot], hxx[slot], hxr[slot])
            for j in range(w):
                sx[j] += hx[slot, j]
                sxx[j] += hxx[slot, j]
                sxr[j] += hxr[slot, j]
            added += 1
        if i - radius - 1 >= ra:  # the row that leaves the window
            slot = (i - radius - 1) % ring
            for j in range(w):
                sx[j] -= hx[slot, j]
                sxx[j] -= hxx[slot, j]
                sxr[j] -= hxr[slot, j]
        inv_rows = 1.0 / (min(h - 1, i + radius) - max(0, i - radius) + 1)
        row_valid = valid[i % ring]
        for j in range(w):
            norm = inv_rows * inv_count[j]
            mu = sx[j] * norm
            var = max(sxx[j] * norm - mu * mu, 0.0)
            cross = sxr[j] * norm - mu * ref_mu[i, j]
            cost = 1.0 - cross / (math.sqrt(var) * ref_std[i, j] + 1e-6)
            cost = min(max(cost, 0.0), INVALID_COST)
            if not row_valid[j] or var <= 1e-8:
                cost = INVALID_COST
            _offer(cost, best, i - r0, j)


@numba.njit(nogil=True, cache=True)
def _cost_tasks(
    srcs, src_hw, P, q, ref, ref_mu, ref_std, inv, radius, best_k, tasks, out, th, nth
):  # pragma: no cover - numba  # fmt: skip
    """The th-th interleaved share of the (hypothesis, r0, r1) tasks: aggregated costs into out (B, H, W)."""
    num_src = srcs.shape[0]
    w = inv.shape[2]
    k = min(best_k, num_src)
    inv_count = np.empty(w)  # 1 / columns of each clipped window
    for j in range(w):
        inv_count[j] = 1.0 / (min(w - 1, j + radius) - max(0, j - radius) + 1)
    for t in range(th, tasks.shape[0], nth):
        b, r0, r1 = tasks[t, 0], tasks[t, 1], tasks[t, 2]
        best = np.full((k, r1 - r0, w), np.inf, np.float32)
        for s in range(num_src):
            _source_costs(srcs, src_hw, P, q, inv, ref, ref_mu, ref_std, inv_count, b, s, r0, r1, radius, best)
        for i in range(r1 - r0):
            for j in range(w):
                total = 0.0
                for m in range(k):
                    total += best[m, i, j]
                out[b, r0 + i, j] = total / k


def bordered(images: np.ndarray) -> np.ndarray:
    """(S, H + 2, W + 2) float32 copy of images (S, H, W) with a one-pixel zero border (the input of ncc_costs)."""
    return np.pad(np.asarray(images, np.float32), ((0, 0), (1, 1), (1, 1)))


def _tasks(num_hyps: int, height: int) -> np.ndarray:
    """(T, 3) int64 rows (hypothesis, first row, end row): each hypothesis in bands of about ``_BAND_ROWS`` rows."""
    bands = max(1, round(height / _BAND_ROWS))
    edges = np.linspace(0, height, bands + 1).round().astype(np.int64)
    return np.array([(b, edges[k], edges[k + 1]) for b in range(num_hyps) for k in range(bands)], np.int64)


def ncc_costs(
    srcs: np.ndarray,
    src_hw: np.ndarray,
    P: np.ndarray,
    q: np.ndarray,
    ref: np.ndarray,
    ref_mu: np.ndarray,
    ref_std: np.ndarray,
    inv_depth: np.ndarray,
    radius: int,
    best_k: int,
    num_threads: int,
) -> np.ndarray:
    """Aggregated matching costs (B, H, W) float32 of per-pixel inverse-depth hypotheses.

    srcs: (S, Hp + 2, Wp + 2) float32 gray sources in [0, 1], zero-padded to (Hp, Wp) and with a one-pixel zero
    border (:func:`bordered`); src_hw: (S, 2) int64 (height, width) of each source, without padding and border.
    P: (S, 3, H, W) float32, K_src·R·ray of each reference pixel; q: (S, 3) float32, K_src·t (source pixels of a
    point at inverse depth d are (P + q·d)[:2] / (P + q·d)[2], COLMAP units). ref, ref_mu, ref_std: (H, W) float32,
    the reference and its window mean and std. inv_depth: (B, H, W) float32 hypotheses, 1/metres. radius: window
    radius, pixels. Cost = mean of the ``best_k`` lowest per-source 1 − NCC, ``INVALID_COST`` where unmatched.
    """
    b, h, w = inv_depth.shape
    out = np.empty((b, h, w), np.float32)
    args = (
        np.ascontiguousarray(srcs, np.float32),
        np.ascontiguousarray(src_hw, np.int64),
        np.ascontiguousarray(P, np.float32),
        np.ascontiguousarray(q, np.float32),
        np.ascontiguousarray(ref, np.float32),
        np.ascontiguousarray(ref_mu, np.float32),
        np.ascontiguousarray(ref_std, np.float32),
        np.ascontiguousarray(inv_depth, np.float32),
        int(radius),
        int(best_k),
        _tasks(b, h),
        out,
    )
    _run_shares(_cost_tasks, args, num_threads, min(len(args[10]), _CHUNKS_PER_THREAD * num_threads))
    return out


def _run_shares(kernel: Callable[..., None], args: tuple, num_threads: int, shares: int) -> None:
    """``kernel(*args, k, shares)`` for k in 0..shares-1 on ``num_threads`` Python threads, each share to the first
    thread that comes free (GIL-free kernels; waiting threads block)."""
    if num_threads <= 1 or shares <= 1:
        kernel(*args, 0, 1)
        return
    if not _POOL or _POOL[0]._max_workers != num_threads:
        _POOL[:] = [ThreadPoolExecutor(max_workers=num_threads, thread_name_prefix="mvs")]
    for future in [_POOL[0].submit(kernel, *args, k, shares) for k in range(shares)]:
        future.result()


@numba.njit(nogil=True, cache=True)
def _jacobi_smallest(a: np.ndarray, v: np.ndarray, vec: np.ndarray) -> None:  # pragma: no cover - numba
    """Unit eigenvector of the smallest eigenvalue of the symmetric 3×3 ``a`` (overwritten) into ``vec`` (3,),
    by cyclic Jacobi rotations until the off-diagonal is 1e-12 of the diagonal; v: 3×3 scratch."""
    v[:, :] = 0.0
    for k in range(3):
        v[k, k] = 1.0
    for _ in range(32):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        diag = a[0, 0] * a[0, 0] + a[1, 1] * a[1, 1] + a[2, 2] * a[2, 2]
        if off <= 1e-24 * diag:  # off-diagonal below 1e-12 of the diagonal: eigenvectors to ~1e-12
            break
        for p, r in ((0, 1), (0, 2), (1, 2)):
            apr = a[p, r]
            if apr == 0.0:
                continue
            theta = (a[r, r] - a[p, p]) / (2.0 * apr)
            t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):  # a <- a · J (columns p, r)
                akp = a[k, p]
                akr = a[k, r]
                a[k, p] = c * akp - s * akr
                a[k, r] = s * akp + c * akr
            for k in range(3):  # a <- Jᵀ · a (rows p, r)
                apk = a[p, k]
                ark = a[r, k]
                a[p, k] = c * apk - s * ark
                a[r, k] = s * apk + c * ark
            for k in range(3):
                vkp = v[k, p]
                vkr = v[k, r]
                v[k, p] = c * vkp - s * vkr
                v[k, r] = s * vkp + c * vkr
    m = 0
    if a[1, 1] < a[m, m]:
        m = 1
    if a[2, 2] < a[m, m]:
        m = 2
    for k in range(3):
        vec[k] = v[k, m]


@numba.njit(nogil=True, cache=True)
def _smallest_eigenvector(a: np.ndarray, rot: np.ndarray, vec: np.ndarray) -> None:  # pragma: no cover - numba
    """Unit eigenvector of the smallest eigenvalue of the symmetric 3×3 ``a`` (overwritten) into ``vec`` (3,).

    The eigenvalue in closed form (trigonometric solution of the characteristic cubic, on ``a`` scaled to unit
    largest entry), the vector as the longest cross product of two rows of a − λI; Jacobi rotations
    (:func:`_jacobi_smallest`, ``rot``: 3×3 scratch) where those rows are nearly parallel (λ not simple).
    """
    scale = 0.0
    for i in range(3):
        for j in range(3):
            scale = max(scale, abs(a[i, j]))
    if scale == 0.0:
        _jacobi_smallest(a, rot, vec)
        return
    a00, a01, a02 = a[0, 0] / scale, a[0, 1] / scale, a[0, 2] / scale
    a11, a12, a22 = a[1, 1] / scale, a[1, 2] / scale, a[2, 2] / scale
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6.0)
    if p < 1e-12:  # a multiple of the identity: every vector is an eigenvector
        _jacobi_smallest(a, rot, vec)
        return
    det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    r = min(max(det / (2.0 * p * p * p), -1.0), 1.0)
    lam = q + 2.0 * p * math.cos(math.acos(r) / 3.0 + 2.0 * math.pi / 3.0)  # the smallest root
    r0 = (a00 - lam, a01, a02)
    r1 = (a01, a11 - lam, a12)
    r2 = (a02, a12, a22 - lam)
    best = -1.0
    for u, v in ((r0, r1), (r0, r2), (r1, r2)):
        c0 = u[1] * v[2] - u[2] * v[1]
        c1 = u[2] * v[0] - u[0] * v[2]
        c2 = u[0] * v[1] - u[1] * v[0]
        n2 = c0 * c0 + c1 * c1 + c2 * c2
        if n2 > best:
            best = n2
            vec[0], vec[1], vec[2] = c0, c1, c2
    if best < 1e-12:  # the two larger eigenvalues are close to the smallest too: no well-separated direction
        _jacobi_smallest(a, rot, vec)
        return
    norm = math.sqrt(best)
    for k in range(3):
        vec[k] /= norm


@numba.njit(nogil=True, cache=True)
def _box_rows(a, radius, out, th, nth):  # pragma: no cover - numba
    """out[i, j, c] = sum of a[i, j - r .. j + r, c] (zeros outside), for the th-th of nth ranges of rows."""
    h, w, nc = a.shape
    for i in range(th * h // nth, (th + 1) * h // nth):
        for c in range(nc):
            s = 0.0
            for j in range(min(radius, w - 1) + 1):
                s += a[i, j, c]
            for j in range(w):
                out[i, j, c] = s
                if j + radius + 1 < w:
                    s += a[i, j + radius + 1, c]
                if j - radius >= 0:
                    s -= a[i, j - radius, c]


@numba.njit(nogil=True, cache=True)
def _box_cols(a, radius, out, th, nth):  # pragma: no cover - numba
    """out[i, j, c] = sum of a[i - r .. i + r, j, c] (zeros outside), for the th-th of nth ranges of columns."""
    h, w, nc = a.shape
    j0 = th * w // nth
    j1 = (th + 1) * w // nth
    s = np.zeros((j1 - j0, nc))
    for i in range(min(radius, h - 1) + 1):
        s += a[i, j0:j1]
    for i in range(h):
        out[i, j0:j1] = s
        if i + radius + 1 < h:
            s += a[i + radius + 1, j0:j1]
        if i - radius >= 0:
            s -= a[i - radius, j0:j1]


def box_sums(a: np.ndarray, radius: int, num_threads: int) -> np.ndarray:
    """Sums (H, W, C) float64 of a (H, W, C) over (2r+1)² windows, zeros outside the image."""
    a = np.ascontiguousarray(a, np.float64)
    rows = np.empty_like(a)
    run_threads(_box_rows, (a, radius, rows), num_threads)
    out = np.empty_like(a)
    run_threads(_box_cols, (rows, radius, out), num_threads)
    return out


@numba.njit(nogil=True, cache=True)
def _moments(X, m, centre, out, th, nth):  # pragma: no cover - numba
    """Per pixel of the th-th of nth ranges of rows: m·(1, x, y, z, xx, xy, xz, yy, yz, zz) of X − centre."""
    h, w = m.shape
    for i in range(th * h // nth, (th + 1) * h // nth):
        for j in range(w):
            if not m[i, j]:
                out[i, j, :] = 0.0
                continue
            x = X[i, j, 0] - centre[0]
            y = X[i, j, 1] - centre[1]
            z = X[i, j, 2] - centre[2]
            out[i, j, 0] = 1.0
            out[i, j, 1] = x
            out[i, j, 2] = y
            out[i, j, 3] = z
            out[i, j, 4] = x * x
            out[i, j, 5] = x * y
            out[i, j, 6] = x * z
            out[i, j, 7] = y * y
            out[i, j, 8] = y * z
            out[i, j, 9] = z * z


@numba.njit(nogil=True, cache=True)
def _plane_normals(sums, X, valid, min_points, out, th, nth):  # pragma: no cover - numba
    """Camera-facing unit normal of the plane fitted to each window's moments (0 where too few points)."""
    h, w = valid.shape
    a = np.empty((3, 3))
    rot = np.empty((3, 3))
    vec = np.empty(3)
    for i in range(th * h // nth, (th + 1) * h // nth):
        for j in range(w):
            n = sums[i, j, 0]
            if not valid[i, j] or n < min_points:
                out[i, j, :] = 0.0
                continue
            mx = sums[i, j, 1] / n
            my = sums[i, j, 2] / n
            mz = sums[i, j, 3] / n
            a[0, 0] = sums[i, j, 4] / n - mx * mx
            a[0, 1] = a[1, 0] = sums[i, j, 5] / n - mx * my
            a[0, 2] = a[2, 0] = sums[i, j, 6] / n - mx * mz
            a[1, 1] = sums[i, j, 7] / n - my * my
            a[1, 2] = a[2, 1] = sums[i, j, 8] / n - my * mz
            a[2, 2] = sums[i, j, 9] / n - mz * mz
            _smallest_eigenvector(a, rot, vec)
            sign = -1.0 if vec[0] * X[i, j, 0] + vec[1] * X[i, j, 1] + vec[2] * X[i, j, 2] > 0 else 1.0
            for c in range(3):
                out[i, j, c] = sign * vec[c]


def plane_normals(X: np.ndarray, valid: np.ndarray, fit: np.ndarray, radius: int, min_points: int,
                  num_threads: int) -> np.ndarray:  # fmt: skip
    """Camera-facing unit normals (H, W, 3) float32 of planes fitted (least squares) to the camera-frame points
    X (H, W, 3) (metres) marked ``fit`` (H, W) bool in each (2r+1)² window; 0 where ``valid`` (H, W) bool is false
    or the window has fewer than ``min_points`` such points."""
    X = np.ascontiguousarray(X, np.float64)
    h, w = valid.shape
    moments = np.empty((h, w, 10))
    centre = X.reshape(-1, 3).mean(axis=0)  # moments about a common centre: float64 keeps the local covariance
    run_threads(_moments, (X, np.ascontiguousarray(fit), centre, moments), num_threads)
    sums = box_sums(moments, radius, num_threads)
    out = np.empty((h, w, 3), np.float32)
    run_threads(_plane_normals, (sums, X, np.ascontiguousarray(valid), int(min_points), out), num_threads)
    return out
