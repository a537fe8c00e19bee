"""Stage ``report``: report/report.{json,md,html} from the manifest and eval/metrics.json, see eval.report.

Besides the evaluation's tables, every stage that declares a :meth:`~hybridsplat.stages.base.Stage.report_section`
gets its section, made from the result it recorded in the manifest, and the notes beside the products' figures
(their training steps, the renderer) come from the train, baseline, background, appearance and eval stages' results
(:func:`run_notes`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from eval.report_options import ReportOptions
from hybridsplat.disk_space import tree_bytes
from hybridsplat.stages import sizes
from hybridsplat.stages.base import Stage, StageContext, StageResult

if TYPE_CHECKING:
    from eval.report import RunNotes

_C2C_VIEWS_PX = (990, 462)  # eval.plots.c2c_views_jpeg: 9 × 4.2 in at 110 dpi
_THUMBNAIL_MAX_SIDE = 1500  # eval.report.THUMBNAIL_MAX_SIDE


@dataclass(frozen=True)
class ReportResult(StageResult):
    """What the report stage made: report/report.html of ``html_bytes`` bytes."""

    html_bytes: int = 0


class ReportStage(Stage):
    name = "report"
    Options = ReportOptions
    Result = ReportResult
    title = "report"

    def inputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.metrics_json, ctx.layout.per_material_json, ctx.layout.accuracy_json]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.report_dir]

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of report/: its text (tables, configuration, JSON and Markdown) at most 8 times the manifest,
        metrics, per-material table and config.toml it is made from, + 256 KiB; the SVG charts (a 50-bar histogram
        per C2C product, per-view bars of PSNR, SSIM and LPIPS, the stages' time and memory bars); and, base64 (4/3)
        in the HTML, JPEGs of each C2C product's views (990 × 462 px), of every render panel and stage figure
        (longer side at most 1500 px)."""
        from hybridsplat.stages import stage_names

        layout = ctx.layout
        sources = [layout.manifest, layout.metrics_json, layout.per_material_json, layout.config]
        c2c, bars = _metrics_counts(layout.metrics_json)
        figures = sorted(layout.eval_dir.glob("plots/render_*.png")) + sorted(layout.classify_figures_dir.glob("*.png"))
        jpegs = c2c * sizes.jpeg_bytes(*_C2C_VIEWS_PX) + sum(_thumbnail_bytes(f) for f in figures)
        svgs = c2c * sizes.svg_bytes(50) + 3 * sizes.svg_bytes(bars) + sizes.svg_bytes(2 * len(stage_names()))
        return 8 * tree_bytes(sources) + 256 * sizes.KIB + svgs + -(-4 * jpegs // 3) + sizes.LOG_BYTES

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        # The report shows every stage's timings and counts: it is current while no other stage's record changed
        # (being found up to date does not change a record's content).
        from hybridsplat.manifest import Manifest

        return {"stages": Manifest(ctx.layout.manifest).content_digest(exclude=(self.name,))}

    def run(self, ctx: StageContext) -> ReportResult:
        opts: ReportOptions = ctx.options(self)
        paths = write_project_report(ctx.layout, units=ctx.config.input.units, max_panels=opts.max_panels)
        return ReportResult(html_bytes=paths.html.stat().st_size)

    def summary(self, result: ReportResult) -> str:
        return f"report.html {result.html_bytes / 1e6:.1f} MB"


def _metrics_counts(path: Path) -> tuple[int, int]:
    """(products with a C2C measurement, held-out view bars over all products) of eval/metrics.json; (0, 0) when
    it is missing or unreadable."""
    import json

    try:
        products = json.loads(path.read_text(encoding="utf-8")).get("products") or {}
        entries = [p for p in products.values() if isinstance(p, dict)]
        c2c = sum(1 for p in entries if p.get("c2c"))
        bars = sum(len((p.get("images") or {}).get("per_view") or []) for p in entries)
    except (OSError, ValueError, AttributeError, TypeError):
        return 0, 0
    return c2c, bars


def _thumbnail_bytes(path: Path) -> int:
    """Upper bytes of the report's JPEG thumbnail of the image at ``path`` (0 when it cannot be read)."""
    found = sizes.photo_sizes(path.parent, [path.name])
    return sizes.jpeg_bytes(*sizes.thumbnail_size(found[0], _THUMBNAIL_MAX_SIDE)) if found else 0


def stage_sections(layout: Any) -> list[dict[str, Any]]:
    """The report sections of the registered stages, from the result each recorded in the project's manifest."""
    from hybridsplat.manifest import Manifest
    from hybridsplat.project_io import stage_result
    from hybridsplat.stages import registered_stages

    if not layout.manifest.is_file():
        return []
    manifest = Manifest(layout.manifest)
    sections = []
    for stage in registered_stages():
        result = stage_result(manifest, stage)
        section = stage.report_section(result) if result is not None else None
        if section is not None:
            sections.append({"title": section.title, "lines": list(section.lines),
                             "figures": [list(f) for f in section.figures]})  # fmt: skip
    return sections


def run_notes(layout: Any) -> RunNotes:
    """What the report tells of how the products were made (:class:`eval.report.RunNotes`), from the train,
    baseline, background, appearance and eval stages' results."""
    from eval.report import RunNotes, TrainingRun
    from hybridsplat.manifest import Manifest
    from hybridsplat.project_io import stage_result
    from hybridsplat.stages.appearance import AppearanceStage
    from hybridsplat.stages.background import BackgroundStage
    from hybridsplat.stages.baseline import BaselineStage
    from hybridsplat.stages.evaluate import EvalStage
    from hybridsplat.stages.train import TrainStage

    if not layout.manifest.is_file():
        return RunNotes()
    manifest = Manifest(layout.manifest)
    train, baseline = stage_result(manifest, TrainStage), stage_result(manifest, BaselineStage)
    background, appearance = stage_result(manifest, BackgroundStage), stage_result(manifest, AppearanceStage)
    evaluated = stage_result(manifest, EvalStage)
    return RunNotes(
        fill=TrainingRun(train.iterations, train.stopped_early) if train is not None and not train.reason else None,
        baseline=TrainingRun(baseline.iterations, baseline.stopped_early) if baseline is not None else None,
        background_steps=background.iterations if background is not None else 0,
        appearance_steps=appearance.iterations if appearance is not None else 0,
        renderer=evaluated.renderer if evaluated is not None else None,
    )


def write_project_report(layout, units: str | None = None, max_panels: int | None = None):
    """The report of the project at ``layout`` (also for folders that only hold metrics), see eval.report."""
    from eval.report import ReportPaths, write_report

    paths = ReportPaths(layout.report_json, layout.report_md, layout.report_html)
    panels = ReportOptions().max_panels if max_panels is None else max_panels
    return write_report(layout.manifest, layout.metrics_json, paths, max_panels=panels, units=units,
                        per_material_file=layout.per_material_json, sections=stage_sections(layout),
                        accuracy_file=layout.accuracy_json,
                        notes=run_notes(layout))  # fmt: skip
