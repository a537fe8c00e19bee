"""The ``cpu`` backend: numba rasteriser with a hand-written backward.

Written by hand because no maintained package rasterises differentiable Gaussians on a CPU (see
``shared/notes/cpu-splat-renderer.md``). Projection, SH and opacity are :mod:`fusion.render.project_cpu`;
this module does the per-pixel work:

1. binning: Gaussians sorted by depth once, then a counting sort by 16×16 tile keeps each tile's list in depth
   order (no per-tile sort);
2. forward: one thread per tile at a time (tiles sorted by list length, longest first, handed out in small chunks
   to Python threads running GIL-free kernels on both cores; a thread that the OS runs more takes more chunks,
   which keeps the wall time down on a shared machine);
   Gaussian-major loops over the units (2 rows × 8 columns, 16 contiguous floats) of each Gaussian's 3σ box,
   16 pixels at once, branch-free so that LLVM vectorises them (hence the polynomial exp, the bitwise masks,
   the compile-time unit size, counters in the float type and ``error_model="numpy"``: each of those alone
   blocked vectorisation or halved its width, 1.5-10x slower); front-to-back compositing with early termination
   per pixel, per unit and per tile;
3. backward: the same traversal front to back, with what is still to be composited behind each Gaussian taken
   from the saved forward result (no division by transmittance), gradients accumulated per intersection (each
   tile writes only its own list entries, so no atomics) in 16 per-lane sums over the entry's units, reduced once
   per entry (a reduction per unit, which LLVM emits for scalar accumulators, cost ~8 % of the kernel), with the
   conic's terms factored out of the per-pixel sums (Σ g·dx, Σ g·dy, Σ g·dx², ... combined once per entry),
   then summed per Gaussian through the transposed index of the binning (Gaussians split over the threads, each
   sum in list-entry order: results do not depend on the thread count). Entries of frozen Gaussians (training's
   context, whose gradients nobody reads) are only peeled off the remainders and the transmittance.

The composited features are channels of one kernel pair: :func:`_forward_kernel` and :func:`_backward_kernel`
compile a variant per channel count (1-8; the renderer's colour is RGB and z), a compile-time constant, as gsplat's
rasteriser takes any number of channels.

Training renders only the pixels its loss reads (``pixels``): the others start as finished, so a unit or tile
without one costs nothing in either pass.

Tried and dropped (single-thread kernel times, same scene): listing a Gaussian only in the tiles its 3σ ellipse
reaches (11 % fewer list entries, 3.5 % less raster time, but +3-5 ms in the serial binning) and visiting per row
pair only the column halves the ellipse reaches (13 % fewer units, no gain: the span costs what it saves).

Kernels are generic in the float type (float32 in production, float64 for gradient checks) and cached on disk
(a fresh checkout compiles the whole cpu training step, these kernels with projection, loss and Adam, in ~30 s on
a busy 2-core machine; later processes load the cache in ~3 s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from numba import njit, types
from numba.core import cgutils
from numba.cpython.unsafe.tuple import tuple_setitem
from numba.extending import intrinsic

from core.errors import ConfigError
from fusion.render.threads import run_chunks, run_threads, timed
from fusion.render.types import ALPHA_MAX, ALPHA_MIN, POWER_MIN, T_MIN, TILE_SIZE


@dataclass(frozen=True)
class TileBins:
    """Depth-sorted Gaussian lists per tile.

    offsets: (n_tiles + 1,) int64; tile t's list is ``ids[offsets[t]:offsets[t+1]]`` (row-major tiles).
    ids: (n_intersections,) int32 Gaussian indices, nearest first within each tile.
    order: (n_tiles,) int64 tile processing order, longest lists first (thread i takes entries i, i + n, ...).
    sorted_ids: (n_binned,) int64 the binned Gaussians, nearest first.
    g_offsets: (n_binned + 1,) int64 and slot_of: (n_intersections,) int64, the transposed index: list entry k
        (of Gaussian ``ids[k]`` = ``sorted_ids[p]``) has slot ``slot_of[k]`` in ``[g_offsets[p], g_offsets[p + 1])``,
        slots of one Gaussian in increasing k. The backward writes each entry's gradients at its slot, so that the
        per-Gaussian sums read contiguous rows, run in parallel and add in a fixed order.
    """

    offsets: np.ndarray
    ids: np.ndarray
    order: np.ndarray
    tiles_x: int
    tiles_y: int
    tile_size: int
    sorted_ids: np.ndarray
    g_offsets: np.ndarray
    slot_of: np.ndarray


@njit(cache=True)
def _tile_rect(mx, my, ex, ey, tile_size, tiles_x, tiles_y):  # pragma: no cover - numba
    tx0 = max(0, int(math.floor((mx - ex) / tile_size)))
    tx1 = min(tiles_x - 1, int(math.floor((mx + ex) / tile_size)))
    ty0 = max(0, int(math.floor((my - ey) / tile_size)))
    ty1 = min(tiles_y - 1, int(math.floor((my + ey) / tile_size)))
    return tx0, tx1, ty0, ty1


@njit(cache=True)
def _bin_kernel(means2d, extents, sorted_ids, tile_size, tiles_x, tiles_y):  # pragma: no cover - numba
    n_tiles = tiles_x * tiles_y
    n_sorted = sorted_ids.shape[0]
    offsets = np.zeros(n_tiles + 1, np.int64)
    g_offsets = np.zeros(n_sorted + 1, np.int64)
    rects = np.empty((n_sorted, 4), np.int32)  # tile box of each sorted Gaussian, computed once
    for p in range(n_sorted):
        g = sorted_ids[p]
        tx0, tx1, ty0, ty1 = _tile_rect(
            means2d[g, 0], means2d[g, 1], extents[g, 0], extents[g, 1], tile_size, tiles_x, tiles_y
        )
        rects[p, 0] = tx0
        rects[p, 1] = tx1
        rects[p, 2] = ty0
        rects[p, 3] = ty1
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                offsets[ty * tiles_x + tx + 1] += 1
        g_offsets[p + 1] = g_offsets[p] + max(0, tx1 - tx0 + 1) * max(0, ty1 - ty0 + 1)
    for t in range(n_tiles):
        offsets[t + 1] += offsets[t]
    ids = np.empty(offsets[n_tiles], np.int32)
    slot_of = np.empty(offsets[n_tiles], np.int64)
    cursor = offsets[:n_tiles].copy()
    for p in range(n_sorted):
        g = sorted_ids[p]
        m = g_offsets[p]
        for ty in range(rects[p, 2], rects[p, 3] + 1):
            for tx in range(rects[p, 0], rects[p, 1] + 1):
                t = ty * tiles_x + tx
                ids[cursor[t]] = g
                slot_of[cursor[t]] = m
                m += 1
                cursor[t] += 1
    return offsets, ids, g_offsets, slot_of


@njit(cache=True)
def _radix_argsort(keys):  # pragma: no cover - numba
    """Stable argsort of unsigned integer keys (LSD radix, 11-bit digits; digits all keys share are skipped)."""
    n = keys.shape[0]
    order = np.arange(n)
    tmp = np.empty(n, np.int64)
    count = np.empty(2049, np.int64)
    for shift in range(0, keys.itemsize * 8, 11):
        count[:] = 0
        for i in range(n):
            count[((keys[i] >> shift) & 2047) + 1] += 1
        if n == 0 or count.max() == n:
            continue
        for b in range(2048):
            count[b + 1] += count[b]
        for i in range(n):
            j = order[i]
            d = (keys[j] >> shift) & 2047
            tmp[count[d]] = j
            count[d] += 1
        order, tmp = tmp, order
    return order


def depth_order(depths: np.ndarray) -> np.ndarray:
    """Stable argsort (int64) of positive float depths (N,): ``np.argsort(depths, kind="stable")``, ~20x faster.

    The bit patterns of positive IEEE floats sort like the numbers, so they are radix-sorted as unsigned integers.
    """
    d = np.ascontiguousarray(depths)
    if d.dtype == np.float32:
        keys = d.view(np.uint32)
    else:
        keys = d.astype(np.float64).view(np.uint64)
    if len(d) and not bool((d > 0).all()):
        return np.argsort(d, kind="stable")
    return _radix_argsort(keys)


def bin_gaussians(
    means2d: np.ndarray,
    extents: np.ndarray,
    depths: np.ndarray,
    visible: np.ndarray,
    width: int,
    height: int,
    tile_size: int = TILE_SIZE,
) -> TileBins:
    """Tile lists for visible Gaussians: means2d and extents (N, 2) px, depths (N,), visible (N,) bool."""
    with timed("bin"):
        return _bin(means2d, extents, depths, visible, width, height, tile_size)


def _bin(means2d, extents, depths, visible, width, height, tile_size) -> TileBins:
    tiles_x = (width + tile_size - 1) // tile_size
    tiles_y = (height + tile_size - 1) // tile_size
    vis = np.flatnonzero(visible)
    sorted_ids = vis[depth_order(depths[vis])].astype(np.int64)
    offsets, ids, g_offsets, slot_of = _bin_kernel(
        np.ascontiguousarray(means2d, np.float64),
        np.ascontiguousarray(extents, np.float64),
        sorted_ids,
        tile_size,
        tiles_x,
        tiles_y,
    )
    by_length = np.argsort(-np.diff(offsets), kind="stable")
    return TileBins(offsets, ids, by_length, tiles_x, tiles_y, tile_size, sorted_ids, g_offsets, slot_of)


_TS = TILE_SIZE
_POWER_MIN = np.float32(POWER_MIN)
_ALPHA_MAX = np.float32(ALPHA_MAX)
_ALPHA_MIN = np.float32(ALPHA_MIN)
_T_MIN = np.float32(T_MIN)


@njit(fastmath=True, inline="always", cache=True)
def _exp_neg(x):  # pragma: no cover - numba
    """exp(x) for x in [-4.5, 0] (clamped to [-6, 0]), relative error < 3e-6 in float32.

    Hand-written because libm's exp blocks vectorisation; this one (Taylor on x/16, four squarings) lets LLVM
    evaluate a whole 16-pixel tile row in one AVX-512 instruction stream.
    """
    y = min(max(x, np.float32(-6.0)), np.float32(0.0)) * np.float32(0.0625)
    e = np.float32(1.0) + y * (
        np.float32(1.0)
        + y
        * (
            np.float32(0.5)
            + y * (np.float32(1 / 6) + y * (np.float32(1 / 24) + y * (np.float32(1 / 120) + y * np.float32(1 / 720))))
        )
    )
    e = e * e
    e = e * e
    e = e * e
    return e * e


_HALF = 8  # a unit is 2 rows × 8 columns of a tile: 16 floats, two AVX2 vectors, contiguous in the unit layout
_PAIRS = _TS // 2


@njit(inline="always", cache=True)
def _box_halves(mx, ex, x0):  # pragma: no cover - numba
    """Halves [h0, h1) of a tile's columns (0-7, 8-15; tile at x0) holding pixel centres within mx ± ex."""
    h0 = max(0, int(math.ceil(mx - ex - x0 - 0.5))) // _HALF
    h1 = min(_TS - 1, int(math.floor(mx + ex - x0 - 0.5))) // _HALF + 1
    return h0, h1


@njit(cache=True)
def _row_span(m, e, y0, y1):  # pragma: no cover - numba
    """Rows r in [y0, y1) whose centres r + 0.5 lie within [m - e, m + e], as tile-local indices."""
    r0 = max(y0, int(math.ceil(m - e - 0.5)))
    r1 = min(y1, int(math.floor(m + e - 0.5)) + 1)
    return r0 - y0, r1 - y0


@intrinsic
def _item(typingctx, tup, idx):  # noqa: ANN001, ANN202 - a numba intrinsic
    """``tup[idx]`` of a homogeneous tuple, idx in range (not checked), through a stack copy of the tuple.

    For the written-out channel lines of :func:`_accumulate` and its kin: the lines past the tuple's length are
    dead code, removed by LLVM, but must still compile, and numba's ``tup[k]`` refuses such an index; with a
    constant index this load lives in a register.
    """
    if not isinstance(tup, types.UniTuple) or not isinstance(idx, types.Integer):
        return None

    def codegen(context, builder, signature, args):  # noqa: ANN001, ANN202
        value, index = args
        slot = cgutils.alloca_once_value(builder, value)
        zero = context.get_constant(types.intp, 0)
        index = context.cast(builder, index, signature.args[1], types.intp)
        return builder.load(builder.gep(slot, [zero, index], inbounds=True))

    return tup.dtype(tup, idx), codegen


@njit(inline="always", cache=True)
def _tile_box(t, tiles_x, width, height):  # pragma: no cover - numba
    """Pixel box [x0, x1) × [y0, y1) of tile t (row-major tiles, clipped to the image)."""
    x0 = (t % tiles_x) * _TS
    y0 = (t // tiles_x) * _TS
    return x0, y0, min(x0 + _TS, width), min(y0 + _TS, height)


@njit(inline="always", cache=True)
def _unit_centres(xu, yu, x0, y0):  # pragma: no cover - numba
    """Pixel centres of the units of the tile at (x0, y0): xu[h, i] columns (2, 16), yu[p, i] rows (_PAIRS, 16)."""
    for i in range(16):
        for h in range(2):
            xu[h, i] = x0 + h * _HALF + i % _HALF + 0.5
        for p in range(_PAIRS):
            yu[p, i] = y0 + 2 * p + i // _HALF + 0.5


@njit(fastmath=True, inline="always", cache=True)
def _splat_alpha(dx, dy, a, b, cc, op):  # pragma: no cover - numba
    """Gaussian value, raw and clamped alpha, and whether it composites (power in range, alpha >= 1/255), at
    offset (dx, dy) px from the mean; branch-free (bitwise &) so that the 16-pixel loops vectorise."""
    power = np.float32(-0.5) * (a * dx * dx + cc * dy * dy) - b * dx * dy
    gauss = _exp_neg(power)
    raw = op * gauss
    alpha = min(_ALPHA_MAX, raw)
    ok = (power <= 0.0) & (power >= _POWER_MIN) & (alpha >= _ALPHA_MIN)
    return gauss, raw, alpha, ok


_MAX_CHANNELS = 8


@njit(inline="always", cache=True)
def _row(channels, features, g):  # pragma: no cover - numba
    """features[g] as a tuple of the type of ``channels`` (its length: the channel count)."""
    fv = channels
    for f in range(len(channels)):
        fv = tuple_setitem(fv, f, features[g, f])
    return fv


def _channel_tuple(n: int, dtype: np.dtype) -> tuple:
    """The kernels' ``channels`` argument: n zeros of ``dtype``, whose tuple type tells numba the channel count."""
    return tuple(np.zeros(n, dtype))


@njit(inline="always", cache=True)
def _accumulate(acc, h, p, i, w, fv):  # pragma: no cover - numba
    """acc[f, h, p, i] += w fv[f] for each channel f of the tuple fv (up to 8). Written out, each line behind a
    test on the tuple's length that is constant at compile time: a loop over the channels here, even of constant
    length, kept LLVM from vectorising the 16-pixel loop around it for fewer than 6 channels (several times
    slower)."""
    n = len(fv)
    if n > 0:
        acc[0, h, p, i] += w * _item(fv, 0)
    if n > 1:
        acc[1, h, p, i] += w * _item(fv, 1)
    if n > 2:
        acc[2, h, p, i] += w * _item(fv, 2)
    if n > 3:
        acc[3, h, p, i] += w * _item(fv, 3)
    if n > 4:
        acc[4, h, p, i] += w * _item(fv, 4)
    if n > 5:
        acc[5, h, p, i] += w * _item(fv, 5)
    if n > 6:
        acc[6, h, p, i] += w * _item(fv, 6)
    if n > 7:
        acc[7, h, p, i] += w * _item(fv, 7)


@njit(inline="always", cache=True)
def _peel(rest, h, p, i, w, fv):  # pragma: no cover - numba
    """rest[f, h, p, i] -= w fv[f] for each channel f of fv (written out as :func:`_accumulate`)."""
    n = len(fv)
    if n > 0:
        rest[0, h, p, i] -= w * _item(fv, 0)
    if n > 1:
        rest[1, h, p, i] -= w * _item(fv, 1)
    if n > 2:
        rest[2, h, p, i] -= w * _item(fv, 2)
    if n > 3:
        rest[3, h, p, i] -= w * _item(fv, 3)
    if n > 4:
        rest[4, h, p, i] -= w * _item(fv, 4)
    if n > 5:
        rest[5, h, p, i] -= w * _item(fv, 5)
    if n > 6:
        rest[6, h, p, i] -= w * _item(fv, 6)
    if n > 7:
        rest[7, h, p, i] -= w * _item(fv, 7)


@njit(inline="always", cache=True)
def _grad_channel(f, rest, go, lanes, h, p, i, w, tp, inv, v, g_alpha):  # pragma: no cover - numba
    """Channel f (value v) at one pixel in the backward: peel the entry (weight w) off what lies behind it, add
    w · dL/dC_f to the feature's lane sum, and return g_alpha plus dC_f/dalpha · dL/dC_f, where
    dC/dalpha_i = f_i T_i - (what lies behind i) / (1 - alpha_i) (tp = T_i, inv = 1 / (1 - alpha_i))."""
    r = rest[f, h, p, i] - w * v
    rest[f, h, p, i] = r
    g = go[f, h, p, i]
    lanes[6 + f, i] += w * g
    return g_alpha + g * (v * tp - r * inv)


@njit(inline="always", cache=True)
def _grad_channels(rest, go, lanes, h, p, i, w, tp, inv, fv, g_alpha):  # pragma: no cover - numba
    """:func:`_grad_channel` for each channel of fv in order (written out as :func:`_accumulate`)."""
    n = len(fv)
    if n > 0:
        g_alpha = _grad_channel(0, rest, go, lanes, h, p, i, w, tp, inv, _item(fv, 0), g_alpha)
    if n > 1:
        g_alpha = _grad_channel(1, rest, go, lanes, h, p, i, w, tp, inv, _item(fv, 1), g_alpha)
    if n > 2:
        g_alpha = _grad_channel(2, rest, go, lanes, h, p, i, w, tp, inv, _item(fv, 2), g_alpha)
    if n > 3:
        g_alpha = _grad_channel(3, rest, go, lanes, h, p, i, w, tp, inv, _item(fv, 3), g_alpha)
    if n > 4:
        g_alpha = _grad_channel(4, rest, go, lanes, h, p, i, w, tp, inv, _item(fv, 4), g_alpha)
    if n > 5:
        g_alpha = _grad_channel(5, rest, go, lanes, h, p, i, w, tp, inv, _item(fv, 5), g_alpha)
    if n > 6:
        g_alpha = _grad_channel(6, rest, go, lanes, h, p, i, w, tp, inv, _item(fv, 6), g_alpha)
    if n > 7:
        g_alpha = _grad_channel(7, rest, go, lanes, h, p, i, w, tp, inv, _item(fv, 7), g_alpha)
    return g_alpha


@njit(nogil=True, cache=True, fastmath=True, error_model="numpy")
def _forward_kernel(
    means2d,
    conics,
    opacities,
    features,
    extents,
    offsets,
    ids,
    order,
    width,
    height,
    tiles_x,
    j0,
    j1,
    channels,
    live,
    out,
    n_used,
):  # pragma: no cover - numba
    """Tiles order[j0:j1] of features (N, nf) into out (H, W, nf + 1) and n_used (H, W) (disjoint per tile);
    pixels where ``live`` (H, W) is 0 are not composited (features 0, alpha 0, n_used 0).

    Tile state is kept in units of 2 rows × 8 columns, [half h, row pair p, i] with pixel (row 2p + i // 8,
    column 8h + i % 8): a Gaussian visits only the units its 3σ box reaches (one 16-wide vectorised loop
    each; a box in one half of the columns costs half a row loop), and units whose 16 pixels have all
    stopped are skipped.

    The channel count is a compile-time constant, carried by the type of an argument (numba compiles, and caches
    on disk, one variant per count, and dispatches on it as fast as on arrays): ``channels``, a tuple of C zeros in
    the float type (:func:`_channel_tuple`). Each Gaussian's channels are a tuple of that length, composited by
    written-out lines (:func:`_accumulate`) of which LLVM keeps those the tuple has, so that it vectorises the
    16-pixel loop as it did the hand-written 4- and 8-channel kernels this one replaced (a runtime channel count, or
    one 16-pixel loop per channel, ran markedly slower).
    """
    nf = len(channels)
    ts = _TS
    dt = means2d.dtype
    n_tiles = offsets.shape[0] - 1
    T = np.empty((2, _PAIRS, 16), dt)
    acc = np.empty((nf, 2, _PAIRS, 16), dt)
    used = np.empty((2, _PAIRS, 16), np.int32)
    alive = np.empty((2, _PAIRS), np.int32)  # pixels of each unit still compositing
    xu = np.empty((2, 16), dt)  # pixel centres of a unit
    yu = np.empty((_PAIRS, 16), dt)
    for j in range(j0, min(j1, n_tiles)):
        t = order[j]
        x0, y0, x1, y1 = _tile_box(t, tiles_x, width, height)
        # A stopped pixel keeps -T (sign = done flag, magnitude = final transmittance); pixels outside the
        # image start stopped.
        n_done = 0
        for h in range(2):
            for p in range(_PAIRS):
                alive[h, p] = 0
                for i in range(16):
                    px = x0 + h * _HALF + i % _HALF
                    py = y0 + 2 * p + i // _HALF
                    inside = (px < width) and (py < height)
                    if inside:
                        inside = live[py, px] != 0
                    T[h, p, i] = 1.0 if inside else -1.0
                    n_done += 0 if inside else 1
                    alive[h, p] += 1 if inside else 0
        acc[:] = 0.0
        used[:] = 0
        _unit_centres(xu, yu, x0, y0)
        zero = xu[0, 0] - xu[0, 0]
        one = xu[0, 1] - xu[0, 0]  # 1 in the float type: an int or float64 count made LLVM pick 4-wide vectors
        start = offsets[t]
        stop_k = offsets[t + 1] if n_done < ts * ts else start  # a tile without a live pixel composites nothing
        for k in range(start, stop_k):
            g = ids[k]
            mx, my, a, b, cc, op = means2d[g, 0], means2d[g, 1], conics[g, 0], conics[g, 1], conics[g, 2], opacities[g]
            fv = _row(channels, features, g)  # scalars: a load in the pixel loop blocked vectorisation
            kk = np.int32(k - start + 1)
            r0, r1 = _row_span(my, extents[g, 1], y0, y1)
            h0, h1 = _box_halves(mx, extents[g, 0], x0)
            for p in range(r0 // 2, (r1 + 1) // 2):
                for h in range(h0, h1):
                    if alive[h, p] == 0:
                        continue
                    stops = zero
                    for i in range(16):
                        dx = xu[h, i] - mx
                        dy = yu[p, i] - my
                        power = np.float32(-0.5) * (a * dx * dx + cc * dy * dy) - b * dx * dy
                        alpha = min(_ALPHA_MAX, op * _exp_neg(power))
                        tp = T[h, p, i]
                        # Bitwise & (no short-circuit branches) keeps the loop vectorisable.
                        ok = (power <= 0.0) & (power >= _POWER_MIN) & (alpha >= _ALPHA_MIN) & (tp > 0.0)
                        test_t = tp * (np.float32(1.0) - alpha)
                        stop = ok & (test_t < _T_MIN)
                        draw = ok & (test_t >= _T_MIN)
                        w = alpha * tp if draw else zero
                        _accumulate(acc, h, p, i, w, fv)
                        T[h, p, i] = -tp if stop else (test_t if draw else tp)
                        u = used[h, p, i]  # load first: a select on the store target blocks vectorisation
                        used[h, p, i] = kk if draw else u
                        stops += one if stop else zero
                    n_stops = np.int32(stops)
                    n_done += n_stops
                    alive[h, p] -= n_stops
            if n_done == ts * ts:
                break
        for r in range(y1 - y0):
            for c in range(x1 - x0):
                h, p, i = c // _HALF, r // 2, (r % 2) * _HALF + c % _HALF
                for f in range(nf):
                    out[y0 + r, x0 + c, f] = acc[f, h, p, i]
                out[y0 + r, x0 + c, nf] = 1.0 - abs(T[h, p, i])
                n_used[y0 + r, x0 + c] = used[h, p, i]


@njit(nogil=True, cache=True, fastmath=True, error_model="numpy")
def _backward_kernel(
    means2d,
    conics,
    opacities,
    features,
    extents,
    offsets,
    ids,
    order,
    width,
    height,
    tiles_x,
    j0,
    j1,
    channels,
    out,
    n_used,
    grad_out,
    slot_of,
    frozen,
    g_isect,
):  # pragma: no cover - numba
    """Tiles order[j0:j1]; writes g_isect (n_isect, 6 + nf) rows ``slot_of[k]`` of their list entries k:
    d/d(mx, my), d/d(a, b, c), d/d(opacity), d/d(features 0..nf-1). Same unit layout as the forward kernel.
    Entries of Gaussians with ``frozen[g]`` != 0 only update what lies behind them (their rows are zeros).

    The channel count is a compile-time constant, the length of the ``channels`` tuple, as in
    :func:`_forward_kernel`.
    """
    nf = len(channels)
    dt = means2d.dtype
    n_tiles = offsets.shape[0] - 1
    ng = nf + 6
    T = np.empty((2, _PAIRS, 16), dt)
    rest = np.empty((nf + 1, 2, _PAIRS, 16), dt)  # what is still to be composited behind the current entry
    go = np.empty((nf + 1, 2, _PAIRS, 16), dt)
    used = np.empty((2, _PAIRS, 16), np.int32)
    unit_used = np.empty((2, _PAIRS), np.int32)  # list entries the slowest pixel of each unit composited
    xu = np.empty((2, 16), dt)
    yu = np.empty((_PAIRS, 16), dt)
    lanes = np.empty((ng, 16), dt)  # per-lane sums of one list entry over its units, reduced once per entry
    sums = np.empty(8, dt)
    for j in range(j0, min(j1, n_tiles)):
        t = order[j]
        x0, y0, x1, y1 = _tile_box(t, tiles_x, width, height)
        _unit_centres(xu, yu, x0, y0)
        zero = xu[0, 0] - xu[0, 0]
        T[:] = 1.0
        rest[:] = 0.0
        go[:] = 0.0
        used[:] = 0
        unit_used[:] = 0
        max_used = 0
        for r in range(y1 - y0):
            for c in range(x1 - x0):
                h, p, i = c // _HALF, r // 2, (r % 2) * _HALF + c % _HALF
                u = n_used[y0 + r, x0 + c]
                used[h, p, i] = u
                unit_used[h, p] = max(unit_used[h, p], u)
                max_used = max(max_used, u)
                for f in range(nf + 1):
                    rest[f, h, p, i] = out[y0 + r, x0 + c, f]
                    go[f, h, p, i] = grad_out[y0 + r, x0 + c, f]
        start = offsets[t]
        for k in range(start, start + max_used):
            g = ids[k]
            mx, my, a, b, cc, op = means2d[g, 0], means2d[g, 1], conics[g, 0], conics[g, 1], conics[g, 2], opacities[g]
            fv = _row(channels, features, g)
            kk = np.int32(k - start)
            r0, r1 = _row_span(my, extents[g, 1], y0, y1)
            h0, h1 = _box_halves(mx, extents[g, 0], x0)
            m = slot_of[k]
            if frozen[g] != 0:
                # No gradient wanted: peel the entry off the pixels' remainders and transmittance only.
                for p in range(r0 // 2, (r1 + 1) // 2):
                    for h in range(h0, h1):
                        if kk >= unit_used[h, p]:
                            continue
                        for i in range(16):
                            _, _, alpha, ok = _splat_alpha(xu[h, i] - mx, yu[p, i] - my, a, b, cc, op)
                            ok = ok & (kk < used[h, p, i])
                            tp = T[h, p, i]
                            w = alpha * tp if ok else zero
                            _peel(rest, h, p, i, w, fv)
                            rest[nf, h, p, i] -= w
                            T[h, p, i] = tp * (np.float32(1.0) - alpha) if ok else tp
                for f in range(ng):
                    g_isect[m, f] = zero
                continue
            lanes[:] = 0.0
            for p in range(r0 // 2, (r1 + 1) // 2):
                for h in range(h0, h1):
                    if kk >= unit_used[h, p]:
                        continue
                    for i in range(16):
                        dx = xu[h, i] - mx
                        dy = yu[p, i] - my
                        gauss, raw, alpha, ok = _splat_alpha(dx, dy, a, b, cc, op)
                        ok = ok & (kk < used[h, p, i])
                        tp = T[h, p, i]
                        w = alpha * tp if ok else zero
                        inv = np.float32(1.0) / (np.float32(1.0) - alpha)
                        # dC/dalpha summed over the channels, the alpha channel (value 1) first
                        r_a = rest[nf, h, p, i] - w
                        rest[nf, h, p, i] = r_a
                        g_alpha = go[nf, h, p, i] * (tp - r_a * inv)
                        g_alpha = _grad_channels(rest, go, lanes, h, p, i, w, tp, inv, fv, g_alpha)
                        T[h, p, i] = tp * (np.float32(1.0) - alpha) if ok else tp
                        g_alpha = g_alpha if (ok & (raw <= _ALPHA_MAX)) else zero
                        lanes[5, i] += g_alpha * gauss
                        g_pow = g_alpha * alpha
                        # the conic is constant per entry: sum g_pow·(dx, dy, dx², dx·dy, dy²), combine once
                        gx = g_pow * dx
                        gy = g_pow * dy
                        lanes[0, i] += gx
                        lanes[1, i] += gy
                        lanes[2, i] += gx * dx
                        lanes[3, i] += gx * dy
                        lanes[4, i] += gy * dy
            sx = zero
            sy = zero
            sxx = zero
            sxy = zero
            syy = zero
            s_op = zero
            s0 = zero
            s1 = zero
            s2 = zero
            s3 = zero
            s4 = zero
            s5 = zero
            s6 = zero
            s7 = zero
            for i in range(16):
                sx += lanes[0, i]
                sy += lanes[1, i]
                sxx += lanes[2, i]
                sxy += lanes[3, i]
                syy += lanes[4, i]
                s_op += lanes[5, i]
                if nf > 0:
                    s0 += lanes[6, i]
                if nf > 1:
                    s1 += lanes[7, i]
                if nf > 2:
                    s2 += lanes[8, i]
                if nf > 3:
                    s3 += lanes[9, i]
                if nf > 4:
                    s4 += lanes[10, i]
                if nf > 5:
                    s5 += lanes[11, i]
                if nf > 6:
                    s6 += lanes[12, i]
                if nf > 7:
                    s7 += lanes[13, i]
            g_isect[m, 0] = a * sx + b * sy
            g_isect[m, 1] = cc * sy + b * sx
            g_isect[m, 2] = np.float32(-0.5) * sxx
            g_isect[m, 3] = -sxy
            g_isect[m, 4] = np.float32(-0.5) * syy
            g_isect[m, 5] = s_op
            sums[0] = s0
            sums[1] = s1
            sums[2] = s2
            sums[3] = s3
            sums[4] = s4
            sums[5] = s5
            sums[6] = s6
            sums[7] = s7
            for f in range(nf):
                g_isect[m, 6 + f] = sums[f]
        for k in range(start + max_used, offsets[t + 1]):  # entries no pixel composited
            for f in range(ng):
                g_isect[slot_of[k], f] = zero


@njit(nogil=True, cache=True)
def _sum_kernel(g_isect, sorted_ids, g_offsets, th, n_threads, g_m2, g_con, g_op, g_feat):  # pragma: no cover
    """Per-Gaussian sums (float64, in list-entry order) of g_isect rows (Gaussian-major) of 6 + C columns
    (C = g_feat.shape[1] features), Gaussians split over threads."""
    n = sorted_ids.shape[0]
    nf = g_feat.shape[1]
    acc = np.empty(6 + nf, np.float64)
    for p in range(n * th // n_threads, n * (th + 1) // n_threads):
        acc[:] = 0.0
        for m in range(g_offsets[p], g_offsets[p + 1]):
            for j in range(6 + nf):
                acc[j] += g_isect[m, j]
        g = sorted_ids[p]
        g_m2[g, 0] = acc[0]
        g_m2[g, 1] = acc[1]
        g_con[g, 0] = acc[2]
        g_con[g, 1] = acc[3]
        g_con[g, 2] = acc[4]
        g_op[g] = acc[5]
        for j in range(nf):
            g_feat[g, j] = acc[6 + j]


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy())


class _RasterizeCPU(torch.autograd.Function):
    """Composite C features front to back; differentiable w.r.t. means2d, conics, opacities and features."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, extents, bins, width, height, live, frozen):  # type: ignore[override]
        m2 = _np(means2d)
        args = (m2, _np(conics), _np(opacities), _np(features), _np(extents).astype(m2.dtype))
        args += (bins.offsets, bins.ids, bins.order, width, height, bins.tiles_x)
        out = np.zeros((height, width, features.shape[1] + 1), m2.dtype)
        n_used = np.zeros((height, width), np.int32)
        tail = (_channel_tuple(features.shape[1], m2.dtype), live, out, n_used)
        run_chunks(_forward_kernel, args, tail, len(bins.order), "raster fwd")
        ctx.args, ctx.out, ctx.n_used, ctx.bins, ctx.frozen = args, out, n_used, bins, frozen
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad_out):  # type: ignore[override]
        args = ctx.args
        go = np.ascontiguousarray(grad_out.detach().cpu().numpy(), dtype=args[0].dtype)
        n, nf, dt = args[0].shape[0], args[3].shape[1], args[0].dtype
        g_isect = np.empty((len(args[6]), 6 + nf), dt)  # every entry is written (zeros past a tile's last use)
        tail = (_channel_tuple(nf, dt), ctx.out, ctx.n_used, go, ctx.bins.slot_of, ctx.frozen, g_isect)
        run_chunks(_backward_kernel, args, tail, len(ctx.bins.order), "raster bwd")
        outs = (np.zeros((n, 2), dt), np.zeros((n, 3), dt), np.zeros(n, dt), np.zeros((n, nf), dt))
        bins = ctx.bins
        run_threads(_sum_kernel, (g_isect, bins.sorted_ids, bins.g_offsets), outs, "gaussian sums")
        return (*(torch.from_numpy(a) for a in outs), None, None, None, None, None, None)


def rasterize_cpu(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    features: torch.Tensor,
    extents: torch.Tensor,
    depths: torch.Tensor,
    visible: torch.Tensor,
    width: int,
    height: int,
    tile_size: int = TILE_SIZE,
    pixels: np.ndarray | None = None,
    frozen: np.ndarray | None = None,
) -> torch.Tensor:
    """Front-to-back composite of per-Gaussian features (N, C) into an (H, W, C + 1) image with the numba kernels.

    Inputs as :class:`fusion.render.projection.Projection` plus opacities (N,) in (0, 1). Output channels are the
    C composited features (Σ wᵢ fᵢ; the renderer's are RGB and z)
    and the accumulated alpha (1 - T_final). No background: the caller blends it with the alpha channel.
    Gradients flow to means2d, conics, opacities and features.
    pixels: (H, W) bool, the pixels to composite (training renders only the pixels its loss reads); the others
    come out empty (0 everywhere) and cost nothing. None = every pixel.
    frozen: (N,) bool, Gaussians whose gradients nobody reads (training's frozen context): their backward only
    composites, and their gradient rows come back zero. None = none.
    Twin of :func:`fusion.render.reference.rasterize_reference`.
    """
    if tile_size != TILE_SIZE:
        raise ConfigError(f"the cpu rasteriser is compiled for {TILE_SIZE}-pixel tiles, got tile_size={tile_size}")
    if features.dim() != 2 or features.shape[0] != means2d.shape[0] or not 1 <= features.shape[1] <= _MAX_CHANNELS:
        raise ValueError(
            f"features must be (N, C) with N = {means2d.shape[0]} and 1 <= C <= {_MAX_CHANNELS} (the channels the "
            f"cpu kernels are written out for), got {tuple(features.shape)}"
        )
    live, frozen_u8 = _live_and_frozen(pixels, frozen, int(means2d.shape[0]), width, height)
    bins = bin_gaussians(_np(means2d), _np(extents), _np(depths), _np(visible), width, height, tile_size)
    return _RasterizeCPU.apply(means2d, conics, opacities, features, extents, bins, width, height, live, frozen_u8)


def _live_and_frozen(
    pixels: np.ndarray | None, frozen: np.ndarray | None, n: int, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' (H, W) uint8 live-pixel mask and (N,) uint8 frozen flags from the optional arguments."""
    if pixels is None:
        live = np.ones((height, width), np.uint8)
    else:
        if tuple(pixels.shape) != (height, width):
            raise ValueError(f"pixels must be ({height}, {width}), got {tuple(pixels.shape)}")
        live = np.ascontiguousarray(pixels, dtype=np.uint8)
    if frozen is None:
        frozen_u8 = np.zeros(n, np.uint8)
    else:
        if tuple(frozen.shape) != (n,):
            raise ValueError(f"frozen must be ({n},), got {tuple(frozen.shape)}")
        frozen_u8 = np.ascontiguousarray(frozen, dtype=np.uint8)
    return live, frozen_u8
