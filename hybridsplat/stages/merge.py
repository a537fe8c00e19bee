"""Stage ``merge``: one Gaussian set for viewers (export/merged.ply) and its survey points (PLY + LAS).

With cleaned splats (splats/cleaned.ply) and a classified cloud, the hybrid (:func:`fusion.survey.hybrid_products`:
trusted MVS Gaussians + splats, a ``source`` and a ``surface`` field per Gaussian, and the point product of the
Gaussians whose geometry is trustworthy); the splats alone also go to export/splats.ply. Without them, the
converted MVS cloud.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fusion.merge_options import MergeOptions
from hybridsplat.disk_space import tree_bytes
from hybridsplat.stages import sizes
from hybridsplat.stages.base import ReportSection, Stage, StageContext


class MergeStage(Stage):
    name = "merge"
    Options = MergeOptions
    title = "merge and export"

    def _hybrid(self, ctx: StageContext) -> bool:
        return ctx.layout.cleaned_splats.is_file() and ctx.layout.classified_points.is_file()

    def inputs(self, ctx: StageContext) -> list[Path]:
        layout = ctx.layout
        extra = [layout.cleaned_splats, layout.classified_points, layout.masks_dir, layout.dense_workspace.sparse]
        background = [layout.background_splats] if layout.background_splats.is_file() else []
        return [layout.mvs_gaussians, *(extra if self._hybrid(ctx) else []), *background]

    def outputs(self, ctx: StageContext) -> list[Path]:
        layout = ctx.layout
        splats = [layout.splats_export] if self._hybrid(ctx) else []
        return [layout.merged_ply, layout.merged_points_ply, layout.merged_points_las, *splats]

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of the merge's products for n = the MVS Gaussians + (hybrid) the cleaned splats: merged.ply with
        n Gaussians at the higher SH degree and both sets' extra fields + ``classification``, ``source``,
        ``surface``; merged_points.ply and .las with n points and those fields + ``opacity``, ``scale`` and the
        normals (3DGS properties at 4 bytes, point fields at 8 at most); export/splats.ply at most
        splats/cleaned.ply's size; 4 origin sidecars and the log (64 KiB)."""
        layout = ctx.layout
        sets = [sizes.ply_vertices(layout.mvs_gaussians)]
        if self._hybrid(ctx):
            sets.append(sizes.ply_vertices(layout.cleaned_splats))
        if layout.background_splats.is_file():
            sets.append(sizes.ply_vertices(layout.background_splats))
        n = sum(s.count for s in sets)
        extras = sum(len(s.extras) for s in sets) + 3
        merged = sizes.gaussian_ply_bytes(n, max(s.sh_degree for s in sets), extras)
        points = sizes.point_ply_bytes(n, extras + 5) + sizes.las_bytes(n, extras + 5)
        splats = tree_bytes([layout.cleaned_splats]) if self._hybrid(ctx) else 0
        return merged + points + splats + 4 * sizes.SIDECAR_BYTES + sizes.LOG_BYTES

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from core.gaussians import GaussianSet
        from core.io.gaussian_ply import read_gaussian_ply
        from fusion.export import ExportOptions, export_gaussian_ply, export_points
        from fusion.merge import merge_gaussians

        layout = ctx.layout
        mvs = read_gaussian_ply(layout.mvs_gaussians)
        extra: dict[str, Any] = {}
        if self._hybrid(ctx):
            products = self._hybrid_products(ctx, mvs)
            gaussians, points, stats, extra = products.gaussians, products.points, products.stats, products.counts
        else:
            result = merge_gaussians(None, mvs)
            gaussians, points, stats = result.gaussians, result.gaussians, result.stats
        background = _background_layer(layout.background_splats, gaussians)
        if background is not None:  # the viewer product only: the survey points never hold it
            gaussians = GaussianSet.concatenate([gaussians, background])
        written = export_gaussian_ply(layout.merged_ply, gaussians, ExportOptions(extra_fields=True))
        export_points(layout.merged_points_ply, points)
        crs = ctx.config.input.crs
        from core.io.origin import write_origin
        from fusion.convert_options import LAYERS

        # the viewer product's sidecar names its layers (and the CRS the user gave)
        write_origin(layout.merged_ply, gaussians.origin, crs, layers={k: int(v) for k, v in LAYERS.items()})
        if crs:  # the survey points' sidecar and the LAS's WKT carry the CRS too
            from core.io.las import write_las
            from fusion.export import gaussians_to_points

            write_las(layout.merged_points_las, gaussians_to_points(points), crs=crs)
            write_origin(layout.merged_points_ply, points.origin, crs)
        else:
            export_points(layout.merged_points_las, points)
        return {"merged": len(gaussians), "written": written.num_written, "mvs": stats.mvs_kept,
                "splats": stats.splats_kept, "background": len(background) if background is not None else 0,
                "points": len(points), **extra}  # fmt: skip

    def _hybrid_products(self, ctx: StageContext, mvs: Any) -> Any:
        """Reads what the hybrid needs (splats, masks, classes) and writes export/splats.ply."""
        from core.io.gaussian_ply import read_gaussian_ply
        from fusion.export import export_gaussian_ply
        from fusion.survey import hybrid_products, view_tests
        from hybridsplat import project_io

        layout = ctx.layout
        opts: MergeOptions = ctx.options(self)
        splats = read_gaussian_ply(layout.cleaned_splats)
        needs = project_io.needs_splats_per_gaussian(layout, mvs)
        export_gaussian_ply(layout.splats_export, splats)
        cameras, _ = project_io.read_project_model(layout, layout.dense_workspace.sparse)
        views = view_tests(cameras, project_io.read_region_masks(layout, cameras), mvs, needs, splats)
        codes, predicted = {}, None
        if opts.needs_mvs_classes and not opts.keep_needs_splats and needs.any():
            codes = project_io.read_needs_splats_class_codes(layout)
            if any(n in codes for n in opts.needs_mvs_classes):
                predicted = project_io.classified_field_per_gaussian(layout, mvs, "classification").astype("int64")
        return hybrid_products(mvs, splats, needs, views, opts, predicted, codes)

    def report_section(self, counts: dict[str, Any]) -> ReportSection | None:
        if not isinstance(counts.get("written"), int):
            return None
        line = (
            f"The merged product (export/merged.ply) holds {counts['written']:,} Gaussians in three layers "
            f"(its `source` field): survey {counts.get('mvs', 0):,} (the MVS Gaussians, positions as converted), "
            f"fill {counts.get('splats', 0):,} (splats trained in the region masks), background "
            f"{counts.get('background', 0):,} (what the photos see beyond the survey region; viewer product only). "
            f"The survey points (merged_points.ply/.las) hold {counts.get('points', 0):,} points, no background."
        )
        return ReportSection("The merged product's layers", (line,))

    def summary(self, counts: dict[str, Any]) -> str:
        layers = f"survey {counts['mvs']}, fill {counts['splats']}, background {counts.get('background', 0)}"
        text = f"{counts['written']} Gaussians in the merged product ({layers})"
        if "point_splats" in counts:
            c = counts["point_splats"]
            text += f", {counts['points']} survey points ({c['kept']} of {c['input']} splats trustworthy)"
        return text


def _background_layer(path: Path, merged: Any) -> Any:
    """The background layer (splats/background.ply) with the merged set's fields (``source`` = BACKGROUND, the
    others 0), or None when there is none."""
    import numpy as np

    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.convert_options import Source

    if not path.is_file():
        return None
    background = read_gaussian_ply(path)
    if len(background) == 0:
        return None
    n = len(background)
    background.fields = {k: np.zeros(n, dtype=np.asarray(v).dtype) for k, v in merged.fields.items()}
    background.fields["source"] = np.full(n, Source.BACKGROUND, dtype=np.uint8)
    return background
