"""The options and codes of the point-to-Gaussian conversion (:mod:`fusion.convert`), without its kernels.

Kept apart from :mod:`fusion.convert` (numba kernels, scipy KD-trees) so that the command line, the pipeline's
configuration and the export/merge code can name a mode, a source code or the options, and check them, without
loading numba; :mod:`fusion.convert` re-exports every name here.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import Any, ClassVar

import numpy as np

from core.constraints import Choice, Constrained, Constraints, Interval
from core.errors import ConfigError


class Source(IntEnum):
    """Codes of the ``source`` field (uint8) carried by Gaussians and exported point clouds: the one list of the
    merged product's layers for every export. Survey products (C2C, LAS and point exports, mesh, measurement)
    never hold ``BACKGROUND``."""

    UNKNOWN = 0
    MVS = 1  # the survey layer: converted from the photogrammetric (MVS) cloud
    SPLAT = 2  # the fill layer: splats trained inside the region masks
    BACKGROUND = 3  # the background layer: what the photos see beyond the survey region (fusion.background)
    # 4: reserved (splat-surface points, removed in 0.4; their LAS classification was 68): survey points of earlier
    # versions may carry it, and the readers pass any code through (fusion.tiles3d.layer_name: "source_4"), so no
    # new layer takes it.


LAYERS: dict[str, Source] = {"survey": Source.MVS, "fill": Source.SPLAT, "background": Source.BACKGROUND}
"""The merged product's layers by name (``--layers survey,fill,background`` on export, render and view)."""


def parse_layers(text: str) -> tuple[Source, ...]:
    """``"survey,fill"`` → their ``source`` codes; :class:`ConfigError` naming the unknown word."""
    words = [w.strip().lower() for w in text.split(",") if w.strip()]
    unknown = [w for w in words if w not in LAYERS]
    if unknown or not words:
        raise ConfigError(f"--layers takes a comma-separated list of {', '.join(LAYERS)}, got {text!r}")
    return tuple(LAYERS[w] for w in dict.fromkeys(words))


def select_layers(gaussians: Any, layers: tuple[Source, ...] | None) -> Any:
    """The Gaussians (a ``GaussianSet``) of ``layers`` (all when None). A set without a ``source`` field is one
    survey layer: the MVS conversion of a cloud, or a splat file of another tool."""
    if layers is None:
        return gaussians
    source = gaussians.fields.get("source")
    if source is None:
        return gaussians if Source.MVS in layers else gaussians.subset(np.zeros(len(gaussians), bool))
    return gaussians.subset(np.isin(np.asarray(source).astype(np.int64), [int(c) for c in layers]))


class ConvertMode(str, Enum):
    """Conversion modes (see the module docstring)."""

    PAPER = "paper"
    ADAPTIVE = "adaptive"


DEFAULT_MODE = ConvertMode.ADAPTIVE  # the toolkit's one default (pipeline and ``hybridsplat convert``)


class ConversionWarning(UserWarning):
    """A clamp or fallback changed values during conversion (the message gives the count)."""


@dataclass(frozen=True)
class ConvertOptions(Constrained):
    """Options of :func:`points_to_gaussians`. Lengths in metres, opacities as stored logits.

    Defaults: ``opacity_logit_min`` = −5 (α ≈ 0.0067, above the 1/255 export cut, so no point is lost) and
    ``opacity_logit_max`` = 10 (α ≈ 0.99995) leave the paper's log(1/d) untouched for any d between 45 µm and
    148 m; ``min_spacing`` = 1e-5 m and ``max_spacing`` = 1e3 m bound the log-scales; ``fallback_spacing`` is used
    for a cloud of a single point. Adaptive: ``tangent_scale`` (surfel σ along the surface, in spacings),
    ``view_saturation`` (views at which opacity saturates) and ``thickness_ratio`` (σ along the normal as a share of
    the tangent σ: flat surfels) were chosen on data_synth scenes with ``bench/bench_convert_quality.py``
    (docs/experiments/2026-11-27-pipeline-defaults.md).
    Execution: ``neighbor_backend`` ``"grid"`` (numba, ``numba.get_num_threads()`` threads, default
    ``NUMBA_NUM_THREADS``) or ``"kdtree"`` (scipy, ``workers`` threads, queried in chunks of ``chunk_size`` points).
    """

    opacity_logit_min: float = -5.0
    opacity_logit_max: float = 10.0
    min_spacing: float = 1e-5
    max_spacing: float = 1e3
    fallback_spacing: float = 0.01
    # adaptive mode
    k_neighbors: int = 8
    tangent_scale: float = 0.4
    thickness_ratio: float = 0.1
    max_opacity: float = 0.98
    view_saturation: float = 1.0
    outlier_spacing_factor: float = 3.0
    # execution
    chunk_size: int = 1_000_000
    workers: int = -1
    neighbor_backend: str = "grid"

    constraints: ClassVar[Constraints] = {
        "opacity_logit_min": Interval(float, None, None),
        "opacity_logit_max": Interval(float, None, None),
        "min_spacing": Interval(float, 0, None, closed="neither"),
        "max_spacing": Interval(float, 0, None, closed="neither"),
        "fallback_spacing": Interval(float, 0, None, closed="neither"),
        "k_neighbors": Interval(int, 1, 64),
        "tangent_scale": Interval(float, 0, None, closed="neither"),
        "thickness_ratio": Interval(float, 0, 1, closed="right"),
        "max_opacity": Interval(float, 0, 1, closed="neither"),
        "view_saturation": Interval(float, 0, None, closed="neither"),
        "outlier_spacing_factor": Interval(float, 0, None, closed="neither"),
        "chunk_size": Interval(int, 1, None),
        "neighbor_backend": Choice(("grid", "kdtree")),
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.opacity_logit_min < self.opacity_logit_max:
            lo, hi = self.opacity_logit_min, self.opacity_logit_max
            raise ConfigError(f"opacity_logit_min must be < opacity_logit_max, got {lo} >= {hi}")
        if not self.min_spacing < self.max_spacing:
            raise ConfigError(f"min_spacing must be < max_spacing, got {self.min_spacing} >= {self.max_spacing}")
