"""Options of the hybrid merge and of its survey-point product (:mod:`fusion.survey`), without heavy imports."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

from core.constraints import Choice, Constrained, Constraints, Interval, NoneOr, SequenceOf
from fusion.clean_options import SurveyPointOptions

VIEWER_FORMATS = {
    "spz": "merged.spz",
    "sog": "merged.sog",
    "compressed-ply": "merged.compressed.ply",
    "splat": "merged.splat",
    "3dtiles": "tiles/tileset.json",
}
"""Viewer formats the merge stage can write beside export/merged.ply: name → path under export/."""


@dataclass(frozen=True)
class MergeOptions(Constrained):
    """Options of the pipeline's ``merge`` stage (:func:`fusion.survey.hybrid_products`).

    keep_needs_splats: keep the MVS Gaussians of points that needed splats (in the 3DGS product and the points).
    points: the rule for trained splats in the survey point product (:class:`fusion.clean.SurveyPointOptions`).
    needs_mvs: ``needs_splats`` MVS points that pass the same view tests (no shape checks) go into the point
        product, with their own rim limit ``needs_mvs_max_rim_spacing`` (spacings; None: no rim test).
    needs_mvs_classes: the predicted classes (names of the project's class set; others are ignored) whose
        ``needs_splats`` MVS points go into the point product as they are: textureless surfaces leave MVS
        incomplete rather than wrong, while reflective and transparent ones add virtual images behind mirrors and
        glass (chosen on the benchmark's training scenes; docs/experiments/2026-11-27-pipeline-defaults.md).
    surface_test: mark the splats that may shape a mesh (the ``surface`` field of merged.ply, see
        :func:`fusion.clean.surface_splat_options`); off: every Gaussian gets ``surface = 1``.
    viewer_formats: the viewer product (merged.ply's Gaussians) also written in these formats, each beside it in
        export/ (:data:`VIEWER_FORMATS`: file name per format), with the origin sidecar and the CRS.
    memory_limit_mb (MiB; ``run --memory-limit``): None writes the survey points (merged_points.ply and .las) whole;
    a number writes them in chunks sized for about that peak memory (:func:`fusion.export_stream.export_chunk_points`:
    the same bytes; at least :data:`fusion.export_stream.BASE_MB` + :data:`fusion.export_stream.MIN_WORK_MB`, else
    a :class:`ConfigError`). The Gaussian sets themselves are in memory either way.
    """

    keep_needs_splats: bool = False
    points: SurveyPointOptions = field(default_factory=SurveyPointOptions)
    needs_mvs: bool = True
    needs_mvs_max_rim_spacing: float | None = 0.5
    needs_mvs_classes: tuple[str, ...] = ("textureless",)
    surface_test: bool = True
    viewer_formats: tuple[str, ...] = ()
    memory_limit_mb: float | None = None

    constraints: ClassVar[Constraints] = {
        "needs_mvs_max_rim_spacing": NoneOr(Interval(float, 0, math.inf, closed="right")),
        "viewer_formats": SequenceOf(Choice(tuple(VIEWER_FORMATS))),
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.memory_limit_mb is not None:
            from fusion.export_stream import export_chunk_points

            export_chunk_points(self.memory_limit_mb)  # a ConfigError naming the value
