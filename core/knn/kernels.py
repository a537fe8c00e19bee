"""The numba kernels of the k-NN query over a :class:`core.knn.grid.ColumnGrid` (see :mod:`core.knn` for the search).

``query_rows`` answers the points of interleaved ranges of column rows: ring 1 from the gathered 3×3
neighbourhood, else rings of columns in a z window, else (isolated outliers) the block search; all exact.
Distances are compared squared; indices are positions in the grid's sorted order.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(nogil=True, cache=True)
def scatter_rows(src: np.ndarray, order: np.ndarray, out: np.ndarray, th: int, nth: int) -> None:
    """out[order[i]] = src[i] for the th-th of nth contiguous ranges of i."""
    n = len(order)
    for i in range(th * n // nth, (th + 1) * n // nth):
        o = order[i]
        for j in range(src.shape[1]):
            out[o, j] = src[i, j]


@numba.njit(cache=True, inline="always")
def _lower_bound(zs: np.ndarray, a: int, b: int, value: float) -> int:
    while a < b:
        m = (a + b) >> 1
        if zs[m] < value:
            a = m + 1
        else:
            b = m
    return a


@numba.njit(cache=True, inline="always")
def _insert(best_d: np.ndarray, best_i: np.ndarray, d2: float, m: int) -> None:
    q = len(best_d) - 1
    while q > 0 and best_d[q - 1] > d2:
        best_d[q] = best_d[q - 1]
        best_i[q] = best_i[q - 1]
        q -= 1
    best_d[q] = d2
    best_i[q] = m


@numba.njit(cache=True, inline="always")
def _scan_column(xyz, zs, a, b, i, wz, best_d, best_i) -> float:
    """Offer the points of sorted range [a, b) within ±wz in z of point i (not i itself) to the k best; returns the
    z window shrunk to the k-th best distance when that is smaller."""
    k = len(best_d)
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    s = _lower_bound(zs, a, b, z - wz)
    for m in range(s, b):
        zm = zs[m]
        if zm > z + wz:
            break
        if m == i:
            continue
        dx = xyz[m, 0] - x
        dy = xyz[m, 1] - y
        dz = zm - z
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < best_d[k - 1]:
            _insert(best_d, best_i, d2, m)
            if best_d[k - 1] < wz * wz:
                wz = np.sqrt(best_d[k - 1]) * (1.0 + 1e-12)
    return wz


@numba.njit(cache=True, inline="always")
def _gap(v: float, a: float, b: float, guard: float) -> float:
    """Distance from v to the interval [a, b] less the rounding guard, ≥ 0."""
    return max(a - v - guard, v - b - guard, 0.0)


@numba.njit(nogil=True, cache=True)
def _scan_block(xyz, zs, col_start, nx, ny, h, lox, loy, guard, bs, ux, uy, nbx, nby, i, best_d, best_i):
    """Scan the columns of block (ux, uy) that may hold a point closer to point i than the current k-th best."""
    k = len(best_d)
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    c0x, c1x = ux * bs, min((ux + 1) * bs, nx)
    c0y, c1y = uy * bs, min((uy + 1) * bs, ny)
    for cx in range(c0x, c1x):
        # border columns are unbounded outwards (points beyond the box are clamped into them)
        xa = lox + cx * h if cx > 0 else -np.inf
        xb = lox + (cx + 1) * h if cx < nx - 1 else np.inf
        gx = _gap(x, xa, xb, guard)
        if gx * gx >= best_d[k - 1]:
            continue
        for cy in range(c0y, c1y):
            c = cx * ny + cy
            a, b = col_start[c], col_start[c + 1]
            if a == b:
                continue
            ya = loy + cy * h if cy > 0 else -np.inf
            yb = loy + (cy + 1) * h if cy < ny - 1 else np.inf
            gy = _gap(y, ya, yb, guard)
            gz = _gap(z, zs[a], zs[b - 1], 0.0)
            if gx * gx + gy * gy + gz * gz >= best_d[k - 1]:
                continue
            s = a
            zhi = np.inf
            if best_d[k - 1] < np.inf:
                r = np.sqrt(best_d[k - 1]) * (1.0 + 1e-12)
                s = _lower_bound(zs, a, b, z - r)
                zhi = z + r
            for m in range(s, b):
                zm = zs[m]
                if zm > zhi:
                    break
                if m == i:
                    continue
                dx = xyz[m, 0] - x
                dy = xyz[m, 1] - y
                dz = zm - z
                d2 = dx * dx + dy * dy + dz * dz
                if d2 < best_d[k - 1]:
                    _insert(best_d, best_i, d2, m)
                    if best_d[k - 1] < np.inf:
                        zhi = z + np.sqrt(best_d[k - 1]) * (1.0 + 1e-12)


@numba.njit(nogil=True, cache=True)
def _block_search(xyz, zs, col_start, nx, ny, h, lox, loy, guard, bzmin, bzmax, nbx, nby, bs, i, cx, cy, bd, bi):
    """Exact k nearest others of point i (column cx, cy) into bd (squared, ascending) / bi (sorted indices): blocks
    ring by ring around the point's block, each skipped when its bounding box is farther than the k-th best, until
    everything outside the rings is provably farther."""
    k = len(bd)
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    for j in range(k):
        bd[j] = np.inf
        bi[j] = -1
    bx, by = cx // bs, cy // bs
    ring = 0
    while True:
        for ux in range(max(bx - ring, 0), min(bx + ring, nbx - 1) + 1):
            side = ux == bx - ring or ux == bx + ring
            for uy in range(max(by - ring, 0), min(by + ring, nby - 1) + 1):
                if not side and uy != by - ring and uy != by + ring:
                    continue  # inner blocks were visited in earlier rings
                bb = ux * nby + uy
                if bzmin[bb] > bzmax[bb]:
                    continue
                xa = lox + ux * bs * h if ux > 0 else -np.inf
                xb = lox + (ux + 1) * bs * h if ux < nbx - 1 else np.inf
                ya = loy + uy * bs * h if uy > 0 else -np.inf
                yb = loy + (uy + 1) * bs * h if uy < nby - 1 else np.inf
                gx = _gap(x, xa, xb, guard)
                gy = _gap(y, ya, yb, guard)
                gz = _gap(z, bzmin[bb], bzmax[bb], 0.0)
                if gx * gx + gy * gy + gz * gz >= bd[k - 1]:
                    continue
                _scan_block(xyz, zs, col_start, nx, ny, h, lox, loy, guard, bs, ux, uy, nbx, nby, i, bd, bi)
        # every point outside the rings is at least `edge` away (sides at the grid's border have nothing beyond)
        edge = np.inf
        if bx - ring > 0:
            edge = min(edge, x - (lox + (bx - ring) * bs * h))
        if bx + ring < nbx - 1:
            edge = min(edge, lox + (bx + ring + 1) * bs * h - x)
        if by - ring > 0:
            edge = min(edge, y - (loy + (by - ring) * bs * h))
        if by + ring < nby - 1:
            edge = min(edge, loy + (by + ring + 1) * bs * h - y)
        if edge == np.inf:
            return
        edge -= guard
        if edge > 0 and bd[k - 1] <= edge * edge:
            return
        ring += 1


_GATHER_CAP = 64
"""Most candidates in a column's 3×3 neighbourhood for the gathered brute-force pass (steeper or denser spots use
the z-windowed per-point scan)."""


@numba.njit(cache=True, inline="always")
def _gather_ring1(xyz, col_start, nx, ny, cx, cy, cap, gx, gy, gz, gi) -> int:
    """Copy the points of the columns within one ring of (cx, cy), own column first, into gx, gy, gz (coordinates)
    and gi (sorted indices); returns their count, or 0 when it exceeds ``cap``."""
    x0, x1 = max(cx - 1, 0), min(cx + 1, nx - 1)
    y0, y1 = max(cy - 1, 0), min(cy + 1, ny - 1)
    total = 0
    for ux in range(x0, x1 + 1):
        total += col_start[ux * ny + y1 + 1] - col_start[ux * ny + y0]  # a row of columns is contiguous
    if total > cap:
        return 0
    c = cx * ny + cy
    ng = 0
    for m in range(col_start[c], col_start[c + 1]):
        gx[ng], gy[ng], gz[ng], gi[ng] = xyz[m, 0], xyz[m, 1], xyz[m, 2], m
        ng += 1
    for ux in range(x0, x1 + 1):
        for m in range(col_start[ux * ny + y0], col_start[ux * ny + y1 + 1]):
            if ux == cx and col_start[c] <= m < col_start[c + 1]:
                continue
            gx[ng], gy[ng], gz[ng], gi[ng] = xyz[m, 0], xyz[m, 1], xyz[m, 2], m
            ng += 1
    return ng


@numba.njit(cache=True, inline="always")
def _ring1_from_gathered(xyz, i, own, ng, gx, gy, gz, gi, g2, sel, cx, cy, nx, ny, h, lox, loy, guard, best_d, best_i):
    """The k best of point i (at position ``own`` of the gathered set) among the gathered points; True when that is
    provably exact, i.e. the k-th best is within r, the distance from the point to the edge of its 3×3 block (the
    ring-1 test of the per-point scan, which then finds the same distances). Only candidates within r can then be
    among the k best, so the others are dropped first (branch-free) and fewer than k of them means False."""
    k = len(best_d)
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    x0, x1 = max(cx - 1, 0), min(cx + 1, nx - 1)
    y0, y1 = max(cy - 1, 0), min(cy + 1, ny - 1)
    r = np.inf
    if x0 > 0:
        r = min(r, x - (lox + x0 * h))
    if x1 < nx - 1:
        r = min(r, lox + (x1 + 1) * h - x)
    if y0 > 0:
        r = min(r, y - (loy + y0 * h))
    if y1 < ny - 1:
        r = min(r, loy + (y1 + 1) * h - y)
    r = h if r == np.inf else r - guard
    r2 = r * r
    for m in range(ng):  # same arithmetic as _scan_column: identical distances
        dx = gx[m] - x
        dy = gy[m] - y
        dz = gz[m] - z
        g2[m] = dx * dx + dy * dy + dz * dz
    g2[own] = np.inf
    cnt = 0
    for m in range(ng):
        sel[cnt] = m
        cnt += 1 if g2[m] <= r2 else 0
    if cnt < k:
        return False
    for j in range(k):
        best_d[j] = np.inf
        best_i[j] = -1
    for t in range(cnt):
        m = sel[t]
        if g2[m] < best_d[k - 1]:
            _insert(best_d, best_i, g2[m], gi[m])
    return best_d[k - 1] <= r2


@numba.njit(nogil=True, cache=True)
def query_rows(
    xyz: np.ndarray,
    zs: np.ndarray,
    order: np.ndarray,
    col_start: np.ndarray,
    nx: int,
    ny: int,
    h: float,
    lox: float,
    loy: float,
    guard: float,
    bzmin: np.ndarray,
    bzmax: np.ndarray,
    nbx: int,
    nby: int,
    bs: int,
    k: int,
    full: bool,
    ring_budget: int,
    dist: np.ndarray,
    idx: np.ndarray,
    summary: np.ndarray,
    far: np.ndarray,
    rows_per_chunk: int,
    th: int,
    nth: int,
) -> None:
    """The k nearest others of the points in column rows [s, s + rows_per_chunk) for s = th·rows_per_chunk, then
    every nth chunk; results at each point's input position (disjoint per thread)."""
    best_d = np.empty(k)
    best_i = np.empty(k, dtype=np.int64)
    zext = zs.max() - zs.min() if len(zs) else 0.0
    max_ring = max(nx, ny, int(np.ceil(zext / h)) + 1)  # by then the window covers every point
    cap = _GATHER_CAP
    qx, qy, qz, q2 = np.empty(cap), np.empty(cap), np.empty(cap), np.empty(cap)
    qi = np.empty(cap, dtype=np.int64)
    qs = np.empty(cap, dtype=np.int64)
    for start in range(th * rows_per_chunk, nx, nth * rows_per_chunk):
        for cx in range(start, min(start + rows_per_chunk, nx)):
            for cy in range(ny):
                c = cx * ny + cy
                if col_start[c] == col_start[c + 1]:
                    continue
                # the column's 3×3 neighbourhood gathered once (own column first) for all its points, when small
                ng = _gather_ring1(xyz, col_start, nx, ny, cx, cy, cap, qx, qy, qz, qi)
                for i in range(col_start[c], col_start[c + 1]):
                    x, y = xyz[i, 0], xyz[i, 1]
                    ring = 1
                    done = False
                    if ng > 0:
                        done = _ring1_from_gathered(
                            xyz, i, i - col_start[c], ng, qx, qy, qz, qi, q2, qs, cx, cy, nx, ny, h, lox, loy, guard,
                            best_d, best_i,
                        )  # fmt: skip
                    while not done:
                        # rescan everything when the block grew (simple and still exact; most points need one pass)
                        for j in range(k):
                            best_d[j] = np.inf
                            best_i[j] = -1
                        x0, x1 = max(cx - ring, 0), min(cx + ring, nx - 1)
                        y0, y1 = max(cy - ring, 0), min(cy + ring, ny - 1)
                        # r: distance from the point to the nearest edge of the block of columns (>= ring·h; sides
                        # at the grid's edge have nothing beyond), less a hair for the rounding of column
                        # assignment. Every point within r lies in the block; the z window is ±r as well.
                        r = np.inf
                        if x0 > 0:
                            r = min(r, x - (lox + x0 * h))
                        if x1 < nx - 1:
                            r = min(r, lox + (x1 + 1) * h - x)
                        if y0 > 0:
                            r = min(r, y - (loy + y0 * h))
                        if y1 < ny - 1:
                            r = min(r, loy + (y1 + 1) * h - y)
                        r = ring * h if r == np.inf else r - guard
                        # own column first, then outwards, nearer side first (a tight k-th best early, so fewer
                        # insertions); a column is skipped when its (x, y) gap already exceeds the k-th best, and
                        # the z window shrinks with the k-th best
                        wz = _scan_column(xyz, zs, col_start[c], col_start[c + 1], i, r, best_d, best_i)
                        sx = 1 if x - (lox + cx * h) > 0.5 * h else -1
                        sy = 1 if y - (loy + cy * h) > 0.5 * h else -1
                        for tx in range(2 * ring + 1):
                            ux = cx + ((tx + 1) // 2) * (sx if tx % 2 == 1 else -sx)
                            if ux < 0 or ux > nx - 1:
                                continue
                            xa = lox + ux * h if ux > 0 else -np.inf
                            xb = lox + (ux + 1) * h if ux < nx - 1 else np.inf
                            gx = _gap(x, xa, xb, guard)
                            gx2 = gx * gx
                            if gx2 >= best_d[k - 1]:
                                continue
                            for ty in range(2 * ring + 1):
                                uy = cy + ((ty + 1) // 2) * (sy if ty % 2 == 1 else -sy)
                                if uy < 0 or uy > ny - 1:
                                    continue
                                cc = ux * ny + uy
                                a, b = col_start[cc], col_start[cc + 1]
                                if a == b or cc == c:
                                    continue
                                ya = loy + uy * h if uy > 0 else -np.inf
                                yb = loy + (uy + 1) * h if uy < ny - 1 else np.inf
                                gy = _gap(y, ya, yb, guard)
                                if gx2 + gy * gy >= best_d[k - 1]:
                                    continue
                                wz = _scan_column(xyz, zs, a, b, i, wz, best_d, best_i)
                        if best_d[k - 1] <= r * r or ring >= max_ring:
                            break
                        # jump straight to the ring that can hold the current k-th candidate (if any was found)
                        if best_d[k - 1] < np.inf:
                            ring = max(ring + 1, int(np.ceil(np.sqrt(best_d[k - 1]) / h)))
                        else:
                            ring = ring * 2
                        ring = min(ring, max_ring)
                        if ring > ring_budget:
                            # an isolated point: the block search prunes whole blocks instead of scanning rings
                            _block_search(
                                xyz, zs, col_start, nx, ny, h, lox, loy, guard, bzmin, bzmax, nbx, nby, bs, i, cx,
                                cy, best_d, best_i,
                            )  # fmt: skip
                            far[th] += 1
                            break
                    if full:
                        o = order[i]
                        for j in range(k):
                            dist[o, j] = np.sqrt(best_d[j])
                            idx[o, j] = order[best_i[j]]
                    else:
                        zeros = 0
                        while zeros < k and best_d[zeros] <= 0.0:
                            zeros += 1
                        summary[i, 0] = np.sqrt(best_d[0])  # in sorted order: scattered by the caller
                        if zeros == k:
                            summary[i, 1] = 0.0
                        else:
                            valid = k - zeros
                            lo_ = zeros + (valid - 1) // 2
                            hi_ = zeros + valid // 2
                            summary[i, 1] = 0.5 * (np.sqrt(best_d[lo_]) + np.sqrt(best_d[hi_]))
