"""PlayCanvas' compressed PLY (``.compressed.ply``, read by SuperSplat, the PlayCanvas engine and splat-transform).

Layout learnt from PlayCanvas' writer and readers — github.com/playcanvas/splat-transform
``src/lib/writers/write-compressed-ply.ts`` and ``compressed-chunk.ts`` (the writer SuperSplat uses),
``src/lib/readers/decompress-ply.ts`` (commit 8d6b801, 2026-07-31), and github.com/playcanvas/engine
``src/framework/parsers/ply.js`` + ``src/scene/gsplat/gsplat-compressed-data.js`` (commit 0aaef5e). No code is copied;
no Python package writes this format (``gsply`` does, inside its own data model, non-atomically), so it is written
here with numpy.

A binary little-endian PLY with three elements, in this order and with these exact type names (the engine's parser
checks both)::

    element chunk ceil(N/256)   property float min_x min_y min_z max_x max_y max_z
                                         min_scale_x min_scale_y min_scale_z max_scale_x max_scale_y max_scale_z
                                         min_r min_g min_b max_r max_g max_b
    element vertex N            property uint packed_position packed_rotation packed_scale packed_color
    element sh N                property uchar f_rest_0 .. f_rest_{3(K-1)-1}   (only when the SH degree is > 0)

Splat i belongs to chunk i // 256; each chunk stores the min/max of its splats' positions (local metres), log-scales
and colours (0.5 + C0 · f_dc), and each splat its values normalised into those ranges, t = (v − min)/(max − min),
as unsigned integers round(t · (2^bits − 1)):

- ``packed_position``: x 11 bits (31–21), y 10 bits (20–11), z 11 bits (10–0).
- ``packed_scale``: log σx, log σy, log σz in 11-10-11 bits likewise; log σ clamped to [−20, 20] first.
- ``packed_color``: r, g, b (8 bits each, bits 31–8, in the chunk's colour range) and α = sigmoid(opacity) (bits 7–0,
  over [0, 1]).
- ``packed_rotation``: the unit quaternion in file order (w, x, y, z) with its largest |component| made positive; bits
  31–30 its index (0 = w … 3 = z), then the other three in index order, 10 bits each: round((c · √2/2 + 0.5) · 1023).
- ``sh``: f_rest channel-major as in a 3DGS PLY, each byte floor((c/8 + 0.5) · 256) clipped to 0..255.

Splats are written in Morton (Z-curve) order of their positions, as splat-transform does, so that each chunk of 256
is spatially compact and its bounding box small; :func:`write_compressed_ply` returns the permutation. Fields
(``source``, ``classification``…) are not stored. Positions are our local ``means``; the float64 origin goes to the
``<name>.origin.json`` sidecar (for ``x.compressed.ply``: ``x.compressed.origin.json``), written by the caller
(:mod:`fusion.export`). The chunk bounds are float32, rounded outwards so every float64 position lies inside its box.

Precision (decoded minus input, per component, in chunk c with extent E = max − min):
- position: ≤ E / (2 · 2047) for x and z, E / (2 · 1023) for y (metres) — e.g. 0.24 mm for a 1 m chunk in x.
- log σ: ≤ E / (2 · 2047) (x, z), E / (2 · 1023) (y), within [−20, 20].
- colour (0.5 + C0 · f_dc): ≤ E / 510; α: ≤ 1/510.
- rotation: the three stored components ≤ √2 / 2046 = 6.9e-4; the largest ≤ 3e(1+e) / (1/2 + √(1/4 − 3e(1+e)))
  = 2.1e-3 with e = 6.9e-4.
- SH rest: ≤ 1/64 with splat-transform's decoding (bucket centres) for |c| < 3.97, ≤ 1/32 in the end buckets and with
  the engine's decoding (b · 8/255 − 4), within [−4, 4]. Values outside are clipped, with a warning that counts them.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import DataError, FormatError
from core.gaussians import SH_C0, DecodedSplats, GaussianSet, sigmoid
from core.io.atomic import atomic_path
from core.io.origin import read_origin
from core.io.ply import load_ply_data

CHUNK_SIZE = 256
"""Splats per chunk."""

CHUNK_PROPERTIES = (
    "min_x", "min_y", "min_z", "max_x", "max_y", "max_z",
    "min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z",
    "min_r", "min_g", "min_b", "max_r", "max_g", "max_b",
)  # fmt: skip
VERTEX_PROPERTIES = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
LOG_SCALE_LIMIT = 20.0
"""Log-scales are clamped to ±20 (PlayCanvas' writer clamps its chunk bounds there)."""
SH_LIMIT = 4.0
"""SH rest coefficients are stored over [−4, 4]."""

_BITS_11_10_11 = (11, 10, 11)
_SHIFTS_11_10_11 = (21, 11, 0)


@dataclass(frozen=True)
class CompressedPlyLayout:
    """What :func:`write_compressed_ply` wrote: counts, SH degree and ``order`` (N,) int64, the input index of each
    splat in file order (file splat i is input splat ``order[i]``)."""

    num_splats: int
    num_chunks: int
    sh_degree: int
    order: np.ndarray


@dataclass
class CompressedPlyData(DecodedSplats):
    """Decoded compressed-PLY content, float64, in file order and the file's (local) frame.

    positions (N, 3) metres; log_scales (N, 3); quats (N, 4) unit (w, x, y, z); alphas (N,) in [0, 1]; sh_dc (N, 3);
    sh_rest (N, K−1, 3); chunks (M, 12 or 18) float32 as stored; origin (3,) from the sidecar (zeros without one).
    """

    positions: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    alphas: np.ndarray
    sh_dc: np.ndarray
    sh_rest: np.ndarray
    chunks: np.ndarray
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))


# -- ordering ------------------------------------------------------------------------------------------------------
def _spread_bits(v: np.ndarray) -> np.ndarray:
    """Interleave two zero bits after each of the low 10 bits of ``v`` (Morton 3-D)."""
    v = v.astype(np.uint32) & np.uint32(0x3FF)
    v = (v ^ (v << np.uint32(16))) & np.uint32(0xFF0000FF)
    v = (v ^ (v << np.uint32(8))) & np.uint32(0x0300F00F)
    v = (v ^ (v << np.uint32(4))) & np.uint32(0x030C30C3)
    v = (v ^ (v << np.uint32(2))) & np.uint32(0x09249249)
    return v


def morton_order(points: np.ndarray) -> np.ndarray:
    """Indices sorting ``points`` (N, 3) along a 10-bit-per-axis Z curve of their bounding box; runs of more than
    256 points in one cell are re-sorted within the cell's own box. Stable, deterministic."""
    points = np.asarray(points, np.float64)
    return _morton_sort(points, np.arange(len(points), dtype=np.int64))


def _morton_sort(points: np.ndarray, index: np.ndarray) -> np.ndarray:
    p = points[index]
    if len(p) < 2:
        return index
    lo, hi = p.min(axis=0), p.max(axis=0)
    extent = hi - lo
    if not np.isfinite(extent).all() or not (extent > 0).any():
        return index
    mul = np.where(extent > 0, 1024.0 / np.where(extent > 0, extent, 1.0), 0.0)
    cell = np.minimum(1023, np.floor((p - lo) * mul)).astype(np.uint32)
    code = (
        _spread_bits(cell[:, 0])
        | (_spread_bits(cell[:, 1]) << np.uint32(1))
        | (_spread_bits(cell[:, 2]) << np.uint32(2))
    )
    order = np.argsort(code, kind="stable")
    index, code = index[order], code[order]
    cuts = np.flatnonzero(np.diff(code)) + 1
    for start, end in zip(np.r_[0, cuts], np.r_[cuts, len(code)], strict=True):
        if end - start > CHUNK_SIZE:
            index[start:end] = _morton_sort(points, index[start:end])
    return index


# -- packing -------------------------------------------------------------------------------------------------------
def _pad_chunks(values: np.ndarray) -> np.ndarray:
    """(N, C) -> (M, 256, C), the last row repeated to fill the last chunk (as PlayCanvas' writer does)."""
    n = len(values)
    m = -(-n // CHUNK_SIZE)
    padded = np.concatenate([values, np.repeat(values[-1:], m * CHUNK_SIZE - n, axis=0)])
    return padded.reshape(m, CHUNK_SIZE, values.shape[1])


def _float32_down(x: np.ndarray) -> np.ndarray:
    c = x.astype(np.float32)
    return np.where(c.astype(np.float64) > x, np.nextafter(c, np.float32(-np.inf)), c).astype(np.float32)


def _float32_up(x: np.ndarray) -> np.ndarray:
    c = x.astype(np.float32)
    return np.where(c.astype(np.float64) < x, np.nextafter(c, np.float32(np.inf)), c).astype(np.float32)


def _unorm(t: np.ndarray, bits: int) -> np.ndarray:
    """PlayCanvas' ``packUnorm``: t in [0, 1] -> round(t · (2^bits − 1)), clamped."""
    top = (1 << bits) - 1
    return np.clip(np.floor(t * top + 0.5), 0, top).astype(np.uint32)


def _chunk_bounds(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-chunk (M, C) minima and maxima of float64 ``values`` (N, C), rounded outwards to float32."""
    chunks = _pad_chunks(values)
    return _float32_down(chunks.min(axis=1)), _float32_up(chunks.max(axis=1))


def _normalise(values: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """t = (v − lo)/(hi − lo) per splat with its chunk's bounds (0 where the chunk has no extent)."""
    chunk = np.arange(len(values)) // CHUNK_SIZE
    lo64, hi64 = lo[chunk].astype(np.float64), hi[chunk].astype(np.float64)
    extent = hi64 - lo64
    return np.where(extent > 0, (values - lo64) / np.where(extent > 0, extent, 1.0), 0.0)


def _pack_11_10_11(t: np.ndarray) -> np.ndarray:
    out = np.zeros(len(t), np.uint32)
    for axis, (bits, shift) in enumerate(zip(_BITS_11_10_11, _SHIFTS_11_10_11, strict=True)):
        out |= _unorm(t[:, axis], bits) << np.uint32(shift)
    return out


def _pack_rotations(quats_wxyz: np.ndarray) -> np.ndarray:
    q = np.asarray(quats_wxyz, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    rows = np.arange(len(q))
    largest = np.argmax(np.abs(q), axis=1)
    q = np.where((q[rows, largest] < 0)[:, None], -q, q)
    out = largest.astype(np.uint32)
    for i in range(4):
        code = _unorm(q[:, i] * (math.sqrt(2.0) / 2.0) + 0.5, 10)
        out = np.where(largest != i, (out << np.uint32(10)) | code, out)
    return out


def _warn_clipped(name: str, what: str, count: int, total: int, limits: str) -> None:
    if count:
        warnings.warn(
            f"{name}: {count} of {total} {what} values lie outside the compressed PLY's range {limits} and were "
            "clipped to it",
            UserWarning,
            stacklevel=3,
        )


def encode_compressed_ply(
    gaussians: GaussianSet, *, sort: bool = True, name: str = "compressed PLY"
) -> tuple[CompressedPlyLayout, np.ndarray, np.ndarray, np.ndarray | None]:
    """Layout, chunk table (M, 18) float32, packed vertices (N, 4) uint32 and SH bytes (N, 3(K−1)) uint8 (None at
    degree 0) for ``gaussians``. ``sort``: Morton order (True) or the input order. Raises :class:`DataError` on an
    empty set and on NaN/inf parameters or zero quaternions, naming ``name``."""
    n = len(gaussians)
    if n == 0:
        raise DataError("no Gaussians to write: a compressed PLY needs at least one splat", name)
    try:
        gaussians.validate("Gaussian set")
    except DataError as err:
        raise DataError(err.problem, name) from err
    order = morton_order(gaussians.means) if sort else np.arange(n, dtype=np.int64)
    gs = gaussians.subset(order)

    pos_lo, pos_hi = _chunk_bounds(gs.means)
    log_scales = gs.log_scales.astype(np.float64)
    outside = np.abs(log_scales) > LOG_SCALE_LIMIT
    _warn_clipped(name, "log-scale", int(outside.sum()), outside.size, f"[-{LOG_SCALE_LIMIT:g}, {LOG_SCALE_LIMIT:g}]")
    log_scales = np.clip(log_scales, -LOG_SCALE_LIMIT, LOG_SCALE_LIMIT)
    scale_lo, scale_hi = _chunk_bounds(log_scales)
    colors = 0.5 + SH_C0 * gs.sh_dc.astype(np.float64)
    color_lo, color_hi = _chunk_bounds(colors)
    chunks = np.concatenate([pos_lo, pos_hi, scale_lo, scale_hi, color_lo, color_hi], axis=1).astype(np.float32)

    rgb = _normalise(colors, color_lo, color_hi)
    alpha = sigmoid(gs.logit_opacities)
    packed_color = (
        (_unorm(rgb[:, 0], 8) << np.uint32(24))
        | (_unorm(rgb[:, 1], 8) << np.uint32(16))
        | (_unorm(rgb[:, 2], 8) << np.uint32(8))
        | _unorm(alpha, 8)
    )
    vertices = np.stack(
        [
            _pack_11_10_11(_normalise(gs.means, pos_lo, pos_hi)),
            _pack_rotations(gs.quats),
            _pack_11_10_11(_normalise(log_scales, scale_lo, scale_hi)),
            packed_color,
        ],
        axis=1,
    ).astype(np.uint32)

    sh = None
    if gs.sh_degree > 0:
        rest = np.ascontiguousarray(gs.sh_rest.transpose(0, 2, 1)).reshape(n, -1).astype(np.float64)  # type: ignore[union-attr]
        outside = (rest < -SH_LIMIT) | (rest > SH_LIMIT)
        _warn_clipped(name, "SH rest", int(outside.sum()), outside.size, f"[-{SH_LIMIT:g}, {SH_LIMIT:g}]")
        sh = np.clip(np.floor((rest / (2 * SH_LIMIT) + 0.5) * 256.0), 0, 255).astype(np.uint8)
    layout = CompressedPlyLayout(num_splats=n, num_chunks=len(chunks), sh_degree=gs.sh_degree, order=order)
    return layout, chunks, vertices, sh


def _header(num_chunks: int, num_splats: int, sh_columns: int) -> bytes:
    lines = [
        "ply",
        "format binary_little_endian 1.0",
        "comment Generated by hybridsplat (PlayCanvas compressed PLY; origin in the .origin.json sidecar)",
        f"element chunk {num_chunks}",
        *(f"property float {p}" for p in CHUNK_PROPERTIES),
        f"element vertex {num_splats}",
        *(f"property uint {p}" for p in VERTEX_PROPERTIES),
    ]
    if sh_columns:
        lines += [f"element sh {num_splats}", *(f"property uchar f_rest_{i}" for i in range(sh_columns))]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def write_compressed_ply(
    path: str | PathLike[str], gaussians: GaussianSet, *, sort: bool = True
) -> CompressedPlyLayout:
    """Write ``gaussians`` (local means) as a PlayCanvas compressed PLY, atomically; returns what was written.

    The caller writes the origin sidecar (:mod:`fusion.export`). Errors as :func:`encode_compressed_ply`.
    """
    path = Path(path)
    layout, chunks, vertices, sh = encode_compressed_ply(gaussians, sort=sort, name=str(path))
    body = [chunks.astype("<f4").tobytes(), vertices.astype("<u4").tobytes()]
    if sh is not None:
        body.append(sh.tobytes())
    with atomic_path(path) as tmp:
        tmp.write_bytes(_header(len(chunks), len(vertices), 0 if sh is None else sh.shape[1]) + b"".join(body))
    return layout


# -- reading -------------------------------------------------------------------------------------------------------
def _unpack_unorm(packed: np.ndarray, bits: int, shift: int) -> np.ndarray:
    return ((packed >> np.uint32(shift)) & np.uint32((1 << bits) - 1)).astype(np.float64) / ((1 << bits) - 1)


def _unpack_11_10_11(packed: np.ndarray) -> np.ndarray:
    return np.stack(
        [_unpack_unorm(packed, b, s) for b, s in zip(_BITS_11_10_11, _SHIFTS_11_10_11, strict=True)], axis=1
    )


def _lerp(lo: np.ndarray, hi: np.ndarray, t: np.ndarray) -> np.ndarray:
    return lo.astype(np.float64) + (hi.astype(np.float64) - lo.astype(np.float64)) * t


def _decode_rotations(packed: np.ndarray) -> np.ndarray:
    largest = (packed >> np.uint32(30)).astype(np.int64)
    stored = np.stack([(_unpack_unorm(packed, 10, s) - 0.5) * math.sqrt(2.0) for s in (20, 10, 0)], axis=1)
    m = np.sqrt(np.maximum(0.0, 1.0 - (stored**2).sum(axis=1)))
    q = np.empty((len(packed), 4))
    rows = np.arange(len(packed))
    slot = np.zeros(len(packed), np.int64)
    for i in range(4):
        is_largest = largest == i
        q[:, i] = np.where(is_largest, m, stored[rows, np.minimum(slot, 2)])
        slot += ~is_largest
    return q


def read_compressed_ply(path: str | PathLike[str]) -> CompressedPlyData:
    """Decode a PlayCanvas compressed PLY (and its origin sidecar) with PlayCanvas' formulas, in float64.

    Raises :class:`FormatError` when the file is a PLY but not a compressed one (names what is missing), and the
    errors of :func:`core.io.ply.load_ply_data` for unreadable or truncated files.
    """
    path = Path(path)
    data = load_ply_data(path)
    names = [e.name for e in data.elements]
    if names[:2] != ["chunk", "vertex"] or names[2:] not in ([], ["sh"]):
        raise FormatError(f"not a compressed PLY: elements {names}, expected chunk, vertex[, sh]", path)
    chunk_el, vertex_el = data["chunk"], data["vertex"]
    chunk_names = [p.name for p in chunk_el.properties]
    if chunk_names not in (list(CHUNK_PROPERTIES), list(CHUNK_PROPERTIES[:12])):
        raise FormatError(f"compressed PLY chunk properties {chunk_names} are not PlayCanvas' 12 or 18", path)
    vertex_names = [p.name for p in vertex_el.properties]
    if vertex_names != list(VERTEX_PROPERTIES):
        raise FormatError(f"compressed PLY vertex properties {vertex_names}, expected {list(VERTEX_PROPERTIES)}", path)
    n = len(vertex_el.data)
    if len(chunk_el.data) != -(-n // CHUNK_SIZE):
        raise FormatError(f"{len(chunk_el.data)} chunks for {n} splats; expected ceil({n}/{CHUNK_SIZE})", path)
    chunks = np.stack([np.asarray(chunk_el.data[p], np.float32) for p in chunk_names], axis=1).reshape(
        -1, len(chunk_names)
    )
    if not np.isfinite(chunks).all():
        raise DataError("compressed PLY chunk bounds hold NaN or infinite values", path)
    packed = {p: np.asarray(vertex_el.data[p]).astype(np.uint32) for p in VERTEX_PROPERTIES}
    ci = np.arange(n) // CHUNK_SIZE
    c = chunks[ci]

    positions = _lerp(c[:, 0:3], c[:, 3:6], _unpack_11_10_11(packed["packed_position"]))
    log_scales = _lerp(c[:, 6:9], c[:, 9:12], _unpack_11_10_11(packed["packed_scale"]))
    col = np.stack([_unpack_unorm(packed["packed_color"], 8, s) for s in (24, 16, 8, 0)], axis=1)
    rgb = _lerp(c[:, 12:15], c[:, 15:18], col[:, :3]) if chunks.shape[1] == 18 else col[:, :3]

    sh_rest = np.zeros((n, 0, 3))
    if "sh" in names:
        sh_el = data["sh"]
        sh_names = [p.name for p in sh_el.properties]
        if len(sh_names) not in (9, 24, 45) or sh_names != [f"f_rest_{i}" for i in range(len(sh_names))]:
            raise FormatError(f"compressed PLY sh element has {len(sh_names)} properties; expected 9, 24 or 45", path)
        if len(sh_el.data) != n:
            raise FormatError(f"compressed PLY sh element has {len(sh_el.data)} rows for {n} splats", path)
        b = np.stack([np.asarray(sh_el.data[p]).astype(np.float64) for p in sh_names], axis=1).reshape(n, -1)
        t = np.where(b == 0, 0.0, np.where(b == 255, 1.0, (b + 0.5) / 256.0))
        k = len(sh_names) // 3
        sh_rest = ((t - 0.5) * 2 * SH_LIMIT).reshape(n, 3, k).transpose(0, 2, 1)
    return CompressedPlyData(
        positions=positions,
        log_scales=log_scales,
        quats=_decode_rotations(packed["packed_rotation"]),
        alphas=col[:, 3],
        sh_dc=(rgb - 0.5) / SH_C0,
        sh_rest=np.ascontiguousarray(sh_rest),
        chunks=chunks,
        origin=read_origin(path),
    )
