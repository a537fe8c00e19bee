"""``hybridsplat mvs PROJECT``: the ``mvs`` stage alone (depth maps and fused cloud in PROJECT/dense)."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("mvs")
    def mvs(
        project: Path = typer.Argument(..., help="Project folder (after 'hybridsplat sfm' or 'run')."),
        backend: str | None = typer.Option(None, help="cpu | colmap (PatchMatch, needs CUDA) | auto."),
        max_image_size: int | None = typer.Option(None, help="Longer side of the dense images, px (-1: full size)."),
        threads: int | None = typer.Option(None, help="CPU threads of the cpu backend (0: all)."),
        min_num_pixels: int | None = typer.Option(None, help="Fusion: minimum number of agreeing views."),
        force: bool = typer.Option(False, "--force", help="Rerun even when up to date."),
    ) -> None:
        """Depth + normal maps per photo, fused by COLMAP into PROJECT/dense/fused.ply (+ .vis)."""
        from hybridsplat.commands.common import run_project_stage

        overrides = {
            "backend": backend,
            "max_image_size": max_image_size,
            "threads": threads,
            "min_num_pixels": min_num_pixels,
        }
        run_project_stage(project, "mvs", overrides, force=force)
