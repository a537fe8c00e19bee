"""``hybridsplat report PROJECT``: the ``report`` stage alone (report/report.{json,md,html}).

On a folder that is not a project (no config.toml: e.g. only an ``eval/metrics.json`` from ``hybridsplat eval``),
the report is written from whatever it holds.
"""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("report")
    def report(
        project: Path = typer.Argument(..., help="Project folder (reads manifest.json and eval/metrics.json)."),
        max_panels: int | None = typer.Option(None, help="Render panels per product (its lowest-PSNR views)."),
        force: bool = typer.Option(True, "--force/--if-changed", help="Rewrite even when up to date."),
    ) -> None:
        """Build report.json (stable schema), report.md and a self-contained report.html of a project."""
        from hybridsplat.layout import ProjectLayout

        layout = ProjectLayout(project)
        if layout.config.is_file():
            from hybridsplat.commands.common import print_result, run_project_stage

            terminal, manifest = run_project_stage(project, "report", {"max_panels": max_panels}, force=force)
            print_result(terminal, project, manifest)
            return
        from hybridsplat.stages.report import write_project_report

        paths = write_project_report(layout, max_panels=max_panels)
        typer.echo(f"wrote {paths.json}, {paths.markdown}, {paths.html}")
