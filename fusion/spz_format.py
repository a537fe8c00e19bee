"""Niantic's SPZ format (``.spz``): gzip-compressed, quantised Gaussian splats, written as **version 2**.

Layout learnt from the reference implementation, github.com/nianticlabs/spz (``src/cc/load-spz.cc``,
``src/cc/splat-utils.h``, ``src/cc/splat-types.h``; read at commit 21715c3, 2026-07-10), and checked against
PlayCanvas splat-transform's independent reader (``src/lib/readers/read-spz.ts``). No code is copied.

Why hand-written: the PyPI candidates do not fit. ``gsply`` writes only versions 3/4, clips out-of-range positions
into the 24-bit range without a word and writes non-atomically; ``alspz`` is an sdist of project-specific bindings
that builds the C++ library with CMake and downloads zlib/zstd at build time; ``spz`` (0.0.1) does not build here.
The format is a header and six byte planes, so numpy and zlib do it in ~150 lines.

Which version we write, and why
-------------------------------
Version 2 (gzip, 3-byte rotations) is the one read most widely: CesiumJS (through the glTF SPZ extension), the
reference loader of every release since 2024, splat-transform (versions 2–4); the PlayCanvas engine's own SPZ
parser reads version 4 only (SuperSplat and PlayCanvas read our ``.compressed.ply`` instead). Version 3 (``version=3``,
smallest-three rotations, 4 bytes) is offered for readers that have it: its rotations are far more precise when the
rotation angle nears 180° (w → 0), where version 2's reconstructed w loses up to ~0.12 (see the table). Version 4
(zstd streams, the reference's current default) is not written, nor read: it needs zstd, which Python 3.11 lacks.

File (gzip member; deflate level 6, memLevel 9, no name, mtime 0 — what the reference's zlib call produces, so the
output is deterministic), decompressed:

=========================  =====================================================================================
bytes                      content (little-endian)
=========================  =====================================================================================
0–15                       header: magic uint32 0x5053474E ("NGSP"), version uint32, numPoints uint32, shDegree
                           uint8, fractionalBits uint8, flags uint8 (bit 0: antialiased; we write 0), reserved 0
9 · N                      positions: x, y, z per splat, each a signed 24-bit fixed-point integer (two's
                           complement, 3 bytes LE): metres · 2^fractionalBits
N                          alphas: round(α · 255)
3 · N                      colours: round(f_dc · 0.15 · 255 + 127.5) per channel (SPZ's own scale, not SH C0)
3 · N                      scales: round((log σ + 10) · 16) per axis
3 · N (v2) / 4 · N (v3)    rotations. v2: the unit quaternion's x, y, z with the sign chosen so that w ≥ 0, each
                           round(c · 127.5 + 127.5); w = √(1 − x² − y² − z²) on reading. v3: uint32 LE, bits 31–30
                           the index (x, y, z, w = 0..3) of the largest |component| (made positive, not stored), then
                           the three others in index order, 10 bits each: a sign bit and a 9-bit magnitude
                           round(511 · |c| · √2)
N · 3 · (K − 1)            SH rest: per splat, coefficient-major with the colour channel innermost (our ``sh_rest``
                           (N, K−1, 3) row-major); each byte (c · 128 + 128) snapped to multiples of 2^(8−bits):
                           bits = 5 for degree 1, 4 for degrees 2–3 (the reference's defaults)
=========================  =====================================================================================

Every rounding is half away from zero and uses float32 arithmetic where the reference does, so a PLY read by our
reader and written here gives the reference's bytes (``tests/test_export_spz.py`` compares them with the reference's
WebAssembly build when node and ``@playcanvas/splat-transform`` are installed).

Frame and axes
--------------
Positions are our local ``means`` (metres, relative to ``origin``): the float64 origin goes to the
``<name>.origin.json`` sidecar (the caller, :mod:`fusion.export`, writes it). The reference's README says SPZ is
"RUB" (three.js axes) and the PLY "RDF", but it converts only when the caller names a source system: its own
``ply_to_spz`` tool (``UnpackOptions.to`` and ``PackOptions.from`` both ``UNSPECIFIED``) and splat-transform's
writer store the PLY's axes unchanged. We do the same — no axis flip — so our ``.spz`` and the reference's
conversion of our 3DGS PLY agree, and viewers show the ``.spz`` as they show the ``.ply``.

Precision (decoded minus input; per component)
----------------------------------------------
- position: ≤ 2^−(fractionalBits+1) m: with the default 12 bits (the reference writer's fixed choice), ±0.122 mm
  (step 0.244 mm) within ±2048 m of the local origin. A set whose local coordinates do not fit gets fewer fractional
  bits (step doubled per bit, with a warning that states it); an explicit ``fractional_bits`` that does not fit is
  a :class:`FormatError`. Positions are never wrapped or clipped. ``hybridsplat export`` asks for the most bits
  that fit (:func:`finest_fractional_bits`; 16 bits within ±128 m: ±7.6 µm), which brings the decoded renders
  closer to the PLY's (bench/bench_export_formats.py; docs/experiments/2026-11-27-export-formats.md).
- opacity α: ≤ 1/510.
- colour (SH DC, ``f_dc``): ≤ 1 / (2 · 0.15 · 255) = 0.0131 (0.0037 in 0–1 colour) within |f_dc| ≤ 3.33.
- log σ: ≤ 1/32 (σ within ±3.2 %) within log σ ∈ [−10, 5.94] (σ from 45 µm to 379 m).
- rotation v2: x, y, z ≤ 1/255; w ≤ min(√D, D / w) with D = √3 · e · (2 √(1 − w²) + √3 · e), e = 1/255 (≤ 0.117
  near w = 0, ≤ 0.024 for w ≥ 0.5). v3: the three stored components ≤ √2 / 2044 = 6.9e-4; the largest
  ≤ 3e(1+e) / (1/2 + √(1/4 − 3e(1+e))) ≈ 2.1e-3 with e = 6.9e-4.
- SH rest: ≤ (2^(8−bits) + 1) / 256, i.e. 0.0352 for degree 1 (5 bits) and 0.0664 for degrees 2–3 (4 bits; 0.0195 and
  0.0352 with the 6 / 5 bits of ``hybridsplat export``, :data:`EXPORT_SH1_BITS`), within
  c ∈ [−1, 1] (the reference rounds to 1/128 first, then to the bucket, hence the + 1).
Values outside these ranges (not positions) are clipped to the nearest code, with a warning that counts them.
"""

from __future__ import annotations

import math
import struct
import warnings
import zlib
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import DataError, FormatError, InputFileError
from core.gaussians import DecodedSplats, GaussianSet, sigmoid
from core.io.atomic import atomic_path
from core.io.origin import read_origin

SPZ_MAGIC = 0x5053474E
"""``"NGSP"`` read as a little-endian uint32."""

SPZ_VERSION = 2
"""The version :func:`write_spz` writes unless told otherwise (see the module docstring)."""

SPZ_WRITABLE_VERSIONS = (2, 3)
SPZ_READABLE_VERSIONS = (2, 3)

SPZ_COLOR_SCALE = 0.15
"""SPZ stores the SH DC term as ``f_dc · 0.15 · 255 + 127.5`` (the reference's ``colorScale``)."""

SPZ_F_DC_LIMIT = 127.5 / (SPZ_COLOR_SCALE * 255.0)
"""|f_dc| SPZ's 8-bit colour code holds (3.33; colour −0.44 … 1.44): the codes 0 and 255."""

SPZ_LOG_SCALE_RANGE = (-10.0, 255.0 / 16.0 - 10.0)
"""log σ SPZ's 8-bit scale code ``(log σ + 10) · 16`` holds: σ from 45 µm to 379 m."""

DEFAULT_FRACTIONAL_BITS = 12
"""The reference writer's fixed-point precision, 2^-12 m = 0.244 mm: below it we warn."""
MAX_FRACTIONAL_BITS = 23
"""The most fractional bits a 24-bit signed coordinate can have (range ±1 m)."""

SH1_BITS = 5
SH_REST_BITS = 4
"""Bits kept per SH coefficient byte (degree 1, degrees 2–3): the reference's ``PackOptions`` defaults."""

EXPORT_SH1_BITS = 6
EXPORT_SH_REST_BITS = 5
"""Bits kept per SH coefficient byte by ``hybridsplat export`` and the tileset's SPZ tiles (degree 1, degrees 2–3):
one more than the reference's, which halves the SH error bound (0.0195 / 0.0352 instead of 0.0352 / 0.0664). Any
SPZ reader reads them (the bytes are the format's; the buckets are the encoder's choice). Chosen on the training
views of two classifier training layouts, never on scored views (the measurements:
docs/experiments/2026-11-27-export-formats.md)."""

HEADER = struct.Struct("<IIIBBBB")
"""The 16-byte header of versions 1–3."""

FLAG_ANTIALIASED = 0x1
_INT24_MIN, _INT24_MAX = -(1 << 23), (1 << 23) - 1
_SQRT1_2 = np.float32(0.707106781186547524401)


@dataclass(frozen=True)
class SpzHeader:
    """The header fields of an SPZ file."""

    version: int
    num_points: int
    sh_degree: int
    fractional_bits: int
    flags: int = 0

    @property
    def position_step(self) -> float:
        """The fixed-point step of positions, metres (2^-fractionalBits)."""
        return 2.0**-self.fractional_bits


@dataclass
class SpzData(DecodedSplats):
    """Decoded SPZ content, float64, in the file's (local) frame.

    positions (N, 3) metres; log_scales (N, 3) log σ; quats (N, 4) (w, x, y, z), unit up to the quantisation (the
    reader rebuilds the missing component as √max(0, 1 − Σ others²), as the reference does); alphas (N,) in [0, 1];
    sh_dc (N, 3); sh_rest (N, K−1, 3) coefficient-major; origin (3,) from the ``.origin.json`` sidecar (zeros
    without one).
    """

    header: SpzHeader
    positions: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    alphas: np.ndarray
    sh_dc: np.ndarray
    sh_rest: np.ndarray
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))


def _round_half_away(x: np.ndarray) -> np.ndarray:
    """C's ``round``: to the nearest integer, halves away from zero (float64 result, exact)."""
    x = np.asarray(x, dtype=np.float64)
    return np.copysign(np.floor(np.abs(x) + 0.5), x)


def _to_u8(x: np.ndarray) -> np.ndarray:
    """The reference's ``toUint8``: round half away from zero, clamp to 0..255."""
    return np.clip(_round_half_away(x), 0, 255).astype(np.uint8)


def _warn_clipped(name: str, what: str, count: int, total: int, limits: str) -> None:
    if count:
        warnings.warn(
            f"{name}: {count} of {total} {what} values lie outside SPZ's range {limits} and were clipped to it",
            UserWarning,
            stacklevel=3,
        )


def _warn_codes_outside(name: str, what: str, codes: np.ndarray, limits: str) -> None:
    """Warn about byte codes (before rounding) that fall outside 0..255, i.e. values SPZ clips."""
    _warn_clipped(name, what, int(np.count_nonzero((codes < -0.5) | (codes > 255.5))), codes.size, limits)


def fixed_point_fits(means: np.ndarray, fractional_bits: int) -> bool:
    """Whether every local coordinate (metres) rounds into a signed 24-bit integer at ``fractional_bits``."""
    if means.size == 0:
        return True
    q = _round_half_away(np.asarray(means, np.float64) * 2.0**fractional_bits)
    return bool(q.min() >= _INT24_MIN and q.max() <= _INT24_MAX)


def choose_fractional_bits(means: np.ndarray, preferred: int = DEFAULT_FRACTIONAL_BITS) -> int | None:
    """The largest number of fractional bits ≤ ``preferred`` at which ``means`` fit 24-bit fixed point, or None
    when not even whole metres fit (|x| > 8 388 607 m)."""
    for bits in range(preferred, -1, -1):
        if fixed_point_fits(means, bits):
            return bits
    return None


def finest_fractional_bits(means: np.ndarray) -> int | None:
    """The most fractional bits (≤ 23) at which ``means`` fit, when that is at least the reference's 12; None
    otherwise (the writer then picks, and warns)."""
    bits = choose_fractional_bits(means, MAX_FRACTIONAL_BITS)
    return bits if bits is not None and bits >= DEFAULT_FRACTIONAL_BITS else None


def _pack_positions(means: np.ndarray, bits: int) -> np.ndarray:
    q = _round_half_away(np.asarray(means, np.float64) * 2.0**bits).astype(np.int64) & 0xFFFFFF
    out = np.empty((len(means), 3, 3), np.uint8)
    out[..., 0] = q & 0xFF
    out[..., 1] = (q >> 8) & 0xFF
    out[..., 2] = (q >> 16) & 0xFF
    return out.reshape(len(means), 9)


def _unit_xyzw(quats_wxyz: np.ndarray) -> np.ndarray:
    """Normalised quaternions reordered to (x, y, z, w), float32 as the reference holds them."""
    q = np.asarray(quats_wxyz, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return q[:, [1, 2, 3, 0]].astype(np.float32)


def _pack_rotations_v2(quats_wxyz: np.ndarray) -> np.ndarray:
    q = _unit_xyzw(quats_wxyz)
    half = np.where(q[:, 3:4] < 0, np.float32(-127.5), np.float32(127.5)).astype(np.float32)
    return _to_u8(q[:, :3] * half + np.float32(127.5))


def _pack_rotations_v3(quats_wxyz: np.ndarray) -> np.ndarray:
    q = _unit_xyzw(quats_wxyz)
    n = len(q)
    largest = np.argmax(np.abs(q), axis=1)  # first of equals, as the reference's strict '>' scan
    negate = q[np.arange(n), largest] < 0
    mag = np.floor(np.float32(511) * (np.abs(q) / _SQRT1_2) + np.float32(0.5))
    mag = np.minimum(mag.astype(np.uint32), 511)
    negbit = ((q < 0) ^ negate[:, None]).astype(np.uint32)
    comp = largest.astype(np.uint32)
    for i in range(4):
        keep = largest != i
        comp = np.where(keep, (comp << np.uint32(10)) | (negbit[:, i] << np.uint32(9)) | mag[:, i], comp)
    return comp.astype("<u4").view(np.uint8).reshape(n, 4)


def _pack_sh(sh_rest: np.ndarray, sh1_bits: int, sh_rest_bits: int) -> tuple[np.ndarray, int]:
    """Bytes (N, 3·(K−1)) and the number of values outside [−1, 1] (clipped)."""
    n, k, _ = sh_rest.shape
    x = np.asarray(sh_rest, np.float32) * np.float32(128.0)
    q0 = _round_half_away(x).astype(np.int64) + 128
    clipped = int(np.count_nonzero(np.abs(sh_rest) > 1.0))
    bucket = np.full((1, k, 1), 1 << (8 - sh_rest_bits), np.int64)
    bucket[:, :3] = 1 << (8 - sh1_bits)
    q = (q0 + bucket // 2) // bucket * bucket  # negatives clamp to 0 below, so floor vs C's truncation is moot
    return np.clip(q, 0, 255).astype(np.uint8).reshape(n, 3 * k), clipped


def _resolve_fractional_bits(means: np.ndarray, fractional_bits: int | None, name: str) -> int:
    """The fractional bits to write (see :func:`encode_spz`); warns when fewer than 12, raises when none fit."""
    if fractional_bits is None:
        bits = choose_fractional_bits(means)
        if bits is None:
            raise FormatError(
                f"local coordinates up to {np.abs(means).max():.6g} m do not fit SPZ's 24-bit fixed point even in "
                f"whole metres (±{_INT24_MAX} m); choose a local origin nearer the data",
                name,
            )
        if bits < DEFAULT_FRACTIONAL_BITS:
            warnings.warn(
                f"{name}: local coordinates up to {np.abs(means).max():.6g} m need {bits} fractional bits in SPZ's "
                f"24-bit fixed point: position step {2.0**-bits * 1000:.3g} mm (±{2.0 ** -(bits + 1) * 1000:.3g} mm)",
                UserWarning,
                stacklevel=4,
            )
    else:
        bits = int(fractional_bits)
        if not 0 <= bits <= 23:
            raise FormatError(f"fractional_bits must lie in 0..23, got {fractional_bits}", name)
        if not fixed_point_fits(means, bits):
            fits = choose_fractional_bits(means, bits)
            hint = f"; {fits} fractional bits fit (step {2.0**-fits * 1000:.3g} mm)" if fits is not None else ""
            raise FormatError(
                f"local coordinates up to {np.abs(means).max():.6g} m do not fit SPZ's 24-bit fixed point at "
                f"{bits} fractional bits (range ±{2.0 ** (23 - bits):g} m){hint}",
                name,
            )
    return bits


def encode_spz(
    gaussians: GaussianSet,
    *,
    version: int = SPZ_VERSION,
    fractional_bits: int | None = None,
    sh1_bits: int = SH1_BITS,
    sh_rest_bits: int = SH_REST_BITS,
    name: str = "SPZ",
) -> tuple[SpzHeader, bytes]:
    """The header and the uncompressed payload (header bytes included) of an SPZ file for ``gaussians``.

    ``fractional_bits``: None picks 12 (the reference's choice) or, when the local coordinates do not fit, the
    largest number that fits, with a warning stating the step; an explicit value that does not fit raises
    :class:`FormatError`. ``name`` (the target file) goes into errors and warnings. Raises :class:`DataError` on
    NaN/inf parameters, zero quaternions and an empty set (the reference loader refuses ``numPoints`` 0).
    """
    if version not in SPZ_WRITABLE_VERSIONS:
        raise FormatError(f"SPZ version {version} cannot be written; expected one of {SPZ_WRITABLE_VERSIONS}", name)
    for label, bits in (("sh1_bits", sh1_bits), ("sh_rest_bits", sh_rest_bits)):
        if not 1 <= bits <= 8:
            raise FormatError(f"{label} must lie in 1..8, got {bits}", name)
    n = len(gaussians)
    if n == 0:
        raise DataError("no Gaussians to write: SPZ readers (the reference's loadSpz) refuse a point count of 0", name)
    try:
        gaussians.validate("Gaussian set")
    except DataError as err:
        raise DataError(err.problem, name) from err
    means = gaussians.means
    bits = _resolve_fractional_bits(means, fractional_bits, name)
    degree = gaussians.sh_degree
    header = SpzHeader(version=version, num_points=n, sh_degree=degree, fractional_bits=bits, flags=0)

    log_scales = np.asarray(gaussians.log_scales, np.float32)
    scale_code = (log_scales - np.float32(SPZ_LOG_SCALE_RANGE[0])) * np.float32(16.0)
    _warn_codes_outside(name, "log-scale", scale_code, "[-10, 5.94] (σ 45 µm .. 379 m)")
    color_code = np.asarray(gaussians.sh_dc, np.float32) * np.float32(SPZ_COLOR_SCALE * 255.0) + np.float32(127.5)
    _warn_codes_outside(name, "colour (f_dc)", color_code, "[-3.33, 3.33]")
    alpha = sigmoid(gaussians.logit_opacities).astype(np.float32) * np.float32(255.0)
    rotations = _pack_rotations_v2(gaussians.quats) if version == 2 else _pack_rotations_v3(gaussians.quats)
    sh, sh_clipped = _pack_sh(gaussians.sh_rest, sh1_bits, sh_rest_bits)  # type: ignore[arg-type]
    _warn_clipped(name, "SH rest", sh_clipped, sh.size, "[-1, 1]")

    planes = [
        HEADER.pack(SPZ_MAGIC, version, n, degree, bits, 0, 0),
        _pack_positions(means, bits).tobytes(),
        _to_u8(alpha).tobytes(),
        _to_u8(color_code).tobytes(),
        _to_u8(scale_code).tobytes(),
        rotations.tobytes(),
        sh.tobytes(),
    ]
    return header, b"".join(planes)


def write_spz(
    path: str | PathLike[str],
    gaussians: GaussianSet,
    *,
    version: int = SPZ_VERSION,
    fractional_bits: int | None = None,
    sh1_bits: int = SH1_BITS,
    sh_rest_bits: int = SH_REST_BITS,
) -> SpzHeader:
    """Write ``gaussians`` (local means) as an SPZ file, atomically; returns the header written.

    The caller writes the origin sidecar (:mod:`fusion.export`). See :func:`encode_spz` for the options and errors.
    """
    path = Path(path)
    header, payload = encode_spz(
        gaussians,
        version=version,
        fractional_bits=fractional_bits,
        sh1_bits=sh1_bits,
        sh_rest_bits=sh_rest_bits,
        name=str(path),
    )
    compressor = zlib.compressobj(6, zlib.DEFLATED, 16 + zlib.MAX_WBITS, 9)  # gzip wrapper, as the reference
    data = compressor.compress(payload) + compressor.flush()
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return header


def read_spz(path: str | PathLike[str]) -> SpzData:
    """Decode an SPZ file of version 2 or 3 (and its origin sidecar); float64 values, see :class:`SpzData`.

    Raises :class:`InputFileError` for a missing or unreadable file, :class:`FormatError` for anything that is not
    an SPZ file of a version this reader knows (version 4 names itself), a truncated payload or SH degree 4.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError("file does not exist", path)
    raw = path.read_bytes()
    if raw[:4] == b"NGSP":
        version = struct.unpack_from("<I", raw, 4)[0] if len(raw) >= 8 else "?"
        raise FormatError(
            f"SPZ version {version} (zstd streams) is not supported; versions {SPZ_READABLE_VERSIONS} are", path
        )
    if raw[:2] != b"\x1f\x8b":
        raise FormatError("not an SPZ file: neither a gzip stream (versions 1-3) nor an NGSP header", path)
    try:
        payload = zlib.decompress(raw, 16 + zlib.MAX_WBITS)
    except zlib.error as err:
        raise InputFileError(f"SPZ gzip stream is truncated or corrupt ({err})", path) from err
    if len(payload) < HEADER.size:
        raise FormatError(f"SPZ payload of {len(payload)} bytes is shorter than its {HEADER.size}-byte header", path)
    magic, version, n, degree, bits, flags, _reserved = HEADER.unpack_from(payload)
    if magic != SPZ_MAGIC:
        raise FormatError(f"bad SPZ magic 0x{magic:08x}, expected 0x{SPZ_MAGIC:08x} ('NGSP')", path)
    if version not in SPZ_READABLE_VERSIONS:
        raise FormatError(f"SPZ version {version} is not supported; versions {SPZ_READABLE_VERSIONS} are", path)
    if degree > 3:
        raise FormatError(f"SH degree {degree} is not supported (0..3)", path)
    header = SpzHeader(version=version, num_points=n, sh_degree=degree, fractional_bits=bits, flags=flags)
    k = (degree + 1) ** 2 - 1
    rot_bytes = 3 if version == 2 else 4
    sizes = [("positions", 9), ("alphas", 1), ("colors", 3), ("scales", 3), ("rotations", rot_bytes), ("sh", 3 * k)]
    needed = HEADER.size + n * sum(s for _, s in sizes)
    if len(payload) < needed:
        raise FormatError(
            f"SPZ payload has {len(payload)} bytes, {needed} expected for {n} splats at SH degree {degree}", path
        )
    planes: dict[str, np.ndarray] = {}
    offset = HEADER.size
    for key, width in sizes:
        planes[key] = np.frombuffer(payload, np.uint8, n * width, offset).reshape(n, width)
        offset += n * width

    p = planes["positions"].reshape(n, 3, 3).astype(np.int64)
    fixed = p[..., 0] | (p[..., 1] << 8) | (p[..., 2] << 16)
    fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)
    positions = fixed.astype(np.float64) * 2.0**-bits
    alphas = planes["alphas"][:, 0].astype(np.float64) / 255.0
    sh_dc = (planes["colors"].astype(np.float64) / 255.0 - 0.5) / SPZ_COLOR_SCALE
    log_scales = planes["scales"].astype(np.float64) / 16.0 - 10.0
    xyzw = _decode_rotations_v2(planes["rotations"]) if version == 2 else _decode_rotations_v3(planes["rotations"])
    sh_rest = ((planes["sh"].astype(np.float64) - 128.0) / 128.0).reshape(n, k, 3)
    return SpzData(
        header=header,
        positions=positions,
        log_scales=log_scales,
        quats=xyzw[:, [3, 0, 1, 2]],
        alphas=alphas,
        sh_dc=sh_dc,
        sh_rest=sh_rest,
        origin=read_origin(path),
    )


def _decode_rotations_v2(r: np.ndarray) -> np.ndarray:
    xyz = r.astype(np.float64) / 127.5 - 1.0
    w = np.sqrt(np.maximum(0.0, 1.0 - (xyz**2).sum(axis=1)))
    return np.concatenate([xyz, w[:, None]], axis=1)


def _decode_rotations_v3(r: np.ndarray) -> np.ndarray:
    packed = np.ascontiguousarray(r).view("<u4")[:, 0].astype(np.int64)
    largest = packed >> 30
    q = np.zeros((len(r), 4))
    rows = np.arange(len(r))
    for i in range(3, -1, -1):  # the last component stored sits in the lowest bits
        keep = largest != i
        mag = (packed & 0x1FF).astype(np.float64) * (math.sqrt(0.5) / 511.0)
        value = np.where((packed >> 9) & 1, -mag, mag)
        q[:, i] = np.where(keep, value, 0.0)
        packed = np.where(keep, packed >> 10, packed)
    q[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - (q**2).sum(axis=1)))
    return q
