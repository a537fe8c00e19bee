"""``hybridsplat mvs``: dense multi-view stereo + COLMAP fusion into PROJECT/dense."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("mvs")
    def mvs(
        project: Path = typer.Argument(..., help="Project folder with sparse/ (from 'hybridsplat sfm')."),
        backend: str = typer.Option("auto", help="cpu (our PyTorch MVS) | colmap (PatchMatch, needs CUDA) | auto."),
        max_image_size: int = typer.Option(-1, help="Longer side of the dense images in pixels (-1 = full size)."),
        images: Path | None = typer.Option(None, help="Image folder (default: the one recorded by 'hybridsplat sfm')."),
        threads: int | None = typer.Option(None, help="CPU threads for the cpu backend (default: all)."),
        min_num_pixels: int = typer.Option(3, help="Fusion: minimum number of agreeing views per fused point."),
    ) -> None:
        """Depth + normal maps per image, fused by COLMAP into PROJECT/dense/fused.ply (+ .vis)."""
        import pycolmap
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from core.errors import ConfigError
        from recon.mvs import FusionOptions, MvsBackend, MvsOptions
        from recon.stages import mvs_stage

        pycolmap.logging.minloglevel = 1  # COLMAP's INFO lines drown the progress bars
        console = Console(stderr=True)
        try:
            parsed = MvsBackend(backend)
        except ValueError as err:
            raise ConfigError(f"unknown backend {backend!r} ({err})") from err
        options = MvsOptions(
            backend=parsed,
            max_image_size=max_image_size,
            num_threads=threads,
            fusion=FusionOptions(min_num_pixels=min_num_pixels),
        )
        with Progress(
            TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=console
        ) as bar:
            tasks: dict[str, int] = {}

            def progress(stage: str, done: int, total: int) -> None:
                if stage not in tasks:
                    tasks[stage] = bar.add_task(f"{stage} maps", total=total)
                bar.update(tasks[stage], completed=done)

            report = mvs_stage(project, options, images, progress)
        typer.echo(
            f"{report.backend}: {report.num_views} views, {report.megapixels:.2f} MP, "
            f"{report.seconds_per_view:.2f} s/view ({report.seconds_per_megapixel:.2f} s/MP), "
            f"{report.num_points} fused points -> {Path(project) / 'dense' / 'fused.ply'}"
        )
