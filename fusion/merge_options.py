"""Options of the hybrid merge and of its survey-point product (:mod:`fusion.survey`), without heavy imports."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

from core.constraints import Choice, Constrained, Constraints, Interval, NoneOr, OfType, SequenceOf, TupleOf
from fusion.clean_options import SurveyPointOptions
from fusion.splat_surface import SplatSurfaceOptions

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
    splat_surface: put splat-surface points into the point product (off by default, and then the products are those
        of a merge without them, byte for byte: the F-score gain they gave on the benchmark's tuning layouts did not
        hold on its scoring layouts, docs/experiments/2026-12-02-survey-verdicts.md):
        :func:`fusion.splat_surface.splat_surface_points` on the cleaned fill layer inside the training masks of the
        training views, the trusted MVS points' z-buffer as the front surface (a depth behind a trusted surface is
        an occluded or virtual layer), the rule
        ``splat_surface_points`` (σ per point: :func:`fusion.splat_surface.sigma_model`, anchored on the fused MVS
        points); added with ``source`` = 4, ``classification`` = 68 and a ``sigma`` field by
        :func:`fusion.survey.with_splat_surface` (points within half the trusted spacing of an MVS point of the
        product left out). The viewer product and the mesh do not change.
    splat_surface_keep_centres: with ``splat_surface``, also keep the splat centres that pass ``points`` (off: the
        surface points replace them; a centre is not a surface sample).
    splat_surface_support: surface points farther than this many trusted spacings from every fused MVS point
        (trusted or not) are left out: floaters of the fill layer render depths the views agree on (None: no test).
        2, chosen on the demo preset at seed 12 (no figure is scored on it; docs/experiments/2026-11-27-splat-
        surface.md, "seed 12 choice, seed 0 score"): the largest support at which every material whose filtered-MVS
        accuracy mean is ≤ τ keeps its mean ≤ τ.
    splat_surface_sigma_scale: (class name, factor) pairs: the σ of a splat-surface point whose predicted class
        (that of its nearest ``needs_splats`` MVS point, :func:`fusion.survey.class_names_of_points`) is named here
        is multiplied by the factor (≥ 1; with ``splat_surface`` only); other classes keep the σ model's value. The
        default was chosen on tuning
        layouts (random-object seeds 60 and 61, random-aerial 60; docs/experiments/2026-12-02-survey-verdicts.md): per
        class, the smallest factor (in steps of 0.05) whose 95 % interval holds the nominal 0.95 of the points of
        every (class, material) cell of ≥ 50 points, so that the issue's bar of 0.90 keeps a margin elsewhere.
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
    splat_surface: bool = False
    splat_surface_keep_centres: bool = False
    splat_surface_support: float | None = 2.0
    splat_surface_sigma_scale: tuple[tuple[str, float], ...] = (("reflective", 1.25),)
    splat_surface_points: SplatSurfaceOptions = field(default_factory=SplatSurfaceOptions)
    memory_limit_mb: float | None = None

    constraints: ClassVar[Constraints] = {
        "needs_mvs_max_rim_spacing": NoneOr(Interval(float, 0, math.inf, closed="right")),
        "viewer_formats": SequenceOf(Choice(tuple(VIEWER_FORMATS))),
        "splat_surface_support": NoneOr(Interval(float, 0, math.inf, closed="right")),
        "splat_surface_sigma_scale": SequenceOf(TupleOf(OfType(str), Interval(float, 1, math.inf))),
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.memory_limit_mb is not None:
            from fusion.export_stream import export_chunk_points

            export_chunk_points(self.memory_limit_mb)  # a ConfigError naming the value
