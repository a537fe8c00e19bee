"""Stage ``classify``: per-point features of the dense cloud → random forest → classify/points.ply.

The cloud keeps its positions, colours and normals and gains ``classification`` (uint8 class code),
``probability`` (float32, of that class) and ``needs_splats`` (uint8 0/1). classify/report.json records the
model, the classes, the point spacing (the masks stage uses it), the counts per class and the model's feature
importances. The report shows classify/figures/classes.png (the cloud coloured by class) and, with a model,
classify/figures/importances.png.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from classify.options import ClassifyOptions
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

_IMPORTANCE_BARS = 20  # classify.figures.importances_png draws the top 20 features


@dataclass(frozen=True)
class ClassifyResult(StageResult):
    """What the classify stage made: ``points`` classified, ``needs_splats`` of them, the ``model`` (its path, or
    the no-model fallback's name), the points ``per_class`` (class name → count), the point spacing (m), the
    seconds it took and its ``figures`` (paths relative to the project). Streamed (``memory_limit_mb``, MiB): its
    peak resident memory (MiB), the ``cells`` it ran in and how often one was ``regrown``."""

    points: int = 0
    needs_splats: int = 0
    model: str = ""
    per_class: dict[str, int] = field(default_factory=dict)
    spacing_m: float = 0.0
    seconds: float = 0.0
    figures: tuple[str, ...] = ()
    memory_limit_mb: float | None = omitted_if_none()
    peak_rss_mb: float | None = omitted_if_none()
    cells: int | None = omitted_if_none()
    regrown: int | None = omitted_if_none()


class ClassifyStage(Stage):
    name = "classify"
    Options = ClassifyOptions
    Result = ClassifyResult
    title = "classify the dense cloud"
    command_help = (
        "Classify the dense cloud into PROJECT/classify/points.ply (classification, probability, needs_splats)."
    )
    command_options = (
        CliOption("model", help="default | none (no-model fallback) | PATH (a .skops model)."),
        CliOption("threshold", help="Needs-splats probability threshold (default: the model's)."),
    )
    run_options = (CliOption("memory_limit_mb", "--memory-limit", help=MEMORY_LIMIT_HELP),)

    def inputs(self, ctx: StageContext) -> list[Path]:
        from classify.run import resolve_model_path

        paths = [ctx.layout.fused_ply, ctx.layout.fused_vis]
        model = resolve_model_path(ctx.options(self).model)
        return paths + ([model] if model is not None and model.is_file() else [])

    def outputs(self, ctx: StageContext) -> list[Path]:
        paths = [ctx.layout.classified_points, ctx.layout.classify_report, ctx.layout.classes_figure]
        return paths + ([ctx.layout.importances_figure] if self._has_model(ctx) else [])

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of classify/: points.ply is fused.ply plus 8 bytes a point (classification, probability,
        needs_splats: 6) and a header (with a memory limit also the streamed classification's temporary cell
        files, :func:`classify.stream.temp_bytes`); report.json and the log 64 KiB each; the
        figures as RGBA PNGs of their sizes at 100 dpi (classes 11 × 5.2 in; importances 6.5 × 6.6 in at most
        (20 bars), + 1 in a side for feature names that reach past its edge)."""
        points = sizes.ply_vertices(ctx.layout.fused_ply).count
        cloud = tree_bytes([ctx.layout.fused_ply]) + 8 * points + sizes.PLY_HEADER_BYTES + sizes.SIDECAR_BYTES
        if ctx.options(self).memory_limit_mb is not None:
            from classify.stream import temp_bytes

            cloud += temp_bytes(points, tree_bytes([ctx.layout.fused_vis]))  # the streamed classification's cells
        figures = sizes.figure_png_bytes(11.0, 5.2)
        if self._has_model(ctx):
            figures += sizes.figure_png_bytes(6.5, 0.28 * _IMPORTANCE_BARS + 1.0, pad_in=1.0)  # long feature names
        return cloud + figures + sizes.JSON_BYTES + sizes.LOG_BYTES

    def _has_model(self, ctx: StageContext) -> bool:
        from classify.run import resolve_model_path

        model = resolve_model_path(ctx.options(self).model)
        return model is not None and model.is_file()

    def run(self, ctx: StageContext) -> ClassifyResult:
        from classify.run import classify_dense, write_classified, write_classify_figures
        from core.io.json_io import write_json_atomic

        opts: ClassifyOptions = ctx.options(self)
        if opts.memory_limit_mb is not None:
            return _run_streamed(ctx, opts, self._has_model(ctx))
        ctx.progress("features", 0, 1)
        result = classify_dense(ctx.layout.dense, opts.model, opts.threshold)
        ctx.progress("features", 1, 1)
        write_classified(ctx.layout.classified_points, result)
        report = result.report()
        write_json_atomic(ctx.layout.classify_report, report)
        importances = ctx.layout.importances_figure if self._has_model(ctx) else None
        figures = write_classify_figures(result, ctx.layout.classes_figure, importances)
        return _result(report, figures, ctx.layout.root)

    def summary(self, result: ClassifyResult) -> str:
        share = result.needs_splats / max(result.points, 1)
        text = f"{result.points} points, {share:.1%} need splats ({result.model})"
        if result.memory_limit_mb is not None:
            text += f", classified in {result.cells} cells (peak {result.peak_rss_mb or 0:.0f} MiB)"
        return text

    def report_section(self, result: ClassifyResult) -> ReportSection | None:
        if result.points <= 0:
            return None
        per = ", ".join(f"{k} {v:,}" for k, v in result.per_class.items())
        line = (f"{result.points:,} points, {result.needs_splats / result.points:.1%} need splats "
                f"({per}); model {Path(result.model).name or '?'}.")  # fmt: skip
        captions = {"classes": "the dense cloud coloured by class (top and side views)",
                    "importances": "the classifier's feature importances"}  # fmt: skip
        figures = tuple((f, captions.get(Path(f).stem, Path(f).stem)) for f in result.figures)
        return ReportSection("Classification and region masks", (line,), figures)


def _result(report: dict[str, Any], figures: list[Path], root: Path, **streamed: Any) -> ClassifyResult:
    """The stage's result from classify/report.json's content (:meth:`classify.run.ClassifiedCloud.report`), the
    figures written (relative to the project ``root``) and, when streamed, its memory counts."""
    return ClassifyResult(
        points=report["points"],
        needs_splats=report["needs_splats"],
        model=report["model"],
        per_class=report["per_class"],
        spacing_m=report["spacing_m"],
        seconds=report["seconds"],
        figures=tuple(str(f.relative_to(root)) for f in figures),
        **streamed,
    )


def _run_streamed(ctx: StageContext, opts: ClassifyOptions, has_model: bool) -> ClassifyResult:
    """The fused cloud classified cell by cell (:func:`classify.stream.classify_stream`) into the same
    classify/points.ply as the in-memory path, with the same report and figures; temporary cell files in
    classify/."""
    import time

    from classify.features import views_from_workspace
    from classify.figures import classified_cloud_png, importances_png
    from classify.run import feature_options_for, load_classifier, needs_views
    from classify.stream import ClassifyStreamOptions, classify_stream, photo_cache_size
    from core.io.atomic import write_bytes_atomic
    from core.io.json_io import write_json_atomic
    from hybridsplat.manifest import PeakMemory
    from recon.workspace import fused_source

    t0 = time.perf_counter()
    model, classes, name, importances = load_classifier(opts.model)
    stream = ClassifyStreamOptions(opts.memory_limit_mb, work_dir=ctx.layout.classified_points.parent)  # type: ignore[arg-type]
    views = None
    if needs_views(feature_options_for(model)):  # photos load lazily: the first call only sizes the cache
        views = views_from_workspace(ctx.layout.dense)
        views = views_from_workspace(ctx.layout.dense, cache=photo_cache_size(views, stream.plan()))
    ctx.layout.classified_points.parent.mkdir(parents=True, exist_ok=True)
    ctx.progress("features", 0, 1)
    # the stage's own peak (sampled resident memory), not ru_maxrss, which keeps the earlier stages' peaks
    with PeakMemory() as memory:
        result = classify_stream(
            fused_source(ctx.layout.dense, stream.plan().chunk_size),
            model,
            views,
            classes,
            ctx.layout.classified_points,
            stream,
            opts.threshold,
        )
    ctx.progress("features", 1, 1)
    per_class = {c.name: result.per_code[c.code] for c in classes.classes}
    report = {
        "points": result.points,
        "needs_splats": result.needs_splats,
        "per_class": per_class,
        "model": name,
        "spacing_m": result.spacing,
        "seconds": time.perf_counter() - t0,
        "features": list(result.feature_names),
        "classes": classes.to_dict(),
        "importances": importances,
    }  # the keys of classify.run.ClassifiedCloud.report
    write_json_atomic(ctx.layout.classify_report, report)
    positions, codes = result.sample
    write_bytes_atomic(
        ctx.layout.classes_figure, classified_cloud_png(positions, codes, classes, counts=result.per_code)
    )
    figures = [ctx.layout.classes_figure]
    if has_model and importances:
        write_bytes_atomic(
            ctx.layout.importances_figure, importances_png(list(importances), list(importances.values()))
        )
        figures.append(ctx.layout.importances_figure)
    return _result(report, figures, ctx.layout.root, memory_limit_mb=opts.memory_limit_mb,
                   peak_rss_mb=memory.peak_mb, cells=result.cells, regrown=result.regrown)  # fmt: skip
