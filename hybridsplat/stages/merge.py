"""Stage ``merge``: one Gaussian set for viewers (export/merged.ply) and its survey points (PLY + LAS).

With cleaned splats (splats/cleaned.ply) and a classified cloud, the hybrid (:func:`fusion.survey.hybrid_products`:
trusted MVS Gaussians + splats, a ``source`` and a ``surface`` field per Gaussian, and the point product of the
Gaussians whose geometry is trustworthy); the splats alone also go to export/splats.ply. Without them, the
converted MVS cloud. ``viewer_formats`` also writes the viewer product as SPZ, SOG, compressed PLY, ``.splat`` or a
3D Tiles tileset beside merged.ply (``--viewer-format``, repeatable); the tileset also holds the survey points as a
point-cloud layer (not the mesh: the mesh stage runs later; ``hybridsplat export`` adds it).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fusion.merge_options import MergeOptions
from hybridsplat.disk_space import tree_bytes
from hybridsplat.stages import sizes
from hybridsplat.stages.base import (
    MEMORY_LIMIT_HELP,
    CliOption,
    ReportSection,
    Stage,
    StageContext,
    StageResult,
    omitted_if_none,
)


def _survey_exports(ctx: StageContext, points: Any, crs: str | None) -> int | None:
    """export/merged_points.ply and .las of the survey points (a GaussianSet): with a CRS, the LAS of every point
    with the CRS as WKT and the PLY's sidecar naming it; without, both through :func:`fusion.export.export_points`.
    With ``memory_limit_mb``, written in chunks (the same bytes): the points a chunk holds (None without)."""
    from core.io.origin import write_origin
    from fusion.export import export_points
    from fusion.export_stream import export_chunk_points, point_chunks, write_las_points

    layout, limit = ctx.layout, ctx.options(MergeStage).memory_limit_mb
    chunk = export_chunk_points(limit) if limit is not None else None
    export_points(layout.merged_points_ply, points, chunk=chunk)
    if crs:  # the survey points' sidecar and the LAS's WKT carry the CRS too
        if chunk is not None:
            write_las_points(layout.merged_points_las, point_chunks(points, chunk), crs)
        else:
            from core.io.las import write_las
            from fusion.export import gaussians_to_points

            write_las(layout.merged_points_las, gaussians_to_points(points), crs=crs)
        write_origin(layout.merged_points_ply, points.origin, crs)
    else:
        export_points(layout.merged_points_las, points, chunk=chunk)
    return chunk


@dataclass(frozen=True)
class MergeResult(StageResult):
    """What the merge stage made: the viewer product's Gaussians (``merged``; ``written`` to export/merged.ply) per
    layer (``mvs`` survey, ``splats`` fill, ``background``), the survey points, and whether the survey, fill
    (hybrid only) and background layers came with their appearance refined.

    Hybrid only (:func:`fusion.survey.hybrid_products`; each a :class:`fusion.clean.SurveyPointCounts` by its field
    names): the survey-point selection of the splats (``point_splats``), the surface test of the splats
    (``surface_splats``) and the selection of the ``needs_splats`` MVS points (``point_needs_mvs``), and the
    needs-splats MVS points kept per class (``point_needs_mvs_classes``). With ``memory_limit_mb`` (MiB), the
    points a chunk of the survey-point export holds."""

    merged: int = 0
    written: int = 0
    mvs: int = 0
    splats: int = 0
    background: int = 0
    points: int = 0
    survey_refined: bool = False
    point_splats: dict[str, int] | None = omitted_if_none()
    surface_splats: dict[str, int] | None = omitted_if_none()
    point_needs_mvs: dict[str, int] | None = omitted_if_none()
    point_needs_mvs_classes: dict[str, int] | None = omitted_if_none()
    fill_refined: bool | None = omitted_if_none()
    background_refined: bool = False
    memory_limit_mb: float | None = omitted_if_none()
    export_chunk_points: int | None = omitted_if_none()


class MergeStage(Stage):
    name = "merge"
    Options = MergeOptions
    Result = MergeResult
    title = "merge and export"
    command_options = (
        CliOption(
            "viewer_formats",
            "--viewer-format",
            help="Also write the viewer product as spz | sog | compressed-ply | splat | 3dtiles (repeatable).",
        ),
        CliOption("memory_limit_mb", "--memory-limit", help=MEMORY_LIMIT_HELP),
    )
    run_options = command_options

    def _hybrid(self, ctx: StageContext) -> bool:
        return ctx.layout.cleaned_splats.is_file() and ctx.layout.classified_points.is_file()

    def inputs(self, ctx: StageContext) -> list[Path]:
        layout = ctx.layout
        extra = [layout.cleaned_splats, layout.classified_points, layout.masks_dir, layout.dense_workspace.sparse]
        layers = [self._background_file(ctx), self._survey_file(ctx), *self._refined_files(ctx).values()]
        return [layout.mvs_gaussians, *(extra if self._hybrid(ctx) else []), *(p for p in layers if p and p.is_file())]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        """Which optional layer files the merge reads (a stage turned off leaves its file behind, unread)."""
        refined = self._refined_files(ctx)
        return {"background": self._background_file(ctx) is not None, "survey": self._survey_file(ctx) is not None,
                **({"refined_layers": sorted(p.name for p in refined.values())} if refined else {})}  # fmt: skip

    def _survey_file(self, ctx: StageContext) -> Path | None:
        """splats/survey.ply (the survey layer's refined appearance) when the appearance stage is on."""
        from fusion.appearance import AppearanceOptions

        return ctx.layout.survey_splats if ctx.config.options("appearance", AppearanceOptions).enabled else None

    def _refined_files(self, ctx: StageContext) -> dict[Path, Path]:
        """Layer file → its refined copy for the viewer product (splats/fill_refined.ply,
        splats/background_refined.ply), for the layers the appearance stage refines (``refine_context``)."""
        from fusion.appearance import AppearanceOptions

        opts = ctx.config.options("appearance", AppearanceOptions)
        if not (opts.enabled and opts.refine_context):
            return {}
        read = {self._background_file(ctx)}
        if self._hybrid(ctx):
            read.add(ctx.layout.cleaned_splats)
        return {base: copy for base, copy in ctx.layout.refined_layers().items() if base in read}

    def _background_file(self, ctx: StageContext) -> Path | None:
        """splats/background.ply when the background stage is on."""
        from fusion.background import BackgroundOptions

        on = ctx.config.options("background", BackgroundOptions).enabled
        return ctx.layout.background_splats if on else None

    def outputs(self, ctx: StageContext) -> list[Path]:
        layout = ctx.layout
        splats = [layout.splats_export] if self._hybrid(ctx) else []
        viewer = [layout.merged_viewer(f) for f in ctx.options(self).viewer_formats]
        return [layout.merged_ply, layout.merged_points_ply, layout.merged_points_las, *splats, *viewer]

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of the merge's products for n = the MVS Gaussians + (hybrid) the cleaned splats + the background
        layer: merged.ply with n Gaussians at the highest SH degree (the refined survey layer's included) and the
        sets' extra fields + ``classification``, ``source``, ``surface``; merged_points.ply and .las with n points
        and those fields + ``opacity``, ``scale`` and the normals (3DGS properties at 4 bytes, point fields at 8 at
        most); export/splats.ply at most splats/cleaned.ply's size; a 3D Tiles viewer product also holds the
        survey points (20 bytes each); 4 origin sidecars and the log (64 KiB)."""
        layout = ctx.layout
        sets = [sizes.ply_vertices(layout.mvs_gaussians)]
        if self._hybrid(ctx):
            sets.append(sizes.ply_vertices(layout.cleaned_splats))
        background, survey = self._background_file(ctx), self._survey_file(ctx)
        if background is not None and background.is_file():
            sets.append(sizes.ply_vertices(background))
        n = sum(s.count for s in sets)
        extras = sum(len(s.extras) for s in sets) + 3
        refined = sizes.ply_vertices(survey) if survey is not None else sizes.PlyVertices()  # replaces the MVS set
        merged = sizes.gaussian_ply_bytes(n, max(refined.sh_degree, *(s.sh_degree for s in sets)), extras)
        fields = extras + 5
        points = sizes.point_ply_bytes(n, fields) + sizes.las_bytes(n, fields)
        splats = tree_bytes([layout.cleaned_splats]) if self._hybrid(ctx) else 0
        formats = ctx.options(self).viewer_formats  # each at most the PLY's size; a tileset adds its JSON (12 %)
        tiled_points = 20 * n  # a tileset's survey points: float32 xyz + RGBA, 20 % for JSON and GLB
        viewer = sum(
            (int(merged * 1.12) + tiled_points if f == "3dtiles" else merged) + sizes.SIDECAR_BYTES for f in formats
        )
        return merged + points + splats + viewer + 4 * sizes.SIDECAR_BYTES + sizes.LOG_BYTES

    def run(self, ctx: StageContext) -> MergeResult:
        from core.gaussians import GaussianSet
        from core.io.gaussian_ply import read_gaussian_ply
        from fusion.export import ExportOptions, export_gaussian_ply
        from fusion.merge import merge_gaussians

        layout = ctx.layout
        mvs = read_gaussian_ply(layout.mvs_gaussians)
        refined = _refined_rows(self._survey_file(ctx), mvs, "the converted MVS Gaussians'")
        hybrid: dict[str, Any] = {}  # the hybrid's fields of the result
        if self._hybrid(ctx):
            products, hybrid = self._hybrid_products(ctx, mvs, refined)
            gaussians, points = products.gaussians, products.points
        else:
            result = merge_gaussians(None, mvs)
            gaussians, points = result.gaussians, result.gaussians
            if refined is not None:  # the viewer set only: the survey points keep the converted attributes
                gaussians = _same_rows(merge_gaussians(None, refined).gaussians, gaussians)
        background_file = self._background_file(ctx)
        refined_background = self._refined_files(ctx).get(background_file)  # type: ignore[arg-type]
        if refined_background is not None and refined_background.is_file():
            background_file = refined_background
        background = _background_layer(background_file, gaussians)
        if background is not None:  # the viewer product only: the survey points never hold it
            gaussians = GaussianSet.concatenate([gaussians, background])
        gaussians, layers = _visible_layers(gaussians)
        written = export_gaussian_ply(layout.merged_ply, gaussians, ExportOptions(extra_fields=True))
        crs = ctx.config.input.crs
        from core.io.origin import write_origin
        from fusion.convert_options import LAYERS

        # the viewer product's sidecar names its layers (and the CRS the user gave)
        write_origin(layout.merged_ply, gaussians.origin, crs, layers={k: int(v) for k, v in LAYERS.items()})
        chunk = _survey_exports(ctx, points, crs)
        _viewer_exports(ctx, gaussians, points, crs)
        return MergeResult(
            merged=len(gaussians),
            written=written.num_written,
            mvs=layers["mvs"],
            splats=layers["splats"],
            background=layers["background"],
            points=len(points),
            survey_refined=refined is not None,
            **hybrid,
            background_refined=background_file == ctx.layout.refined_background_splats,
            memory_limit_mb=ctx.options(self).memory_limit_mb if chunk is not None else None,
            export_chunk_points=chunk,
        )

    def _hybrid_products(self, ctx: StageContext, mvs: Any, refined: Any) -> tuple[Any, dict[str, Any]]:
        """Reads what the hybrid needs (splats, masks, classes) and writes export/splats.ply; with ``refined`` (the
        survey layer's refined appearance, one per MVS Gaussian) the viewer set takes it. Returns the products and
        the hybrid's fields of :class:`MergeResult` (the point selections' counts of
        :func:`fusion.survey.hybrid_products`, whether the fill was refined)."""
        from core.io.gaussian_ply import read_gaussian_ply
        from fusion.export import export_gaussian_ply
        from fusion.merge import merge_hybrid
        from fusion.survey import hybrid_products, view_tests
        from hybridsplat import project_io

        layout = ctx.layout
        opts: MergeOptions = ctx.options(self)
        splats = read_gaussian_ply(layout.cleaned_splats)
        fill_file = self._refined_files(ctx).get(layout.cleaned_splats)
        refined_fill = _refined_rows(fill_file, splats, "splats/cleaned.ply's")
        needs = project_io.needs_splats_per_gaussian(layout, mvs)
        export_gaussian_ply(layout.splats_export, splats)
        cameras, _ = project_io.read_project_model(layout, layout.dense_workspace.sparse)
        views = view_tests(cameras, project_io.read_region_masks(layout, cameras), mvs, needs, splats)
        codes, predicted = {}, None
        if opts.needs_mvs_classes and not opts.keep_needs_splats and needs.any():
            codes = project_io.read_needs_splats_class_codes(layout)
            if any(n in codes for n in opts.needs_mvs_classes):
                predicted = project_io.classified_field_per_gaussian(layout, mvs, "classification").astype("int64")
        products = hybrid_products(mvs, splats, needs, views, opts, predicted, codes)
        if refined is not None or refined_fill is not None:
            survey, fill = mvs if refined is None else refined, splats if refined_fill is None else refined_fill
            viewer = merge_hybrid(survey, fill, needs, keep_needs_splats=opts.keep_needs_splats).gaussians
            products.gaussians = _same_rows(viewer, products.gaussians)
        return products, {**products.counts, "fill_refined": refined_fill is not None}

    def report_section(self, result: MergeResult) -> ReportSection | None:
        line = (
            f"The merged product (export/merged.ply) holds {result.written:,} Gaussians in three layers "
            f"(its `source` field): survey {result.mvs:,} (the MVS Gaussians, positions as converted"
            f"{', appearance refined' if result.survey_refined else ''}), "
            f"fill {result.splats:,} (splats trained in the region masks), background "
            f"{result.background:,} (what the photos see beyond the survey region; viewer product only). "
            f"The survey points (merged_points.ply/.las) hold {result.points:,} points, no background."
        )
        return ReportSection("The merged product's layers", (line,))

    def summary(self, result: MergeResult) -> str:
        layers = f"survey {result.mvs}, fill {result.splats}, background {result.background}"
        text = f"{result.written} Gaussians in the merged product ({layers})"
        if result.point_splats is not None:
            c = result.point_splats
            text += f", {result.points} survey points ({c.get('kept', 0)} of {c.get('input', 0)} splats trustworthy)"
        return text


def _viewer_exports(ctx: StageContext, gaussians: Any, points: Any, crs: str | None) -> None:
    """The viewer product in every ``viewer_formats`` format; a 3D Tiles tileset also holds the survey points just
    written to export/merged_points.ply (the same cloud, from memory: the file appears only when the stage ends).
    The mesh cannot go into it here: the mesh stage runs after the merge (``hybridsplat export merged.ply --out
    DIR/tileset.json --survey-points export/merged_points.ply --mesh export/mesh.glb`` adds both)."""
    from fusion.export import ExportOptions, export_gaussians, export_tileset, gaussians_to_points, prepare

    for fmt in ctx.options(MergeStage).viewer_formats:
        path = ctx.layout.merged_viewer(fmt)
        if fmt == "3dtiles":  # what export_points wrote: the default filters, then one point per Gaussian
            cloud = gaussians_to_points(prepare(points, ExportOptions()).gaussians)
            export_tileset(path, gaussians, ExportOptions(crs=crs), points=cloud)
        else:
            export_gaussians(path, gaussians, ExportOptions(crs=crs))


def _refined_rows(path: Path | None, base: Any, what: str) -> Any:
    """A layer with its appearance refined (splats/survey.ply, fill_refined.ply, background_refined.ply), checked row
    for row against the layer as converted or trained (``base``, named ``what`` in the error); None without the
    file."""
    import numpy as np

    from core.errors import DataError
    from core.io.gaussian_ply import read_gaussian_ply

    if path is None or not path.is_file():
        return None
    refined = read_gaussian_ply(path)
    same = np.array_equal(refined.origin, base.origin) and np.array_equal(refined.means, base.means)
    if len(refined) != len(base) or not same:
        raise DataError(f"does not hold {what} positions row for row: run the appearance stage again", path)
    return refined


def _same_rows(viewer: Any, survey: Any) -> Any:
    """``viewer`` (the merge of the refined survey layer) with the fields of ``survey`` (the same merge of the
    converted one: the same rows, since the merge selects by position and class only)."""
    import numpy as np

    if len(viewer) != len(survey) or not np.array_equal(viewer.means, survey.means):
        raise AssertionError("the refined and converted survey layers merged to different rows")
    viewer.fields = dict(survey.fields)
    return viewer


def _visible_layers(gaussians: Any) -> tuple[Any, dict[str, int]]:
    """The viewer set without the Gaussians below the exporters' opacity threshold (``ExportOptions.min_opacity``:
    invisible once quantised; a refined fill splat can fade to it) and its count per layer (``mvs``, ``splats``,
    ``background``: what export/merged.ply holds)."""
    import numpy as np

    from fusion.convert_options import Source
    from fusion.export import ExportOptions

    visible = gaussians.opacities >= np.float32(ExportOptions().min_opacity)
    if not visible.all():
        gaussians = gaussians.subset(visible)
    source = np.asarray(gaussians.fields["source"])
    layers = {"mvs": Source.MVS, "splats": Source.SPLAT, "background": Source.BACKGROUND}
    return gaussians, {name: int((source == value).sum()) for name, value in layers.items()}


def _background_layer(path: Path | None, merged: Any) -> Any:
    """The background layer (splats/background.ply or its refined copy) with the merged set's fields (``source`` =
    BACKGROUND, the others 0), or None when there is none (its invisible Gaussians are left out with the others',
    :func:`_visible_layers`)."""
    import numpy as np

    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.convert_options import Source

    if path is None or not path.is_file():
        return None
    background = read_gaussian_ply(path)
    if len(background) == 0:
        return None
    n = len(background)
    background.fields = {k: np.zeros(n, dtype=np.asarray(v).dtype) for k, v in merged.fields.items()}
    background.fields["source"] = np.full(n, Source.BACKGROUND, dtype=np.uint8)
    return background
