"""Stage ``merge``: one Gaussian set for viewers (export/merged.ply) and its points (PLY + LAS), see fusion.merge."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hybridsplat.stages.base import Stage, StageContext


class MergeStage(Stage):
    name = "merge"
    title = "merge and export"

    def inputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.mvs_gaussians]

    def outputs(self, ctx: StageContext) -> list[Path]:
        layout = ctx.layout
        return [layout.merged_ply, layout.merged_points_ply, layout.merged_points_las]

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from core.io.gaussian_ply import read_gaussian_ply
        from fusion.export import export_gaussian_ply, export_points
        from fusion.merge import merge_gaussians

        layout = ctx.layout
        result = merge_gaussians(None, read_gaussian_ply(layout.mvs_gaussians))
        written = export_gaussian_ply(layout.merged_ply, result.gaussians)
        export_points(layout.merged_points_ply, result.gaussians)
        export_points(layout.merged_points_las, result.gaussians)
        if ctx.config.input.crs:  # the georeference sidecars carry the CRS the user gave
            from core.io.origin import write_origin

            for path in (layout.merged_ply, layout.merged_points_ply):
                write_origin(path, result.gaussians.origin, ctx.config.input.crs)
        return {"merged": len(result.gaussians), "written": written.num_written}

    def summary(self, counts: dict[str, Any]) -> str:
        return f"{counts['written']} Gaussians in the merged product"
