"""The ``.splat`` format of antimatter15's WebGL viewer (also read by gsplat.js, SuperSplat, splat-transform).

No header; N records of 32 bytes, little-endian:

=========  ===========  ======================================================================
bytes      type         content
=========  ===========  ======================================================================
0–11       float32 × 3  position x, y, z (metres, local frame: add the sidecar origin for world)
12–23      float32 × 3  scale σ per axis, activated: exp(log-scale)
24–27      uint8 × 4    R, G, B from the SH DC term (0.5 + C0 · f_dc) · 255, A = sigmoid(opacity) · 255
28–31      uint8 × 4    rotation quaternion (w, x, y, z), normalised, stored as q · 128 + 128 clipped to 0..255
=========  ===========  ======================================================================

antimatter15's ``convert.py`` truncates (``astype(uint8)``) when quantising; we round to the nearest code instead,
so an 8-bit MVS colour survives the float32 round trip through f_dc exactly (truncation turns 200 into 199 when
float32 rounding lands just below). Readers decode both the same way. Records are sorted by importance
(σx·σy·σz · α, descending) as that converter does, so progressive loaders show the large opaque splats first.
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import DataError, FormatError, InputFileError
from core.gaussians import SH_C0, GaussianSet, sigmoid
from core.io.atomic import atomic_path

SPLAT_RECORD = np.dtype([("position", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)), ("rot", "u1", (4,))])
"""One 32-byte ``.splat`` record."""

assert SPLAT_RECORD.itemsize == 32  # layout constant, not input validation


@dataclass
class SplatData:
    """Decoded ``.splat`` content: positions (N, 3) float32, scales (N, 3) float32 (σ, metres),
    rgba (N, 4) uint8, quats (N, 4) float32 (w, x, y, z) decoded as (byte − 128) / 128."""

    positions: np.ndarray
    scales: np.ndarray
    rgba: np.ndarray
    quats: np.ndarray

    def __len__(self) -> int:
        return len(self.positions)


def encode_splat(gaussians: GaussianSet, sort: bool = True) -> np.ndarray:
    """The (N,) structured array of :data:`SPLAT_RECORD` for a Gaussian set (local means, SH DC only)."""
    n = len(gaussians)
    rec = np.zeros(n, dtype=SPLAT_RECORD)
    rec["position"] = gaussians.means.astype(np.float32)
    rec["scale"] = np.exp(gaussians.log_scales.astype(np.float64)).astype(np.float32)
    color = 0.5 + SH_C0 * gaussians.sh_dc.astype(np.float64)
    alpha = sigmoid(gaussians.logit_opacities.astype(np.float64))
    rgba = np.concatenate([color, alpha[:, None]], axis=1)
    rec["rgba"] = np.clip(np.rint(rgba * 255.0), 0, 255).astype(np.uint8)
    q = gaussians.quats.astype(np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    rec["rot"] = np.clip(np.rint(q * 128.0 + 128.0), 0, 255).astype(np.uint8)
    if sort and n:
        importance = np.exp(gaussians.log_scales.astype(np.float64).sum(axis=1)) * alpha
        rec = rec[np.argsort(-importance, kind="stable")]
    return rec


def write_splat(path: str | PathLike[str], gaussians: GaussianSet, sort: bool = True) -> Path:
    """Write ``gaussians`` as a ``.splat`` file (32 · N bytes, atomically). Returns the path.

    Positions are the float32 local means; the caller writes the origin sidecar (see :mod:`fusion.export`).
    """
    path = Path(path)
    data = encode_splat(gaussians, sort=sort)
    with atomic_path(path) as tmp:
        data.tofile(tmp)
    return path


def read_splat(path: str | PathLike[str]) -> SplatData:
    """Decode a ``.splat`` file (independent of the writer's code path apart from the record dtype)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError("file does not exist", path)
    size = path.stat().st_size
    if size % SPLAT_RECORD.itemsize:
        raise FormatError(f".splat size {size} bytes is not a multiple of {SPLAT_RECORD.itemsize}", path)
    rec = np.fromfile(path, dtype=SPLAT_RECORD)
    for key in ("position", "scale"):
        bad = ~np.isfinite(rec[key]).all(axis=1)
        if bad.any():
            raise DataError(
                f"{int(bad.sum())} splats have NaN or infinite {key} (first: splat {int(np.flatnonzero(bad)[0])})",
                path,
            )
    quats = (rec["rot"].astype(np.float32) - 128.0) / 128.0
    return SplatData(rec["position"].copy(), rec["scale"].copy(), rec["rgba"].copy(), quats)
