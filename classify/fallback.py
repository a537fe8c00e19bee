"""The no-model fallback: flag points from MVS quality signals alone (no training, no labels).

A point needs splats when any of these fires (thresholds in :class:`FallbackOptions`):

- ``depth_freespace`` ≥ 0.4: 40 % of the views whose frustum holds the point see *past* it (a virtual
  point behind a mirror, a point refracted through glass, a floater);
- ``color_std_views`` ≥ 0.05: its colour changes with the viewpoint (specular, transparent);
- ``ncc_views`` ≤ 0.1: the views' patches around it are flat or disagree (textureless, view-dependent);
- ``n_views`` < 3 or ``depth_residual`` ≥ 0.05: weakly supported or inconsistent.

The thresholds were chosen by a grid search on the default model's training scenes (tabletop and aerial, seed
7), maximising the mean binary F1; it stays low (~0.27 there): the rules are a last resort, not a classifier.

Its class is a guess from the signal that fired: free-space or colour change → reflective, flat patches →
textureless, a linear neighbourhood (``linearity_s0`` ≥ 0.8) → thin. ``probability`` is the share of fired
rules among those evaluated (a score, not a calibrated probability).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from classify.classes import ClassSet
from classify.features import FeatureTable
from classify.model import Prediction
from core.errors import ConfigError

FALLBACK_FEATURES = (
    "depth_freespace",
    "color_std_views",
    "ncc_views",
    "n_views",
    "depth_residual",
    "linearity_s0",
)


@dataclass(frozen=True)
class FallbackOptions:
    """Thresholds of the rules (see the module docstring)."""

    max_freespace: float = 0.4
    max_color_std: float = 0.05
    min_ncc: float = 0.1
    min_views: int = 3
    max_residual: float = 0.05
    thin_linearity: float = 0.8


def fallback_predict(
    table: FeatureTable, classes: ClassSet, options: FallbackOptions = FallbackOptions()
) -> Prediction:
    """Classify from the multi-view quality features of ``table`` (which must hold :data:`FALLBACK_FEATURES`)."""
    missing = [n for n in FALLBACK_FEATURES if n not in table.names]
    if missing:
        raise ConfigError(f"the fallback needs the features {', '.join(missing)} (multi-view features and scale 0)")
    col = table.column
    free = col("depth_freespace") >= options.max_freespace
    colour = col("color_std_views") >= options.max_color_std
    flat = col("ncc_views") <= options.min_ncc
    weak = (col("n_views") < options.min_views) | (col("depth_residual") >= options.max_residual)
    rules = np.stack([free, colour, flat, weak], axis=1)
    needs = rules.any(axis=1)
    codes = np.full(len(needs), classes.collaborative_code, dtype=np.uint8)

    def code(name: str) -> int | None:
        return next((c.code for c in classes.classes if c.name == name), None)

    for name, which in (
        ("textureless", flat),
        ("reflective", free | colour),
        ("thin", needs & (col("linearity_s0") >= options.thin_linearity)),
    ):
        c = code(name)
        if c is not None:
            codes[which] = c
    other = needs & classes.needs_splats_of(codes).__invert__()
    if other.any():
        codes[other] = next(c.code for c in classes.classes if c.needs_splats)
    score = rules.mean(axis=1).astype(np.float32)
    prob = np.where(needs, score, 1.0 - score).astype(np.float32)
    return Prediction(codes, prob, needs, score)
