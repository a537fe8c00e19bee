"""Stage ``report``: report/report.{json,md,html} from the manifest and eval/metrics.json, see eval.report."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hybridsplat.stages.base import Stage, StageContext


@dataclass(frozen=True)
class ReportStageOptions:
    """Options of the ``report`` stage.

    max_panels: render | photo | error panels shown per product (its lowest-PSNR held-out views).
    """

    max_panels: int = 4


class ReportStage(Stage):
    name = "report"
    Options = ReportStageOptions
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
        opts: ReportStageOptions = ctx.options(self)
        paths = write_project_report(ctx.layout, units=ctx.config.input.units, max_panels=opts.max_panels)
        return {"html_bytes": paths.html.stat().st_size}

    def summary(self, counts: dict[str, Any]) -> str:
        return f"report.html {counts['html_bytes'] / 1e6:.1f} MB"


def write_project_report(layout, units: str | None = None, max_panels: int | None = None):
    """The report of the project at ``layout`` (also for folders that only hold metrics), see eval.report."""
    from eval.report import DEFAULT_MAX_PANELS, ReportPaths, write_report

    paths = ReportPaths(layout.report_json, layout.report_md, layout.report_html)
    panels = DEFAULT_MAX_PANELS if max_panels is None else max_panels
    return write_report(layout.manifest, layout.metrics_json, paths, max_panels=panels, units=units,
                        per_material_file=layout.per_material_json)  # fmt: skip
