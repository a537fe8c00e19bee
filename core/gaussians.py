"""Sets of 3D Gaussians, stored pre-activation as 3DGS viewers expect.

Storage (per Gaussian i):
- ``means[i]``: float64 (3,), metres, relative to ``origin`` (float64 (3,), world coordinates).
- ``log_scales[i]``: float32 (3,), natural log of the standard deviations σ (metres).
- ``quats[i]``: float32 (4,), rotation as a quaternion (w, x, y, z), not necessarily normalised.
- ``logit_opacities[i]``: float32, logit(α).
- ``sh_dc[i]``: float32 (3,), SH degree-0 coefficient per RGB channel; colour = 0.5 + C0 · sh_dc.
- ``sh_rest[i]``: float32 (K-1, 3) with K = (degree+1)², coefficient-major in memory (as gsplat and the
  original 3DGS code hold ``features_rest``); the 3DGS PLY stores it channel-major (``f_rest_*``: all R
  coefficients, then G, then B) — the transposition is done by the PLY reader/writer only.
- ``fields``: optional per-Gaussian extras kept through merge and export (e.g. ``source``, ``classification``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from core.errors import DataError

SH_C0 = 0.28209479177387814
"""The degree-0 real spherical-harmonic constant, 1 / (2 √π)."""


def num_sh_bases(degree: int) -> int:
    """Number of SH coefficients per channel for a degree: (degree + 1)²."""
    return (degree + 1) ** 2


def sh_degree_from_rest(num_rest: int) -> int:
    """SH degree from the number of non-DC coefficients per channel (0, 3, 8 or 15)."""
    degree = int(round(math.sqrt(num_rest + 1))) - 1
    if degree < 0 or degree > 3 or num_sh_bases(degree) - 1 != num_rest:
        raise DataError(f"{num_rest} SH rest coefficients per channel is not a degree 0..3 layout (0, 3, 8 or 15)")
    return degree


def sigmoid(x: np.ndarray) -> np.ndarray:
    """Numerically stable logistic function."""
    x = np.asarray(x, dtype=np.float64)
    out = np.empty_like(x)
    pos = x >= 0
    out[pos] = 1.0 / (1.0 + np.exp(-x[pos]))
    e = np.exp(x[~pos])
    out[~pos] = e / (1.0 + e)
    return out


def logit(p: np.ndarray, eps: float = 1e-7) -> np.ndarray:
    """Inverse of :func:`sigmoid`, with p clamped to [eps, 1 - eps] so the result stays finite."""
    p = np.clip(np.asarray(p, dtype=np.float64), eps, 1.0 - eps)
    return np.log(p) - np.log1p(-p)


@dataclass
class GaussianSet:
    """N Gaussians with pre-activation parameters (see the module docstring for layouts and units)."""

    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    logit_opacities: np.ndarray
    sh_dc: np.ndarray
    sh_rest: np.ndarray | None = None
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    fields: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.means = np.ascontiguousarray(np.asarray(self.means, dtype=np.float64).reshape(-1, 3))
        n = len(self.means)
        self.log_scales = np.asarray(self.log_scales, dtype=np.float32).reshape(n, 3)
        self.quats = np.asarray(self.quats, dtype=np.float32).reshape(n, 4)
        self.logit_opacities = np.asarray(self.logit_opacities, dtype=np.float32).reshape(n)
        self.sh_dc = np.asarray(self.sh_dc, dtype=np.float32).reshape(n, 3)
        if self.sh_rest is None:
            self.sh_rest = np.zeros((n, 0, 3), dtype=np.float32)
        rest = np.asarray(self.sh_rest, dtype=np.float32)
        if rest.ndim == 3 and rest.shape[0] == n and rest.shape[2] == 3:
            self.sh_rest = rest
        elif n == 0:
            raise DataError("an empty Gaussian set needs sh_rest of shape (0, K-1, 3) to fix its SH degree")
        else:
            self.sh_rest = rest.reshape(n, -1, 3)
        sh_degree_from_rest(self.sh_rest.shape[1])
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        self.fields = {k: np.asarray(v).reshape(-1) for k, v in self.fields.items()}
        for k, v in self.fields.items():
            if len(v) != n:
                raise DataError(f"Gaussian field {k!r} has {len(v)} entries for {n} Gaussians")

    def __len__(self) -> int:
        return len(self.means)

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_rest(self.sh_rest.shape[1])  # type: ignore[union-attr]

    # -- activations ---------------------------------------------------------------------------
    @property
    def scales(self) -> np.ndarray:
        """σ per axis, metres, (N, 3) float32."""
        return np.exp(self.log_scales.astype(np.float64)).astype(np.float32)

    @property
    def opacities(self) -> np.ndarray:
        """α in (0, 1), (N,) float32."""
        return sigmoid(self.logit_opacities).astype(np.float32)

    @property
    def unit_quats(self) -> np.ndarray:
        """Normalised quaternions (w, x, y, z), (N, 4) float32."""
        q = self.quats.astype(np.float64)
        return (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)

    @property
    def base_colors(self) -> np.ndarray:
        """View-independent RGB in [0, 1] from the DC term, 0.5 + C0 · sh_dc, clipped; (N, 3) float32."""
        return np.clip(0.5 + SH_C0 * self.sh_dc, 0.0, 1.0).astype(np.float32)

    @property
    def world_means(self) -> np.ndarray:
        """(N, 3) float64 world coordinates."""
        return self.means + self.origin

    @property
    def sh_coeffs(self) -> np.ndarray:
        """All SH coefficients (N, K, 3), DC first (gsplat's ``colors`` layout for ``sh_degree``)."""
        return np.concatenate([self.sh_dc[:, None, :], self.sh_rest], axis=1)  # type: ignore[list-item]

    # -- checks and edits ------------------------------------------------------------------------
    def validate(self, name: str = "Gaussian set") -> None:
        """Raise :class:`DataError` on NaN/inf in any parameter or a zero-norm quaternion."""
        for attr in ("means", "log_scales", "quats", "logit_opacities", "sh_dc", "sh_rest"):
            values = getattr(self, attr)
            bad = ~np.isfinite(values.reshape(len(self), -1)).all(axis=1) if len(self) else np.zeros(0, bool)
            if bad.any():
                raise DataError(
                    f"{name}: {int(bad.sum())} Gaussians have NaN or infinite {attr} "
                    f"(first: {int(np.flatnonzero(bad)[0])})"
                )
        norms = np.linalg.norm(self.quats.astype(np.float64), axis=1)
        if (norms <= 0).any():
            raise DataError(f"{name}: {int((norms <= 0).sum())} Gaussians have a zero quaternion")

    def subset(self, index: np.ndarray | slice) -> GaussianSet:
        """The Gaussians selected by a mask, index array or slice."""
        return GaussianSet(
            self.means[index],
            self.log_scales[index],
            self.quats[index],
            self.logit_opacities[index],
            self.sh_dc[index],
            self.sh_rest[index],  # type: ignore[index]
            self.origin.copy(),
            {k: v[index] for k, v in self.fields.items()},
        )

    def with_sh_degree(self, degree: int) -> GaussianSet:
        """The same set with SH truncated (or zero-padded) to ``degree``."""
        k = num_sh_bases(degree) - 1
        rest = self.sh_rest[:, :k]  # type: ignore[index]
        if rest.shape[1] < k:
            rest = np.concatenate([rest, np.zeros((len(self), k - rest.shape[1], 3), np.float32)], axis=1)
        out = self.subset(slice(None))
        out.sh_rest = np.ascontiguousarray(rest)
        return out

    def with_origin(self, origin: np.ndarray) -> GaussianSet:
        """The same Gaussians with means expressed relative to another origin (float64)."""
        out = self.subset(slice(None))
        origin = np.asarray(origin, dtype=np.float64).reshape(3)
        out.means = self.means + (self.origin - origin)
        out.origin = origin
        return out

    @staticmethod
    def concatenate(sets: Sequence[GaussianSet]) -> GaussianSet:
        """One set from several, in the first set's origin and the highest SH degree; common fields kept."""
        if not sets:
            raise DataError("cannot concatenate an empty list of Gaussian sets")
        degree = max(s.sh_degree for s in sets)
        origin = sets[0].origin
        parts = [s.with_origin(origin).with_sh_degree(degree) for s in sets]
        names = set.intersection(*(set(p.fields) for p in parts))
        return GaussianSet(
            np.concatenate([p.means for p in parts]),
            np.concatenate([p.log_scales for p in parts]),
            np.concatenate([p.quats for p in parts]),
            np.concatenate([p.logit_opacities for p in parts]),
            np.concatenate([p.sh_dc for p in parts]),
            np.concatenate([p.sh_rest for p in parts]),  # type: ignore[misc]
            origin,
            {k: np.concatenate([p.fields[k] for p in parts]) for k in sorted(names)},
        )


class DecodedSplats:
    """The methods shared by what the compressed formats' readers decode (SPZ, PlayCanvas compressed PLY, SOG).

    A subclass (a dataclass) holds, float64 in the file's local frame: ``positions`` (N, 3) metres, ``log_scales``
    (N, 3), ``quats`` (N, 4) (w, x, y, z), ``alphas`` (N,) in [0, 1], ``sh_dc`` (N, 3), ``sh_rest`` (N, K−1, 3)
    and ``origin`` (3,) world coordinates of that frame.
    """

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def sh_degree(self) -> int:
        return int(round(math.sqrt(self.sh_rest.shape[1] + 1))) - 1

    def to_gaussians(self) -> GaussianSet:
        """A :class:`GaussianSet` (opacities 0 and 1 map to finite logits, ±16.1)."""
        return GaussianSet(
            means=self.positions,
            log_scales=self.log_scales,
            quats=self.quats,
            logit_opacities=logit(self.alphas),
            sh_dc=self.sh_dc,
            sh_rest=self.sh_rest,
            origin=self.origin,
        )
