"""``hybridsplat sfm``: structure from motion (or known-pose triangulation) into PROJECT/sparse."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("sfm")
    def sfm(
        input_path: Path = typer.Argument(
            ..., help="A folder of photos, or a data_synth scene folder (images/, sparse/0/)."
        ),
        out: Path = typer.Option(..., "--out", help="Project folder; the model is written to PROJECT/sparse/."),
        known_poses: bool = typer.Option(
            False,
            "--known-poses",
            help="Use the known cameras (scene sparse/0 or --reference): match + triangulate only.",
        ),
        masks: Path | None = typer.Option(
            None, "--masks", help="Folder of PNG masks NAME.png (black = ignore features)."
        ),
        reference: Path | None = typer.Option(
            None, "--reference", help="COLMAP model with reference cameras to align to (or to use with --known-poses)."
        ),
        matcher: str = typer.Option("exhaustive", help="exhaustive | sequential | spatial | vocabtree."),
        max_image_size: int = typer.Option(
            1600, help="Feature extraction on images downscaled to this longer side (px)."
        ),
        seed: int = typer.Option(0, help="Random seed of the mapper (same inputs + seed -> same model)."),
    ) -> None:
        """Structure from motion with pycolmap: SIFT, matching, mapping (or triangulation), alignment to a reference."""
        import pycolmap
        from rich.console import Console
        from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

        from core.errors import ConfigError
        from recon.sfm import Matcher, SfmOptions
        from recon.stages import sfm_stage

        pycolmap.logging.minloglevel = 1  # COLMAP's INFO lines drown the progress bars
        console = Console(stderr=True)
        try:
            parsed = Matcher(matcher)
        except ValueError as err:
            raise ConfigError(f"unknown matcher {matcher!r} ({err})") from err
        options = SfmOptions(
            matcher=parsed, max_image_size=max_image_size, seed=seed, mask_dir=str(masks) if masks else None
        )
        with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(), console=console) as bar:
            task = bar.add_task(
                "triangulating known poses" if known_poses else "SfM: features, matching, mapping", total=1
            )
            report = sfm_stage(
                input_path, out, known_poses, options, reference, progress=lambda s, d, t: bar.update(task, completed=d)
            )
        for name, why in sorted({**report.skipped, **report.unregistered}.items()):
            console.print(f"[yellow]not registered[/]: {name}: {why}")
        line = (
            f"{len(report.registered)}/{report.num_images} images registered, {report.num_points} points, "
            f"reprojection error {report.mean_reprojection_error:.3f} px, "
            f"mean track length {report.mean_track_length:.2f}"
        )
        if report.alignment is not None:
            a = report.alignment
            line += (
                f"; aligned to the reference: scale {a.transform.scale:.6g}, centre residual rms {a.rms_inliers:.4g} m "
                f"({a.num_inliers}/{len(a.residuals)} inliers)"
            )
        typer.echo(line)
