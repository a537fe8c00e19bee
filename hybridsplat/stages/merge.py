"""Stage ``merge``: one Gaussian set for viewers (export/merged.ply) and its points (PLY + LAS), see fusion.merge.

With cleaned splats (splats/cleaned.ply) and a classified cloud, the hybrid: trusted MVS Gaussians + splats, the
``needs_splats`` MVS points left out (``keep_needs_splats`` keeps them), a ``source`` field per Gaussian; the splats
alone also go to export/splats.ply. Without them, the converted MVS cloud.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hybridsplat.stages.base import Stage, StageContext


@dataclass(frozen=True)
class MergeStageOptions:
    """Options of the ``merge`` stage. keep_needs_splats: keep the MVS Gaussians of points that needed splats."""

    keep_needs_splats: bool = False


class MergeStage(Stage):
    name = "merge"
    Options = MergeStageOptions
    title = "merge and export"

    def _hybrid(self, ctx: StageContext) -> bool:
        return ctx.layout.cleaned_splats.is_file() and ctx.layout.classified_points.is_file()

    def inputs(self, ctx: StageContext) -> list[Path]:
        extra = [ctx.layout.cleaned_splats, ctx.layout.classified_points] if self._hybrid(ctx) else []
        return [ctx.layout.mvs_gaussians, *extra]

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
        if self._hybrid(ctx):
            from fusion.export import ExportOptions
            from fusion.merge import merge_hybrid
            from hybridsplat.stages.train import needs_splats_per_gaussian

            splats = read_gaussian_ply(layout.cleaned_splats)
            opts: MergeStageOptions = ctx.options(self)
            needs = needs_splats_per_gaussian(ctx, mvs)
            result = merge_hybrid(mvs, splats, needs, keep_needs_splats=opts.keep_needs_splats)
            export_gaussian_ply(layout.splats_export, splats)
            written = export_gaussian_ply(layout.merged_ply, result.gaussians, ExportOptions(extra_fields=True))
        else:
            result = merge_gaussians(None, mvs)
            written = export_gaussian_ply(layout.merged_ply, result.gaussians)
        export_points(layout.merged_points_ply, result.gaussians)
        crs = ctx.config.input.crs
        if crs:  # the georeference sidecars and the LAS's WKT carry the CRS the user gave
            from core.io.las import write_las
            from core.io.origin import write_origin
            from fusion.export import gaussians_to_points

            write_las(layout.merged_points_las, gaussians_to_points(result.gaussians), crs=crs)
            for path in (layout.merged_ply, layout.merged_points_ply):
                write_origin(path, result.gaussians.origin, crs)
        else:
            export_points(layout.merged_points_las, result.gaussians)
        s = result.stats
        return {"merged": len(result.gaussians), "written": written.num_written, "mvs": s.mvs_kept,
                "splats": s.splats_kept}  # fmt: skip

    def summary(self, counts: dict[str, Any]) -> str:
        return f"{counts['written']} Gaussians in the merged product"
