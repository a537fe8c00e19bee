"""Options of the classification of a dense cloud (the ``classify`` stage, :func:`classify.run.classify_dense`)."""

from __future__ import annotations

from dataclasses import dataclass

from core.errors import ConfigError


@dataclass(frozen=True)
class ClassifyOptions:
    """model: ``default`` (the model shipped in classify/models/default.skops), ``none`` (the documented no-model
    fallback from MVS quality signals, :mod:`classify.fallback`), or the path of a ``.skops`` model
    (``hybridsplat classify train``).
    threshold: a point needs splats when the summed probability of the needs-splats classes reaches this;
    None = the threshold stored with the model (chosen on its held-out data), else 0.5.
    """

    model: str = "default"
    threshold: float | None = None

    def __post_init__(self) -> None:
        if self.threshold is not None and not 0.0 < self.threshold < 1.0:
            raise ConfigError(f"threshold must lie strictly between 0 and 1, got {self.threshold}")
