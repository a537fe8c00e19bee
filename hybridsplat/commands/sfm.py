"""``hybridsplat sfm INPUT --out PROJECT``: the ``sfm`` stage alone (camera poses and sparse model)."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("sfm")
    def sfm(
        input_path: Path = typer.Argument(
            ..., help="A folder of photos (or with images/), a COLMAP workspace, or a data_synth scene."
        ),
        out: Path = typer.Option(..., "--out", help="Project folder; the model is written to PROJECT/sparse/."),
        cameras: Path | None = typer.Option(None, help="COLMAP model of known cameras (poses fixed)."),
        full_sfm: bool = typer.Option(False, "--full-sfm", help="Ignore the cameras a scene or workspace brings."),
        reference: Path | None = typer.Option(None, help="Camera centres to align to: 'NAME X Y Z' text or a model."),
        units: str = typer.Option("m", help="Unit of the reference coordinates: m | mm | cm | ft."),
        crs: str | None = typer.Option(None, help="CRS of the reference (EPSG:N)."),
        feature_masks: Path | None = typer.Option(None, help="COLMAP masks NAME.png (black = ignore features)."),
        camera_model: str = typer.Option("SIMPLE_RADIAL", help="COLMAP camera model."),
        single_camera: bool = typer.Option(True, "--single-camera/--camera-per-photo"),
        matcher: str = typer.Option("exhaustive", help="exhaustive | sequential | spatial | vocabtree."),
        max_image_size: int = typer.Option(1600, help="Features are extracted at this longer side (px)."),
        seed: int = typer.Option(0, help="Seed (same inputs + seed -> same model)."),
        force: bool = typer.Option(False, "--force", help="Rerun even when up to date."),
    ) -> None:
        """Structure from motion (or triangulation with known cameras) and alignment to a reference."""
        from hybridsplat.commands.common import input_options_from_cli, stage_options_from_cli
        from hybridsplat.config import ProjectConfig
        from hybridsplat.pipeline import run_pipeline
        from hybridsplat.stages import stage_named
        from hybridsplat.terminal import Terminal

        config = ProjectConfig(
            input=input_options_from_cli(
                input_path, cameras=cameras, full_sfm=full_sfm, reference=reference, units=units, crs=crs,
                feature_masks=feature_masks,
            ),
            seed=seed,
            stages=stage_options_from_cli(
                sfm={
                    "camera_model": camera_model,
                    "single_camera": single_camera,
                    "matcher": matcher,
                    "max_image_size": max_image_size,
                }
            ),
        )  # fmt: skip
        run_pipeline(out, config, [stage_named("sfm")], Terminal(), ["sfm"] if force else [])
