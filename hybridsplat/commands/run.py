"""``hybridsplat run`` (every stage on an input) and ``hybridsplat demo`` (the built-in synthetic scene + run)."""

from __future__ import annotations

from pathlib import Path

import typer

from hybridsplat.commands.common import input_options_from_cli, print_result, stage_options_from_cli

DEMO_STAGES = {
    "mesh": {"budget": 2_000},
    "train": {"iterations": 600},
    "baseline": {"enabled": True, "iterations": 1_000},
}
"""The demo's stage options: a small mesh and CPU-sized training budgets for the hybrid and the whole-scene
baseline, so that every stage of the demo scene runs in minutes on 2 cores (``bench/bench_pipeline.py`` sweeps
the budgets)."""


def register(app: typer.Typer) -> None:
    @app.command("run")
    def run(
        input_path: Path = typer.Argument(
            ..., help="A folder of photos (or with images/), a COLMAP workspace, or a data_synth scene."
        ),
        out: Path = typer.Option(..., "--out", help="Project folder (created); its layout: docs/conventions.md."),
        model: int | None = typer.Option(None, help="Model N of a COLMAP workspace with several (default: largest)."),
        cameras: Path | None = typer.Option(
            None, help="COLMAP model of known cameras: poses fixed, only matching and triangulation."
        ),
        full_sfm: bool = typer.Option(
            False, "--full-sfm", help="Ignore the cameras a scene or workspace brings; run SfM and align to them."
        ),
        reference: Path | None = typer.Option(
            None, help="Align to these camera centres: a text file 'NAME X Y Z' per line, or a COLMAP model."
        ),
        units: str = typer.Option("m", help="Unit of the reference coordinates: m | mm | cm | ft."),
        crs: str | None = typer.Option(None, help="CRS of the reference (EPSG:N), written to sidecars and LAS."),
        holdout: int = typer.Option(
            -1, help="Hold out every N-th photo for evaluation (default: the input's own test views, else 8; 0: none)."
        ),
        splat_masks: Path | None = typer.Option(None, help="Masks of regions that need splats (white), NAME.png."),
        feature_masks: Path | None = typer.Option(None, help="COLMAP masks for feature extraction (black = ignore)."),
        camera_model: str = typer.Option("SIMPLE_RADIAL", help="COLMAP camera model for SfM."),
        single_camera: bool = typer.Option(
            True, "--single-camera/--camera-per-photo", help="One camera for all photos, or one per photo."
        ),
        matcher: str = typer.Option("exhaustive", help="exhaustive | sequential | spatial | vocabtree."),
        mvs_backend: str = typer.Option("auto", help="auto | cpu | colmap (COLMAP PatchMatch needs CUDA)."),
        max_image_size: int = typer.Option(1000, help="Longer side of the dense images, px (-1: full size)."),
        convert_mode: str = typer.Option("adaptive", help="MVS-to-Gaussian conversion: adaptive | paper."),
        lidar: Path | None = typer.Option(
            None, help="Reference cloud (PLY/LAS/LAZ/E57, e.g. a LiDAR scan) for the C2C evaluation."
        ),
        lpips_weights: Path | None = typer.Option(None, help="LPIPS v0.1 AlexNet weights (.npz)."),
        mesh: int = typer.Option(0, "--mesh", help="Also write a mesh with this many triangles (0: no mesh)."),
        train_iterations: int | None = typer.Option(
            None, help="Most splat-training steps (default: the train stage's; it stops early on a plateau)."
        ),
        baseline: bool = typer.Option(
            False, "--baseline", help="Also train the whole-scene 3DGS baseline and compare with it in the report."
        ),
        seed: int = typer.Option(0, help="Seed of every random choice."),
        force: list[str] = typer.Option([], "--force", help="Rerun this stage even when up to date (repeatable)."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    ) -> None:
        """Run every stage end to end; stages already up to date are skipped, and say so."""
        from hybridsplat.config import ProjectConfig
        from hybridsplat.pipeline import run_pipeline
        from hybridsplat.terminal import Terminal

        config = ProjectConfig(
            input=input_options_from_cli(
                input_path, model, cameras, full_sfm, reference, units, crs, holdout, splat_masks, feature_masks
            ),
            seed=seed,
            stages=stage_options_from_cli(
                sfm={"camera_model": camera_model, "single_camera": single_camera, "matcher": matcher},
                mvs={"backend": mvs_backend, "max_image_size": max_image_size},
                convert={"mode": convert_mode},
                mesh={"budget": mesh},
                train={"iterations": train_iterations},
                baseline={"enabled": True if baseline else None},
                eval={
                    "lpips_weights": str(lpips_weights.resolve()) if lpips_weights else "",
                    "reference": str(lidar.resolve()) if lidar else "",
                },
            ),
        )
        terminal = Terminal(quiet=quiet)
        terminal.line(f"hybridsplat run: {input_path} -> {out}")
        manifest = run_pipeline(out, config, terminal=terminal, force=force)
        print_result(terminal, out, manifest)

    @app.command("demo")
    def demo(
        out: Path = typer.Option(Path("demo_project"), "--out", help="Folder for the scene (OUT/scene) and project."),
        preset: str = typer.Option("demo", help="data_synth preset of the built-in scene (demo: a reduced tabletop)."),
        seed: int = typer.Option(0, help="Seed of the scene and the pipeline."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    ) -> None:
        """The main job on the built-in synthetic scene: generate it, then run every stage on it."""
        from data_synth import generate_scene
        from hybridsplat.config import InputOptions, ProjectConfig
        from hybridsplat.pipeline import run_pipeline
        from hybridsplat.terminal import Terminal

        terminal = Terminal(quiet=quiet)
        scene = out / "scene"
        if not (scene / "scene.json").is_file():
            terminal.line(f"hybridsplat demo: generating the {preset} scene into {scene}")
            generate_scene(preset, scene, seed=seed, overwrite=True)
        else:
            terminal.line(f"hybridsplat demo: using the scene in {scene}")
        project = out / "project"
        config = ProjectConfig(
            input=InputOptions(path=str(scene.resolve())),
            seed=seed,
            stages=stage_options_from_cli(**DEMO_STAGES),
        )
        manifest = run_pipeline(project, config, terminal=terminal)
        print_result(terminal, project, manifest)
