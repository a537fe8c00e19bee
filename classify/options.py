"""Options of the classification of a dense cloud (the ``classify`` stage, :func:`classify.run.classify_dense`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from core.constraints import Constrained, Constraints, Interval, NoneOr


@dataclass(frozen=True)
class ClassifyOptions(Constrained):
    """model: ``default`` (the model shipped in classify/models/default.skops), ``none`` (the documented no-model
    fallback from MVS quality signals, :mod:`classify.fallback`), or the path of a ``.skops`` model
    (``hybridsplat classify train``).
    threshold: a point needs splats when the summed probability of the needs-splats classes reaches this;
    None = the threshold stored with the model (chosen on its held-out data), else 0.5.
    memory_limit_mb (MiB): None classifies the fused cloud in memory; a number classifies it in x-y cells with halos
    within about that peak memory (:func:`classify.stream.classify_stream`, the same classify/points.ply; at least
    :data:`classify.stream.BASE_MB` + :data:`classify.stream.MIN_WORK_MB`, else a :class:`ConfigError`).
    """

    model: str = "default"
    threshold: float | None = None
    memory_limit_mb: float | None = None

    constraints: ClassVar[Constraints] = {"threshold": NoneOr(Interval(float, 0, 1, closed="neither"))}

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.memory_limit_mb is not None:
            from classify.stream import plan_memory

            plan_memory(self.memory_limit_mb)  # a ConfigError naming the value
