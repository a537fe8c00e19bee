"""Stage ``merge``: one Gaussian set for viewers (export/merged.ply) and its points (PLY + LAS), see fusion.merge.

With cleaned splats (splats/cleaned.ply) and a classified cloud, the hybrid: trusted MVS Gaussians + splats, the
``needs_splats`` MVS points left out (``keep_needs_splats`` keeps them), a ``source`` field per Gaussian; the splats
alone also go to export/splats.ply. Without them, the converted MVS cloud.

The 3DGS PLY (merged.ply) keeps every cleaned splat for rendering; the point product (merged_points.ply/.las, the
survey deliverable) keeps the trusted MVS points and only those splats and ``needs_splats`` MVS points whose geometry
is trustworthy (:func:`fusion.clean.select_survey_points`: splats opaque, thin along the normal and not large; both
seen inside the region mask from several training views, not seen outside it unoccluded, and near the silhouette rim
of some view, which rejects the virtual images of reflections and refractions that MVS and splats place inside
mirrors and glass), plus the ``needs_splats`` MVS points of the classes that leave MVS incomplete rather than wrong
(``points_needs_mvs_classes``: textureless by default); the counts of what was left out and why are
recorded.

merged.ply carries a ``surface`` field besides ``source``: 1 for the MVS Gaussians and for the splats whose centres
pass :func:`fusion.clean.surface_splat_options` (opaque, inside the visual hull of the masks, not behind the trusted
surface filled across its holes), 0 for the other splats. The mesh stage builds its geometry from ``surface = 1``
only (colours from every Gaussian).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hybridsplat.stages.base import Stage, StageContext


@dataclass(frozen=True)
class MergeStageOptions:
    """Options of the ``merge`` stage. keep_needs_splats: keep the MVS Gaussians of points that needed splats.

    points_*: the rule for splats in the point product (see fusion.clean.SurveyPointOptions; a negative value turns
    a check off): min_opacity (α), max_thickness_spacing / max_extent_spacing (smallest / largest σ in trusted MVS
    point spacings), min_views (views seeing the centre inside the mask), min_mask_share (share of the unoccluded
    views that see it inside the mask), max_rim_spacing (distance to a mask edge in some view, in spacings).
    points_needs_mvs: ``needs_splats`` MVS points that pass the same view tests go into the point product, with
    their own rim limit ``points_needs_mvs_max_rim_spacing`` (with the classifier's masks, wider than the objects,
    tabletop kept 1 of 1114 such points at 0.5 and 1002 at 4 spacings: 2.08 instead of 1.62 mm mean C2C, 0.647
    instead of 0.642 completeness, and every non-collaborative material more complete than MVS-only).
    points_needs_mvs_classes: the predicted classes (names of the project's class set; others are ignored) whose
    ``needs_splats`` MVS points go into the point product as they are. Textureless surfaces leave MVS incomplete,
    not wrong: the points it does fuse there lie on the surface (data_synth tabletop, MVS accuracy: textureless
    paint 3.5 mm against mirror 22 mm), while reflective and transparent ones add virtual images behind mirrors
    and glass. Measured on the benchmark's projects (seed 1, 24 views 320×240, merge + eval re-run on the same
    trained splats; merged C2C mean / completeness, MVS only 2.28 mm / 0.716 and 223.6 mm / 0.690): tabletop, 600
    training steps, 1.77 mm / 0.711 → 1.79 / 0.722, 1000 steps 1.97 / 0.721 → 1.98 / 0.732; aerial, 600 steps
    215.8 mm / 0.687 → 216.3 / 0.688, 1000 steps 220.3 / 0.687 → 220.7 / 0.688. Adding ``thin`` changed nothing on
    the tabletop (4 points) and cost the aerial 5.4 mm (221.7 mm; 226.2 at 1000 steps, above MVS only: the steel
    lattice's points); every needs-splats class (as ``keep_needs_splats`` for the points) 2.35 mm / 0.724 and
    224.3 mm / 0.690, less accurate than MVS only on both.
    surface_test: mark the splats that may shape a mesh (``surface`` field of merged.ply, see the module docstring);
    off: every Gaussian gets ``surface = 1``.
    """

    keep_needs_splats: bool = False
    points_min_opacity: float = 0.2
    points_max_thickness_spacing: float = 2.0
    points_max_extent_spacing: float = 10.0
    points_min_views: int = 3
    points_min_mask_share: float = 0.9
    points_max_rim_spacing: float = 0.5
    points_needs_mvs: bool = True
    points_needs_mvs_max_rim_spacing: float = 0.5
    points_needs_mvs_classes: tuple[str, ...] = ("textureless",)
    surface_test: bool = True

    def survey_options(self, shape_checks: bool = True, rim: float | None = None):
        from fusion.clean import SurveyPointOptions

        def opt(v: float) -> float | None:
            return None if v < 0 else v

        return SurveyPointOptions(opt(self.points_min_opacity), opt(self.points_max_thickness_spacing),
                                  opt(self.points_max_extent_spacing), max(self.points_min_views, 0),
                                  opt(self.points_min_mask_share),
                                  max_rim_spacing=opt(self.points_max_rim_spacing if rim is None else rim),
                                  shape_checks=shape_checks)  # fmt: skip


@dataclass
class ViewTests:
    """cameras (Cameras), masks (name → (H, W) bool), trusted MVS points (M, 3) in the cameras' local frame, and
    their median spacing (metres)."""

    cameras: Any
    masks: dict[str, np.ndarray]
    trusted: np.ndarray
    spacing: float


class MergeStage(Stage):
    name = "merge"
    Options = MergeStageOptions
    title = "merge and export"

    def _hybrid(self, ctx: StageContext) -> bool:
        return ctx.layout.cleaned_splats.is_file() and ctx.layout.classified_points.is_file()

    def inputs(self, ctx: StageContext) -> list[Path]:
        layout = ctx.layout
        extra = [layout.cleaned_splats, layout.classified_points, layout.masks_dir, layout.dense_workspace.sparse]
        return [layout.mvs_gaussians, *(extra if self._hybrid(ctx) else [])]

    def outputs(self, ctx: StageContext) -> list[Path]:
        layout = ctx.layout
        splats = [layout.splats_export] if self._hybrid(ctx) else []
        return [layout.merged_ply, layout.merged_points_ply, layout.merged_points_las, *splats]

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from core.io.gaussian_ply import read_gaussian_ply
        from fusion.export import export_gaussian_ply, export_points
        from fusion.merge import merge_gaussians

        layout = ctx.layout
        mvs = read_gaussian_ply(layout.mvs_gaussians)
        extra: dict[str, Any] = {}
        if self._hybrid(ctx):
            from fusion.export import ExportOptions
            from fusion.merge import merge_hybrid, subset
            from hybridsplat.stages.train import needs_splats_per_gaussian

            splats = read_gaussian_ply(layout.cleaned_splats)
            opts: MergeStageOptions = ctx.options(self)
            needs = needs_splats_per_gaussian(ctx, mvs)
            result = merge_hybrid(mvs, splats, needs, keep_needs_splats=opts.keep_needs_splats)
            export_gaussian_ply(layout.splats_export, splats)
            views = self._views(ctx, mvs, needs, splats)
            surface, sel_surface = surface_field(result.gaussians, views, opts.surface_test)
            result.gaussians.fields["surface"] = surface
            written = export_gaussian_ply(layout.merged_ply, result.gaussians, ExportOptions(extra_fields=True))
            sel_splats, sel_mvs = self._survey_points(views, mvs, needs, splats, opts)
            needs_left_out = needs.copy()
            if sel_mvs is not None:
                needs_left_out[np.flatnonzero(needs)[sel_mvs.keep]] = False
            by_class = self._kept_classes(ctx, mvs, needs, opts)
            for kept in by_class.values():
                needs_left_out[kept] = False
            points = merge_hybrid(mvs, subset(splats, sel_splats.keep), needs_left_out,
                                  keep_needs_splats=opts.keep_needs_splats).gaussians  # fmt: skip
            extra = {"point_splats": vars(sel_splats.counts)}
            if sel_surface is not None:
                extra["surface_splats"] = vars(sel_surface.counts)
            if sel_mvs is not None:
                extra["point_needs_mvs"] = vars(sel_mvs.counts)
            extra["point_needs_mvs_classes"] = {name: int(kept.sum()) for name, kept in by_class.items()}
        else:
            result = merge_gaussians(None, mvs)
            written = export_gaussian_ply(layout.merged_ply, result.gaussians)
            points = result.gaussians
        export_points(layout.merged_points_ply, points)
        crs = ctx.config.input.crs
        if crs:  # the georeference sidecars and the LAS's WKT carry the CRS the user gave
            from core.io.las import write_las
            from core.io.origin import write_origin
            from fusion.export import gaussians_to_points

            write_las(layout.merged_points_las, gaussians_to_points(points), crs=crs)
            write_origin(layout.merged_ply, result.gaussians.origin, crs)
            write_origin(layout.merged_points_ply, points.origin, crs)
        else:
            export_points(layout.merged_points_las, points)
        s = result.stats
        return {"merged": len(result.gaussians), "written": written.num_written, "mvs": s.mvs_kept,
                "splats": s.splats_kept, "points": len(points), **extra}  # fmt: skip

    def _views(self, ctx: StageContext, mvs, needs, splats) -> ViewTests:
        """What the view tests of fusion.clean.select_survey_points need: cameras, masks, trusted points, spacing."""
        from scipy.spatial import cKDTree

        from hybridsplat.stages.base import read_project_model
        from hybridsplat.stages.train import read_masks

        cameras, _ = read_project_model(ctx, ctx.layout.dense_workspace.sparse)
        trusted = mvs.subset(~needs).with_origin(cameras.origin).means if (~needs).any() else np.zeros((0, 3))
        spacing = 0.0
        if len(trusted) > 1:
            spacing = float(np.median(cKDTree(trusted).query(trusted, k=2)[0][:, 1]))
        if not spacing > 0:  # no trusted surface to measure a spacing on: the splats' own
            own = splats.means
            spacing = float(np.median(cKDTree(own).query(own, k=2)[0][:, 1])) if len(own) > 1 else 1.0
        spacing = spacing if spacing > 0 else 1.0
        return ViewTests(cameras, read_masks(ctx, cameras), trusted, spacing)

    def _survey_points(self, views: ViewTests, mvs, needs, splats, opts: MergeStageOptions):
        """Which cleaned splats and which ``needs_splats`` MVS points go into the point product (selections of
        fusion.clean.select_survey_points; the second is None when ``points_needs_mvs`` is off)."""
        from fusion.clean import select_survey_points

        cameras, masks, trusted, spacing = views.cameras, views.masks, views.trusted, views.spacing
        sel_splats = select_survey_points(splats, cameras, masks, trusted, spacing, opts.survey_options())
        sel_mvs = None
        if opts.points_needs_mvs and not opts.keep_needs_splats and needs.any():
            mvs_rule = opts.survey_options(shape_checks=False, rim=opts.points_needs_mvs_max_rim_spacing)
            sel_mvs = select_survey_points(mvs.subset(needs), cameras, masks, trusted, spacing, mvs_rule)
        return sel_splats, sel_mvs

    def _kept_classes(self, ctx: StageContext, mvs, needs, opts: MergeStageOptions) -> dict[str, np.ndarray]:
        """Per class name of ``points_needs_mvs_classes`` present in the project's class set (classify/report.json):
        (N,) bool, its ``needs_splats`` MVS points. Empty when ``keep_needs_splats`` keeps them all anyway."""
        if opts.keep_needs_splats or not opts.points_needs_mvs_classes or not needs.any():
            return {}
        from classify.classes import ClassSet
        from core.io.json_io import read_json_object
        from hybridsplat.stages.train import classified_field_per_gaussian

        report = ctx.layout.classify_report
        stored = read_json_object(report).get("classes") if report.is_file() else None
        if not stored:
            return {}
        codes = {c.name: c.code for c in ClassSet.from_dict(stored, report).classes if c.needs_splats}
        wanted = [n for n in opts.points_needs_mvs_classes if n in codes]
        if not wanted:
            return {}
        predicted = classified_field_per_gaussian(ctx, mvs, "classification").astype(np.int64)
        return {name: needs & (predicted == codes[name]) for name in wanted}

    def summary(self, counts: dict[str, Any]) -> str:
        text = f"{counts['written']} Gaussians in the merged product"
        if "point_splats" in counts:
            c = counts["point_splats"]
            text += f", {counts['points']} survey points ({c['kept']} of {c['input']} splats trustworthy)"
        return text


def surface_field(merged, views: ViewTests, test: bool):  # -> tuple[np.ndarray, SurveyPointSelection | None]
    """(N,) uint8 ``surface`` per merged Gaussian (1 for MVS Gaussians; for splats the verdict of
    fusion.clean.surface_splat_options, or 1 when ``test`` is off) and the splats' selection (None when off)."""
    from fusion.clean import select_survey_points, surface_splat_options
    from fusion.convert import Source
    from fusion.merge import subset

    out = np.ones(len(merged), np.uint8)
    if not test:
        return out, None
    is_splat = np.asarray(merged.fields["source"]) == Source.SPLAT
    sel = select_survey_points(subset(merged, is_splat), views.cameras, views.masks, views.trusted, views.spacing,
                               surface_splat_options())  # fmt: skip
    out[is_splat] = sel.keep
    return out, sel
