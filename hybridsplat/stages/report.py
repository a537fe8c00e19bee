"""Stage ``report``: report/report.{json,md,html} from the manifest and eval/metrics.json, see eval.report.

Besides the evaluation's tables, every stage that declares a :meth:`~hybridsplat.stages.base.Stage.report_section`
gets its section, made from the counts it recorded in the manifest.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from eval.report_options import ReportOptions
from hybridsplat.stages.base import Stage, StageContext


class ReportStage(Stage):
    name = "report"
    Options = ReportOptions
    title = "report"

    def inputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.metrics_json, ctx.layout.per_material_json]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.report_dir]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        # The report shows every stage's timings and counts: it is current while no other stage's record changed
        # (being found up to date does not change a record's content).
        from hybridsplat.manifest import Manifest

        return {"stages": Manifest(ctx.layout.manifest).content_digest(exclude=(self.name,))}

    def run(self, ctx: StageContext) -> dict[str, Any]:
        opts: ReportOptions = ctx.options(self)
        paths = write_project_report(ctx.layout, units=ctx.config.input.units, max_panels=opts.max_panels)
        return {"html_bytes": paths.html.stat().st_size}

    def summary(self, counts: dict[str, Any]) -> str:
        return f"report.html {counts['html_bytes'] / 1e6:.1f} MB"


def stage_sections(layout: Any) -> list[dict[str, Any]]:
    """The report sections of the registered stages, from the counts each recorded in the project's manifest."""
    from hybridsplat.manifest import Manifest
    from hybridsplat.stages import registered_stages

    if not layout.manifest.is_file():
        return []
    records = Manifest(layout.manifest).stages
    sections = []
    for stage in registered_stages():
        record = records.get(stage.name)
        if record is None or record.skipped:
            continue
        section = stage.report_section(record.counts or {})
        if section is not None:
            sections.append({"title": section.title, "lines": list(section.lines),
                             "figures": [list(f) for f in section.figures]})  # fmt: skip
    return sections


def write_project_report(layout, units: str | None = None, max_panels: int | None = None):
    """The report of the project at ``layout`` (also for folders that only hold metrics), see eval.report."""
    from eval.report import ReportPaths, write_report

    paths = ReportPaths(layout.report_json, layout.report_md, layout.report_html)
    panels = ReportOptions().max_panels if max_panels is None else max_panels
    return write_report(layout.manifest, layout.metrics_json, paths, max_panels=panels, units=units,
                        per_material_file=layout.per_material_json, sections=stage_sections(layout))  # fmt: skip
