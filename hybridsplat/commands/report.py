"""``hybridsplat report PROJECT``: JSON, Markdown and self-contained HTML reports of a project's evaluation."""

from __future__ import annotations

from pathlib import Path

import typer


def report(
    project: Path = typer.Argument(..., help="Project folder (reads manifest.json and eval/metrics.json)."),
    out: Path | None = typer.Option(None, "--out", help="Output folder (default: PROJECT/report)."),
) -> None:
    """Build report.json (stable schema), report.md and a self-contained report.html.

    Tables of C2C (mean, st. dev., ...) and image metrics (whole image and masked) per product, plots,
    stage timings and versions, from PROJECT/manifest.json and PROJECT/eval/metrics.json."""
    from eval.report import write_report

    paths = write_report(project, out)
    typer.echo(f"wrote {paths.json}, {paths.markdown}, {paths.html}")


def register(app: typer.Typer) -> None:
    app.command("report")(report)
