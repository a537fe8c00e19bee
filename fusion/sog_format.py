"""PlayCanvas' SOG ("Spatially Ordered Gaussians", ``.sog`` or ``meta.json`` + WebP images), meta version 2.

Layout learnt from PlayCanvas' writer and reader — github.com/playcanvas/splat-transform ``src/lib/writers/
write-sog.ts``, ``src/lib/readers/read-sog.ts``, ``src/lib/spatial/quantize-1d-core.ts`` and ``k-means.ts``,
``src/lib/io/write/zip-file-system.ts`` (read in the sources of npm ``@playcanvas/splat-transform`` 3.7.0). No code
is copied: the layout is the format, the codebooks and the k-means are our own (any codebook is valid; the reader
only looks values up), written with numpy, Pillow's lossless WebP and :mod:`zipfile`.

What is written
---------------
Seven lossless RGBA WebP images of W × H texels, W = 4 · ceil(√N / 4), H = 4 · ceil(N / W / 4) (each ≤ 16383, so
N ≤ ~268 M); splat i (in Morton order of its position, as splat-transform sorts, see
:func:`fusion.compressed_ply_format.morton_order`) is texel i in row-major order; padding texels are 0. And
``meta.json`` (compact JSON)::

    {"version": 2, "asset": {"generator": "hybridsplat …"}, "count": N,
     "means": {"mins": [3], "maxs": [3], "files": ["means_l.webp", "means_u.webp"]},
     "scales": {"codebook": [256], "files": ["scales.webp"]},
     "quats": {"files": ["quats.webp"]},
     "sh0": {"codebook": [256], "files": ["sh0.webp"]},
     "shN": {"count": P, "bands": D, "codebook": [256], "files": ["shN_centroids.webp", "shN_labels.webp"]}}

- ``means_l`` / ``means_u``: per axis the low / high byte (R, G, B = x, y, z; A = 255) of a 16-bit code
  round(65535 · (l − min) / (max − min)) of l = sign(p) · ln(1 + |p|), p the local position (metres); ``mins`` /
  ``maxs`` are the per-axis extremes of l (float64 JSON numbers). Decoding: p = sign(l) · (e^|l| − 1).
- ``scales``: R, G, B = indices into ``scales.codebook`` of log σx, log σy, log σz (A = 255).
- ``quats``: the unit quaternion (w, x, y, z) with its largest |component| made positive; R, G, B = the other three
  in index order, each round(255 · (c/√2 + 1/2)); A = 252 + the index of the largest (0 = w … 3 = z).
- ``sh0``: R, G, B = indices into ``sh0.codebook`` of f_dc (the SH DC coefficients, not colours); A = round(255 · α).
- ``shN`` (degree D ≥ 1 only): the f_rest vectors are clustered by k-means into a palette of P = min(65536, the
  largest power of two ≤ N) centroids (splat-transform's size); ``shN_labels``: R = label & 255, G = label >> 8
  (B = 0, A = 255); ``shN_centroids``: 64 · (K−1) × ceil(P / 64) texels, centroid c's coefficient j at texel
  (row c // 64, column (c % 64) · (K−1) + j), R, G, B = indices into ``shN.codebook`` of its red, green, blue
  value (A = 255). K − 1 = 3, 8, 15 for D = 1, 2, 3.

The ``.sog`` bundle is a zip of those eight files, stored (no compression; WebP is compressed already), written in
splat-transform's order with meta.json last, a fixed 1980-01-01 timestamp and no extra fields, so the bytes are
the same on every run. The unbundled form (an output named ``…meta.json``, as splat-transform decides) writes the
same files into the folder of ``meta.json``. The float64 origin goes to the ``<name>.origin.json`` sidecar
(``x.origin.json`` for ``x.sog``, ``meta.origin.json`` for ``meta.json``), written by :mod:`fusion.export`; SOG has
no field for it. Fields (``source``, ``classification``…) are not stored. The engine's optional ``"model"`` entry
(antialiased / 2DGS) is not written (3DGS, the default); legacy version 1 (per-channel mins/maxs, no
``version``) is neither written nor read.

Codebooks (:func:`quantise_codebook`): 256 float32 entries over the pooled values of the three columns; 64 of them
are fixed on a uniform grid from the smallest to the largest value, the other 192 start at quantiles and move by 1-D
Lloyd iterations (deterministic) to where the values are dense. Every value maps to its nearest entry.

Precision (decoded minus input, per component)
-----------------------------------------------
- position: |Δp| ≤ (|p| + 1) · (e^(δ/2) − 1) with δ = (max − min)/65535 of the axis' log range: e.g. a scene in
  ±20 m (δ = 9.3e-5) errs ≤ 0.98 mm at 20 m and ≤ 0.05 mm at the origin. Large local coordinates lose precision:
  keep the origin inside the scene (our local frame does).
- log σ and f_dc: ≤ half the largest gap between consecutive codebook entries, ≤ (max − min) / 126 of the pooled
  values by the fixed grid (plus float32 rounding of the entries); in practice far less where values are dense.
  Colour 0.5 + C0 · f_dc errs C0 = 0.282 times the f_dc error.
- α: ≤ 1/510.
- rotation: the three stored components ≤ √2/510 = 2.8e-3; the largest ≤ 3e(1+e) / (1/2 + √(1/4 − 3e(1+e))) =
  8.4e-3 with e = 2.8e-3.
- SH rest: lossy by clustering (each splat gets its centroid; exact when N = P, i.e. N a power of two ≤ 65536),
  then each centroid value within half the largest gap of ``shN.codebook`` (≤ its range / 126).
No value is clipped: the codebooks and the position range span the data.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import DataError, FormatError, InputFileError
from core.gaussians import DecodedSplats, GaussianSet, sigmoid
from core.io.atomic import atomic_path
from core.io.origin import read_origin
from fusion.compressed_ply_format import morton_order

SOG_VERSION = 2
"""The meta.json version written and read (splat-transform 3.x and the PlayCanvas engine read 2)."""
CODEBOOK_SIZE = 256
GRID_ENTRIES = 64
"""Codebook entries fixed on a uniform grid over the values' range (the error bound); the rest follow density."""
CODEBOOK_ITERATIONS = 20
SH_ITERATIONS = 10
"""k-means iterations for the SH palette (splat-transform's default)."""
MAX_PALETTE = 65536
MAX_TEXTURE = 16383
"""WebP's largest dimension."""
WEBP_OPTIONS = {"lossless": True, "exact": True, "quality": 80, "method": 4}
"""Pillow's lossless WebP: ``exact`` keeps the RGB of transparent texels; quality/method are the effort (libwebp's
defaults: quality 100 is 10× slower for 0.1 % smaller files)."""
FLAT_KMEANS_LIMIT = 1024
"""Palettes up to this size are clustered by plain k-means; larger ones in two levels (:func:`kmeans`)."""

MEANS_FILES = ("means_l.webp", "means_u.webp")
SHN_FILES = ("shN_centroids.webp", "shN_labels.webp")
FILE_ORDER = (*MEANS_FILES, "quats.webp", "scales.webp", "sh0.webp", *SHN_FILES)
"""The order splat-transform writes the images into a bundle (meta.json comes last)."""
_SH_COEFFS = (0, 3, 8, 15)
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


@dataclass(frozen=True)
class SogLayout:
    """What :func:`write_sog` wrote: count, texture size, SH degree, palette size (0 at degree 0), the files and
    ``order`` (N,) int64, the input index of each splat in file order (file splat i is input splat ``order[i]``)."""

    num_splats: int
    width: int
    height: int
    sh_degree: int
    palette_size: int
    files: tuple[str, ...]
    order: np.ndarray


@dataclass
class SogData(DecodedSplats):
    """Decoded SOG content, float64, in file order and the file's (local) frame.

    positions (N, 3) metres; log_scales (N, 3); quats (N, 4) unit (w, x, y, z); alphas (N,) in [0, 1]; sh_dc (N, 3);
    sh_rest (N, K−1, 3); meta: the parsed meta.json; origin (3,) from the sidecar (zeros without one).
    """

    positions: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    alphas: np.ndarray
    sh_dc: np.ndarray
    sh_rest: np.ndarray
    meta: dict
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))


def is_sog_path(path: str | PathLike[str]) -> bool:
    """Whether ``path`` names a SOG output: ``*.sog`` (bundle) or ``*meta.json`` but not ``lod-meta.json``
    (unbundled; splat-transform's rule)."""
    name = Path(path).name.lower()
    return name.endswith(".sog") or (name.endswith("meta.json") and not name.endswith("lod-meta.json"))


# -- sizes ---------------------------------------------------------------------------------------------------------
def texture_size(n: int) -> tuple[int, int]:
    """(width, height) of the per-splat textures for ``n`` ≥ 1 splats: splat-transform's 4 · ceil(√n / 4) and
    4 · ceil(n / width / 4), in exact integers."""
    root = math.isqrt(n - 1) + 1 if n > 0 else 0  # ceil(√n)
    width = 4 * max(1, -(-root // 4))
    return width, 4 * max(1, -(-n // (4 * width)))


def palette_size(n: int) -> int:
    """SH palette size for ``n`` splats: min(64, 2^floor(log2(n / 1024))) · 1024 = the largest power of two ≤ n,
    at most 65536 (splat-transform's formula); 0 for no splats."""
    return 0 if n < 1 else min(MAX_PALETTE, 1 << (n.bit_length() - 1))


# -- transforms ----------------------------------------------------------------------------------------------------
def log_transform(p: np.ndarray) -> np.ndarray:
    """sign(p) · ln(1 + |p|), elementwise (float64)."""
    p = np.asarray(p, np.float64)
    return np.sign(p) * np.log1p(np.abs(p))


def inverse_log_transform(v: np.ndarray) -> np.ndarray:
    """sign(v) · (e^|v| − 1), the inverse of :func:`log_transform`."""
    v = np.asarray(v, np.float64)
    return np.sign(v) * np.expm1(np.abs(v))


# -- codebooks and clustering --------------------------------------------------------------------------------------
def _nearest(codebook: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Index of the nearest entry of a non-decreasing ``codebook`` for each value (ties go up)."""
    c = codebook.astype(np.float64)
    return np.searchsorted((c[:-1] + c[1:]) / 2, values, side="right").astype(np.int64)


def quantise_codebook(values: np.ndarray, size: int = CODEBOOK_SIZE) -> tuple[np.ndarray, np.ndarray]:
    """A non-decreasing float32 codebook (``size``,) for the finite ``values`` (any shape) and the uint8 index of
    each value's nearest entry (``values``' shape).

    ``GRID_ENTRIES`` entries sit on a uniform grid from min to max (so no value errs by more than (max − min) /
    (2 (GRID_ENTRIES − 1))); the others start at quantiles and take ``CODEBOOK_ITERATIONS`` Lloyd steps (each
    moves to the mean of the values nearest to it). Deterministic.
    """
    flat = np.asarray(values, np.float64).reshape(-1)
    if flat.size == 0:
        return np.zeros(size, np.float32), np.zeros(np.shape(values), np.uint8)
    v = np.sort(flat)
    lo, hi = v[0], v[-1]
    if hi - lo <= 0:
        codebook = np.full(size, lo, np.float32)
        return codebook, np.zeros(np.shape(values), np.uint8)
    grid = np.linspace(lo, hi, GRID_ENTRIES)
    free_n = size - GRID_ENTRIES
    free = v[np.minimum(((2 * np.arange(free_n) + 1) * len(v)) // (2 * free_n), len(v) - 1)]
    prefix = np.concatenate([[0.0], np.cumsum(v)])
    for _ in range(CODEBOOK_ITERATIONS):
        entries = np.concatenate([grid, free])
        order = np.argsort(entries, kind="stable")
        sorted_entries = entries[order]
        mids = (sorted_entries[:-1] + sorted_entries[1:]) / 2
        bounds = np.concatenate([[0], np.searchsorted(v, mids, side="right"), [len(v)]])
        counts = np.diff(bounds)
        sums = prefix[bounds[1:]] - prefix[bounds[:-1]]
        means = np.where(counts > 0, sums / np.maximum(counts, 1), sorted_entries)
        updated = entries.copy()
        updated[order] = means
        free = updated[GRID_ENTRIES:]
    codebook = np.sort(np.concatenate([grid, free])).astype(np.float32)
    codebook[0], codebook[-1] = np.float32(lo), np.float32(hi)  # keep the ends exact to float32
    codebook = np.maximum.accumulate(codebook)
    labels = _nearest(codebook, flat).astype(np.uint8)
    return codebook, labels.reshape(np.shape(values))


def _assign(points: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """Nearest centroid (squared Euclidean) of each point: argmax of x·c − |c|²/2, one matrix product per block of
    rows (≤ 64 MB of scores)."""
    c64 = centroids.astype(np.float64)
    augmented = np.concatenate([c64, -0.5 * (c64**2).sum(axis=1, keepdims=True)], axis=1).astype(np.float32).T
    labels = np.empty(len(points), np.int64)
    block = max(1, (1 << 24) // max(1, len(centroids)))
    ones = np.ones((min(block, len(points)), 1), np.float32)
    for start in range(0, len(points), block):
        x = points[start : start + block]
        scores = np.concatenate([x, ones[: len(x)]], axis=1) @ augmented
        labels[start : start + block] = np.argmax(scores, axis=1)
    return labels


def _lloyd(x: np.ndarray, k: int, iterations: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Plain Lloyd's k-means of float32 ``x`` seeded with ``k`` distinct points; empty clusters keep their centroid."""
    n = len(x)
    if k >= n:
        return x.copy(), np.arange(n, dtype=np.int64)
    rng = np.random.default_rng(seed)
    centroids = x[np.sort(rng.choice(n, size=k, replace=False))].copy()
    labels = _assign(x, centroids)
    for _ in range(iterations):
        counts = np.bincount(labels, minlength=k)
        sums = np.stack([np.bincount(labels, weights=x[:, j], minlength=k) for j in range(x.shape[1])], axis=1)
        filled = counts > 0
        centroids[filled] = (sums[filled] / counts[filled, None]).astype(np.float32)
        labels = _assign(x, centroids)
    return centroids, labels


def _split_budget(sizes: np.ndarray, k: int) -> np.ndarray:
    """Split ``k`` centroids over groups of ``sizes`` points: ≥ 1 each, ≤ its size, about proportional."""
    share = np.minimum(sizes, np.maximum(1, np.floor(k * sizes / sizes.sum()))).astype(np.int64)
    for i in np.argsort(-sizes, kind="stable"):  # hand out what rounding left, largest groups first
        if share.sum() >= k:
            break
        share[i] = min(sizes[i], share[i] + k - share.sum())
    return share


# Hand-written rather than sklearn's KMeans: its cost per step is N · k · D too, minutes at splat-transform's 65536
# palette entries; the two-level split below is what makes that size tractable, and twenty lines of Lloyd's steps
# keep the bytes of a .sog identical across library versions.
def kmeans(points: np.ndarray, k: int, iterations: int = SH_ITERATIONS, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """k-means of ``points`` (N, D) into ``k`` clusters: centroids (k', D) float32 (k' = min(k, N)) and labels (N,).

    Up to ``FLAT_KMEANS_LIMIT`` clusters: Lloyd's algorithm, ``iterations`` steps, seeded with distinct points drawn
    by ``np.random.default_rng(seed)``; a cluster left empty keeps its centroid; ``k ≥ N`` makes every point its own
    centroid. Larger ``k`` (splat-transform's palettes reach 65536, which costs N · k · D per step on a CPU): two
    levels, ⌈√k⌉ coarse clusters, then each coarse cluster's points into a share of ``k`` proportional to their
    count; a point's label is its nearest centroid within its coarse cluster (N · 2√k · D per step). Deterministic.
    """
    x = np.ascontiguousarray(points, np.float32)
    if k <= FLAT_KMEANS_LIMIT or k >= len(x):
        return _lloyd(x, k, iterations, seed)
    coarse_k = math.isqrt(k - 1) + 1
    _, coarse = _lloyd(x, coarse_k, iterations, seed)
    groups = np.unique(coarse)
    members = [np.flatnonzero(coarse == g) for g in groups]
    share = _split_budget(np.array([len(m) for m in members]), k)
    centroids, labels, base = [], np.empty(len(x), np.int64), 0
    for i, (index, count) in enumerate(zip(members, share, strict=True)):
        sub_centroids, sub_labels = _lloyd(x[index], int(count), iterations, seed + 1 + i)
        centroids.append(sub_centroids)
        labels[index] = base + sub_labels
        base += len(sub_centroids)
    return np.concatenate(centroids), labels


# -- encoding ------------------------------------------------------------------------------------------------------
def _texture(rows: np.ndarray, width: int, height: int) -> np.ndarray:
    """(N, 4) uint8 texel values -> (height, width, 4) image, row-major, zero padding."""
    out = np.zeros((width * height, 4), np.uint8)
    out[: len(rows)] = rows
    return out.reshape(height, width, 4)


def _rgba(rgb: np.ndarray, alpha: np.ndarray | int = 255) -> np.ndarray:
    a = np.broadcast_to(np.asarray(alpha, np.uint8), (len(rgb),))
    return np.concatenate([rgb.astype(np.uint8), a[:, None]], axis=1)


def _encode_means(means: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray]:
    """meta ``means`` (without files) and the low/high byte rows (N, 4)."""
    log = log_transform(means)
    mins, maxs = log.min(axis=0), log.max(axis=0)
    extent = maxs - mins
    t = np.where(extent > 0, (log - mins) / np.where(extent > 0, extent, 1.0), 0.0)
    code = np.clip(np.floor(t * 65535.0 + 0.5), 0, 65535).astype(np.uint32)
    low, high = _rgba(code & np.uint32(0xFF)), _rgba(code >> np.uint32(8))
    return {"mins": [float(v) for v in mins], "maxs": [float(v) for v in maxs]}, low, high


def _encode_quats(quats_wxyz: np.ndarray) -> np.ndarray:
    q = np.asarray(quats_wxyz, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    rows = np.arange(len(q))
    largest = np.argmax(np.abs(q), axis=1)
    q = np.where((q[rows, largest] < 0)[:, None], -q, q)
    others = np.array([[j for j in range(4) if j != i] for i in range(4)])[largest]  # (N, 3) index order
    stored = np.take_along_axis(q, others, axis=1)
    codes = np.clip(np.floor(255.0 * (stored / math.sqrt(2.0) + 0.5) + 0.5), 0, 255)
    return _rgba(codes, (252 + largest).astype(np.uint8))


def _encode_sh_rest(sh_rest: np.ndarray, iterations: int, seed: int) -> tuple[dict, np.ndarray, np.ndarray, int]:
    """meta ``shN`` (without files), the centroid image, the label rows (N, 4) and the palette size."""
    n, coeffs, _ = sh_rest.shape
    flat = np.ascontiguousarray(sh_rest.transpose(0, 2, 1)).reshape(n, 3 * coeffs)  # channel-major, as f_rest
    centroids, labels = kmeans(flat, palette_size(n), iterations, seed)
    k = len(centroids)
    codebook, codes = quantise_codebook(centroids)
    codes = codes.reshape(len(centroids), 3, coeffs).transpose(0, 2, 1)  # (P, coeffs, rgb)
    rows = math.ceil(len(centroids) / 64)
    image = np.zeros((rows * 64, coeffs, 4), np.uint8)
    image[: len(centroids), :, :3] = codes
    image[: len(centroids), :, 3] = 255
    image = image.reshape(rows, 64 * coeffs, 4)
    label_rows = _rgba(np.stack([labels & 0xFF, labels >> 8, np.zeros_like(labels)], axis=1))
    meta = {"count": k, "bands": int(round(math.sqrt(coeffs + 1))) - 1, "codebook": [float(c) for c in codebook]}
    return meta, image, label_rows, k


def encode_sog(
    gaussians: GaussianSet,
    *,
    sort: bool = True,
    sh_iterations: int = SH_ITERATIONS,
    seed: int = 0,
    name: str = "SOG",
) -> tuple[SogLayout, dict, dict[str, np.ndarray]]:
    """Layout, meta.json content and the images (file name -> (H, W, 4) uint8) for ``gaussians`` (local means).

    ``sort``: Morton order (True) or the input order; ``sh_iterations`` and ``seed``: the SH palette's k-means.
    Raises :class:`DataError` naming ``name`` on an empty set, NaN/inf parameters or zero quaternions, and
    :class:`FormatError` when the textures would exceed WebP's 16383 texels.
    """
    n = len(gaussians)
    if n == 0:
        raise DataError("no Gaussians to write: a SOG file needs at least one splat", name)
    try:
        gaussians.validate("Gaussian set")
    except DataError as err:
        raise DataError(err.problem, name) from err
    width, height = texture_size(n)
    if max(width, height) > MAX_TEXTURE:
        raise FormatError(f"{n} splats need {width}×{height} texels; WebP (and SOG) allow {MAX_TEXTURE}", name)
    order = morton_order(gaussians.means) if sort else np.arange(n, dtype=np.int64)
    gs = gaussians.subset(order)

    means_meta, low, high = _encode_means(gs.means)
    scale_book, scale_codes = quantise_codebook(gs.log_scales.astype(np.float64))
    dc_book, dc_codes = quantise_codebook(gs.sh_dc.astype(np.float64))
    alpha = np.clip(np.floor(sigmoid(gs.logit_opacities) * 255.0 + 0.5), 0, 255).astype(np.uint8)
    images = {
        MEANS_FILES[0]: _texture(low, width, height),
        MEANS_FILES[1]: _texture(high, width, height),
        "quats.webp": _texture(_encode_quats(gs.quats), width, height),
        "scales.webp": _texture(_rgba(scale_codes), width, height),
        "sh0.webp": _texture(_rgba(dc_codes, alpha), width, height),
    }
    from hybridsplat import __version__

    meta: dict = {
        "version": SOG_VERSION,
        "asset": {"generator": f"hybridsplat v{__version__}"},
        "count": n,
        "means": {**means_meta, "files": list(MEANS_FILES)},
        "scales": {"codebook": [float(c) for c in scale_book], "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": [float(c) for c in dc_book], "files": ["sh0.webp"]},
    }
    k = 0
    if gs.sh_degree > 0:
        shn_meta, centroid_image, label_rows, k = _encode_sh_rest(gs.sh_rest, sh_iterations, seed)  # type: ignore[arg-type]
        images[SHN_FILES[0]] = centroid_image
        images[SHN_FILES[1]] = _texture(label_rows, width, height)
        meta["shN"] = {**shn_meta, "files": list(SHN_FILES)}
    files = tuple(f for f in FILE_ORDER if f in images)
    layout = SogLayout(n, width, height, gs.sh_degree, k, (*files, "meta.json"), order)
    return layout, meta, images


def encode_webp(image: np.ndarray) -> bytes:
    """Lossless WebP bytes of an (H, W, 4) uint8 RGBA image (Pillow; every texel kept exactly)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image), "RGBA").save(buf, format="WEBP", **WEBP_OPTIONS)
    return buf.getvalue()


def _meta_bytes(meta: dict) -> bytes:
    return json.dumps(meta, separators=(",", ":"), allow_nan=False).encode("utf-8")


def _zip_bundle(entries: list[tuple[str, bytes]]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_STORED) as bundle:
        for name, data in entries:
            info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
            info.external_attr = 0o644 << 16
            bundle.writestr(info, data, compress_type=zipfile.ZIP_STORED)
    return buf.getvalue()


def write_sog(
    path: str | PathLike[str],
    gaussians: GaussianSet,
    *,
    sort: bool = True,
    sh_iterations: int = SH_ITERATIONS,
    seed: int = 0,
) -> SogLayout:
    """Write ``gaussians`` (local means) as SOG, atomically: a ``.sog`` bundle, or for a path named ``…meta.json``
    that file and its images in its folder (each file atomic; all or none inside an output transaction).

    The caller writes the origin sidecar (:mod:`fusion.export`). Errors as :func:`encode_sog`, and
    :class:`FormatError` for a path that is neither form.
    """
    path = Path(path)
    if not is_sog_path(path):
        raise FormatError("a SOG output must be named *.sog (bundle) or meta.json (unbundled)", path)
    layout, meta, images = encode_sog(gaussians, sort=sort, sh_iterations=sh_iterations, seed=seed, name=str(path))
    entries = [(f, encode_webp(images[f])) for f in layout.files[:-1]]
    entries.append(("meta.json", _meta_bytes(meta)))
    if path.name.lower().endswith(".sog"):
        with atomic_path(path) as tmp:
            tmp.write_bytes(_zip_bundle(entries))
    else:
        for name, data in entries:
            with atomic_path(path if name == "meta.json" else path.parent / name) as tmp:
                tmp.write_bytes(data)
    return layout


# -- reading -------------------------------------------------------------------------------------------------------
def _load_files(path: Path) -> tuple[dict, Callable[[str], bytes]]:
    """meta.json content and a ``read(name) -> bytes`` for a bundle or a meta.json."""
    if not path.is_file():
        raise InputFileError("SOG file not found", path)
    if path.name.lower().endswith(".sog") or zipfile.is_zipfile(path):
        try:
            bundle = zipfile.ZipFile(path)
        except zipfile.BadZipFile as err:
            raise FormatError(f"not a SOG bundle (not a zip archive: {err})", path) from err
        names = set(bundle.namelist())

        def read(name: str) -> bytes:
            if name not in names:
                raise FormatError(f"SOG bundle lacks {name!r} (holds {sorted(names)})", path)
            return bundle.read(name)

        raw = read("meta.json")
    else:

        def read(name: str) -> bytes:
            file = path.parent / name
            if not file.is_file():
                raise InputFileError(f"SOG image {name!r} named by {path.name} is missing", file)
            return file.read_bytes()

        raw = path.read_bytes()
    try:
        meta = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise FormatError(f"SOG meta.json is not valid JSON ({err})", path) from err
    if not isinstance(meta, dict):
        raise FormatError("SOG meta.json must hold an object", path)
    return meta, read


def _decode_webp(data: bytes, name: str, count: int, path: Path) -> np.ndarray:
    """(H, W, 4) uint8 texels of a WebP image; checks that it holds ``count`` texels."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(data)) as img:
            rgba = np.asarray(img.convert("RGBA"))
    except (UnidentifiedImageError, OSError) as err:
        raise FormatError(f"SOG image {name!r} is not a readable WebP ({err})", path) from err
    if rgba.shape[0] * rgba.shape[1] < count:
        raise FormatError(f"SOG image {name!r} has {rgba.shape[1]}×{rgba.shape[0]} texels for {count} splats", path)
    return rgba


def _codebook(meta: dict, key: str, path: Path) -> np.ndarray:
    book = np.asarray(meta[key].get("codebook", []), np.float64).astype(np.float32)
    if book.shape != (CODEBOOK_SIZE,) or not np.isfinite(book).all():
        raise FormatError(f"SOG {key}.codebook must hold {CODEBOOK_SIZE} finite numbers", path)
    return book.astype(np.float64)


def _check_meta(meta: dict, path: Path) -> int:
    version = meta.get("version")
    if version != SOG_VERSION:
        found = "none (a version 1 file)" if version is None else repr(version)
        raise FormatError(f"SOG meta.json version {found} is not read; only version {SOG_VERSION}", path)
    for key in ("means", "scales", "quats", "sh0"):
        if not isinstance(meta.get(key), dict) or not meta[key].get("files"):
            raise FormatError(f"SOG meta.json lacks {key!r} with its files", path)
    count = meta.get("count")
    if not isinstance(count, int) or count < 0:
        raise FormatError(f"SOG meta.json count must be a non-negative integer, got {count!r}", path)
    return count


def _decode_quats(texels: np.ndarray) -> np.ndarray:
    tag = texels[:, 3].astype(np.int64)
    stored = (texels[:, :3].astype(np.float64) / 255.0 * 2.0 - 1.0) / math.sqrt(2.0)
    largest = np.clip(tag - 252, 0, 3)
    q = np.zeros((len(texels), 4))
    others = np.array([[j for j in range(4) if j != i] for i in range(4)])[largest]
    np.put_along_axis(q, others, stored, axis=1)
    q[np.arange(len(q)), largest] = np.sqrt(np.maximum(0.0, 1.0 - (stored**2).sum(axis=1)))
    q[(tag < 252) | (tag > 255)] = [1.0, 0.0, 0.0, 0.0]  # what splat-transform decodes for a bad tag
    return q


def _decode_sh_rest(meta: dict, read: Callable[[str], bytes], count: int, path: Path) -> np.ndarray:
    shn = meta.get("shN")
    bands = shn.get("bands", 0) if isinstance(shn, dict) else 0
    if bands not in (1, 2, 3):
        return np.zeros((count, 0, 3))
    coeffs = _SH_COEFFS[bands]
    files = shn.get("files", [])
    if len(files) != 2:
        raise FormatError("SOG shN.files must name the centroids and the labels images", path)
    book = _codebook(meta, "shN", path)
    cen = _decode_webp(read(files[0]), files[0], 0, path)
    if cen.shape[1] != 64 * coeffs:
        raise FormatError(f"SOG shN centroids image is {cen.shape[1]} texels wide; expected {64 * coeffs}", path)
    lab = _decode_webp(read(files[1]), files[1], count, path).reshape(-1, 4)[:count]
    labels = lab[:, 0].astype(np.int64) | (lab[:, 1].astype(np.int64) << 8)
    palette = int(shn.get("count", 0))
    centroids = cen.reshape(-1, coeffs, 4)[:, :, :3]  # (rows·64, coeffs, rgb) codes
    valid = (labels < palette) & (labels < len(centroids))
    out = np.zeros((count, coeffs, 3))
    out[valid] = book[centroids[labels[valid]]]
    return out


def read_sog(path: str | PathLike[str]) -> SogData:
    """Decode a SOG file (a ``.sog`` bundle or an unbundled ``meta.json``) of meta version 2, and its origin
    sidecar, with splat-transform's formulas in float64; see :class:`SogData`.

    Raises :class:`InputFileError` for a missing file or image, :class:`FormatError` for a bad zip, JSON, meta
    version (version 1 names itself), missing entries or images too small for the count.
    """
    path = Path(path)
    meta, read = _load_files(path)
    count = _check_meta(meta, path)
    tex = {
        key: [_decode_webp(read(f), f, count, path).reshape(-1, 4)[:count] for f in meta[key]["files"]]
        for key in ("means", "scales", "quats", "sh0")
    }
    mins = np.asarray(meta["means"]["mins"], np.float64)
    maxs = np.asarray(meta["means"]["maxs"], np.float64)
    extent = np.where(maxs - mins != 0, maxs - mins, 1.0)
    low, high = tex["means"][0][:, :3].astype(np.float64), tex["means"][1][:, :3].astype(np.float64)
    positions = inverse_log_transform(mins + extent * ((low + 256.0 * high) / 65535.0))
    sh0 = tex["sh0"][0]
    return SogData(
        positions=positions,
        log_scales=_codebook(meta, "scales", path)[tex["scales"][0][:, :3]],
        quats=_decode_quats(tex["quats"][0]),
        alphas=sh0[:, 3].astype(np.float64) / 255.0,
        sh_dc=_codebook(meta, "sh0", path)[sh0[:, :3]],
        sh_rest=_decode_sh_rest(meta, read, count, path),
        meta=meta,
        origin=read_origin(path),
    )
