"""``hybridsplat run`` (the whole pipeline) and ``hybridsplat demo`` (synthetic scene + pipeline)."""

from __future__ import annotations

from pathlib import Path

import typer


def _print_summary(manifest: object) -> None:
    for name, rec in manifest.stages.items():  # type: ignore[attr-defined]
        if rec.skipped:
            status = f"skipped: {rec.reason}"
        elif rec.cached:
            status = "up to date"
        else:
            status = f"{rec.seconds:.1f} s, peak {rec.peak_mb:.0f} MB"
        typer.echo(f"  {name:<9} {status}")


def register(app: typer.Typer) -> None:
    @app.command("run")
    def run(
        input_path: Path = typer.Argument(..., help="A folder of photos, or a data_synth scene folder."),
        out: Path = typer.Option(
            ..., "--out", help="Project folder (created); see docs/conventions.md for its layout."
        ),
        known_poses: bool = typer.Option(
            True, "--known-poses/--full-sfm", help="Use the scene's known cameras, or run full SfM (and align)."
        ),
        mvs_backend: str = typer.Option("auto", help="auto | cpu | colmap (COLMAP PatchMatch needs CUDA)."),
        max_image_size: int = typer.Option(-1, help="Longer side of the dense images in pixels (-1: full size)."),
        convert_mode: str = typer.Option("adaptive", help="MVS-to-Gaussian conversion: paper | adaptive."),
        lpips_weights: Path | None = typer.Option(None, help="LPIPS v0.1 AlexNet weights (.npz)."),
        seed: int = typer.Option(0, help="Seed of every random choice."),
    ) -> None:
        """Run every stage end to end: SfM, MVS, conversion, merge/export, evaluation, report."""
        from hybridsplat.pipeline import PipelineConfig, run_pipeline

        config = PipelineConfig(
            known_poses=known_poses,
            mvs_backend=mvs_backend,
            max_image_size=max_image_size,
            convert_mode=convert_mode,
            lpips_weights=str(lpips_weights) if lpips_weights else None,
            seed=seed,
        )
        manifest = run_pipeline(input_path, out, config, progress=lambda m: typer.echo(f"[run] {m}", err=True))
        typer.echo(f"project {out}:")
        _print_summary(manifest)
        typer.echo(f"report: {out / 'report' / 'report.html'}")

    @app.command("demo")
    def demo(
        out: Path = typer.Option(
            Path("demo_project"), "--out", help="Folder for the scene (OUT/scene) and the project."
        ),
        preset: str = typer.Option("tiny", help="data_synth preset of the built-in scene."),
        seed: int = typer.Option(0, help="Seed of the scene and the pipeline."),
    ) -> None:
        """The main job on the built-in synthetic scene: generate it, then run the whole pipeline on it."""
        from data_synth import generate_scene
        from hybridsplat.pipeline import PipelineConfig, run_pipeline

        scene = out / "scene"
        if not (scene / "scene.json").is_file():
            typer.echo(f"[demo] generating the {preset} scene into {scene}", err=True)
            generate_scene(preset, scene, seed=seed, overwrite=True)
        project = out / "project"
        manifest = run_pipeline(
            scene, project, PipelineConfig(seed=seed), progress=lambda m: typer.echo(f"[demo] {m}", err=True)
        )
        typer.echo(f"project {project}:")
        _print_summary(manifest)
        typer.echo(f"report: {project / 'report' / 'report.html'}")
