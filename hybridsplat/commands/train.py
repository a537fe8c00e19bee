"""``hybridsplat train PROJECT``: the ``train`` stage alone (splats trained inside the region masks)."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("train")
    def train(
        project: Path = typer.Argument(..., help="Project folder (after classification: classify/points.ply, masks)."),
        iterations: int | None = typer.Option(None, help="Maximum training steps (early stop on hold-out pixels)."),
        downscale: int | None = typer.Option(None, help="Integer downscale of photos and masks for training."),
        cap: int | None = typer.Option(None, help="Hard budget of trained splats."),
        flat: bool | None = typer.Option(None, "--flat/--no-flat", help="Surface-aligned (flat) splats."),
        force: bool = typer.Option(False, "--force", help="Rerun even when up to date."),
    ) -> None:
        """Train new splats inside the masks with the trusted MVS Gaussians frozen as context (a progress bar shows
        masked loss, masked PSNR and the splat count)."""
        from hybridsplat.commands.common import run_project_stage

        overrides = {"iterations": iterations, "downscale": downscale, "cap": cap, "flat": flat}
        run_project_stage(project, "train", overrides, force=force)
