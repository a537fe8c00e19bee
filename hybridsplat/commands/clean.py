"""``hybridsplat clean PROJECT``: the ``clean`` stage alone (floaters and degenerate splats removed)."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("clean")
    def clean(
        project: Path = typer.Argument(..., help="Project folder (after 'hybridsplat train')."),
        min_opacity: float | None = typer.Option(None, help="Remove splats with opacity below this (< 0: off)."),
        min_cluster_size: int | None = typer.Option(None, help="Clusters smaller than this are floaters."),
        force: bool = typer.Option(False, "--force", help="Rerun even when up to date."),
    ) -> None:
        """Remove trained splats outside every mask, near-transparent, over-large or in small isolated clusters."""
        from hybridsplat.commands.common import run_project_stage

        overrides = {"min_opacity": min_opacity, "min_cluster_size": min_cluster_size}
        run_project_stage(project, "clean", overrides, force=force)
