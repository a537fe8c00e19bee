"""``hybridsplat status PROJECT``: per stage current / stale (why) / skipped (why) / running, without running."""

from __future__ import annotations

import json
from pathlib import Path

import typer


def status_command(
    project: Path = typer.Argument(..., help="A project folder (written by 'hybridsplat run')."),
    as_json: bool = typer.Option(False, "--json", help="Print the status as JSON (stable keys) instead of text."),
) -> None:
    """Say which stages are current, which are stale and why, which were skipped and why, and which one runs now
    (pid, since); with each stage's last time, peak memory and size from the manifest. Inputs are hashed as
    'run' would, nothing is written."""
    from hybridsplat.project_status import format_status, project_status

    status = project_status(project)
    if as_json:
        typer.echo(json.dumps(status.to_json(), indent=2, default=str))
    else:
        typer.echo(format_status(status))


def register(app: typer.Typer) -> None:
    """Add ``status`` to the CLI."""
    app.command("status", help=status_command.__doc__)(status_command)
