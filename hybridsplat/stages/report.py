"""Stage ``report``: report/report.{json,md,html} from the manifest and eval/metrics.json, see eval.report."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hybridsplat.stages.base import Stage, StageContext


class ReportStage(Stage):
    name = "report"
    title = "report"

    def inputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.metrics_json]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.report_dir]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        # The report shows every stage's timings and counts: it is current while no other stage's record changed
        # (being found up to date does not change a record's content).
        from hybridsplat.manifest import Manifest

        return {"stages": Manifest(ctx.layout.manifest).content_digest(exclude=(self.name,))}

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from eval.report import write_report

        paths = write_report(ctx.layout.root, ctx.layout.report_dir)
        return {"html_bytes": paths.html.stat().st_size}

    def summary(self, counts: dict[str, Any]) -> str:
        return f"report.html {counts['html_bytes'] / 1e6:.1f} MB"
