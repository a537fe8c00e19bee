"""Radiometric features: RGB, HSV and the local colour variance."""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree


def rgb_hsv(colors: np.ndarray) -> dict[str, np.ndarray]:
    """red, green, blue, hue, saturation, value (each (N,) float32 in [0, 1]) from colours (N, 3) uint8.

    Hue is HSV hue / 360 and 0 for grey pixels: scikit-image's ``rgb2hsv`` rule, in float32 like it (when two
    channels tie for the maximum, blue's formula wins over green's over red's), as a threaded numba kernel
    (much faster than ``rgb2hsv``, see docs/experiments/2026-11-27-domain-defaults.md; the tests compare the two).
    """
    rgb = np.ascontiguousarray(np.asarray(colors, dtype=np.float32).reshape(-1, 3) / np.float32(255.0))
    hue, sat, val = _hsv_kernel(rgb)
    names = ("red", "green", "blue", "hue", "saturation", "value")
    cols = (rgb[:, 0], rgb[:, 1], rgb[:, 2], hue, sat, val)
    return {n: np.ascontiguousarray(c, dtype=np.float32) for n, c in zip(names, cols, strict=True)}


@numba.njit(parallel=True, cache=True, nogil=True)
def _hsv_kernel(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    n = rgb.shape[0]
    hue = np.empty(n, dtype=np.float32)
    sat = np.empty(n, dtype=np.float32)
    val = np.empty(n, dtype=np.float32)
    zero, one, two, four, six = np.float32(0), np.float32(1), np.float32(2), np.float32(4), np.float32(6)
    for i in numba.prange(n):
        r, g, b = rgb[i, 0], rgb[i, 1], rgb[i, 2]
        v = max(r, g, b)
        delta = v - min(r, g, b)
        val[i] = v
        if delta == zero:
            sat[i] = zero
            hue[i] = zero
            continue
        sat[i] = delta / v
        if b == v:
            h = four + (r - g) / delta
        elif g == v:
            h = two + (b - r) / delta
        else:
            h = (g - b) / delta
        hue[i] = (h / six) % one
    return hue, sat, val


def color_variance(
    colors: np.ndarray,
    neighbours: np.ndarray | None = None,
    positions: np.ndarray | None = None,
    k: int = 16,
    chunk_size: int = 250_000,
    workers: int = -1,
    with_self: bool = False,
) -> np.ndarray:
    """Standard deviation of the colour over each point's neighbourhood, /255, averaged over R, G, B: (N,) float32.

    neighbours: (N, k) int64 indices of each point's neighbours (the finest geometric level's; with_self: the
    point itself belongs to its neighbourhood without being listed); when None they are found among
    ``positions`` (N, 3) with a k-NN query (self included).
    """
    c = np.asarray(colors, dtype=np.float32).reshape(-1, 3) / 255.0
    n = len(c)
    if neighbours is not None:
        return _color_std_kernel(c, np.ascontiguousarray(neighbours, dtype=np.int64), bool(with_self))
    out = np.empty(n, dtype=np.float32)
    tree = None if neighbours is not None else cKDTree(np.asarray(positions, dtype=np.float64))
    for start in range(0, n, chunk_size):
        sl = slice(start, min(n, start + chunk_size))
        if neighbours is not None:
            idx = neighbours[sl]
        else:
            assert tree is not None and positions is not None
            _, idx = tree.query(positions[sl], k=min(k, n), workers=workers)
            idx = np.asarray(idx).reshape(sl.stop - sl.start, -1)
        out[sl] = c[idx].std(axis=1).mean(axis=1)
    return out


@numba.njit(parallel=True, cache=True, nogil=True)
def _color_std_kernel(c: np.ndarray, neighbours: np.ndarray, with_self: bool) -> np.ndarray:  # pragma: no cover
    """Per row of ``neighbours`` (plus row i itself when ``with_self``): the population std of ``c`` (N, 3) over
    those rows, averaged over channels."""
    n, m = neighbours.shape
    k = m + 1 if with_self else m
    first = -1 if with_self else 0
    out = np.empty(n, dtype=np.float32)
    for i in numba.prange(n):
        acc = 0.0
        for ch in range(3):
            s = 0.0
            s2 = 0.0
            for j in range(first, m):
                t = np.int64(i)
                if j >= 0:
                    t = neighbours[i, j]
                v = c[t, ch]
                s += v
                s2 += v * v
            mean = s / k
            acc += np.sqrt(max(s2 / k - mean * mean, 0.0))
        out[i] = acc / 3.0
    return out
