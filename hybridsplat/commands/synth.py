"""``hybridsplat synth --preset tabletop --seed 0 --out DIR``: generate a synthetic scene with exact ground truth."""

from __future__ import annotations

import time
from pathlib import Path

import typer


def synth(
    out: Path = typer.Option(..., "--out", "-o", help="Folder to create (must not exist or be empty)."),
    preset: str = typer.Option(
        "tiny",
        "--preset",
        "-p",
        help="Scene preset: tiny | tabletop | demo | textured | aerial (fixed layouts) | random-object | random-aerial "
        "(layouts drawn from the seed; seeds 100-199 are for scoring, 0-99 for tuning).",
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of every random choice (same seed, same bytes)."),
    views: int | None = typer.Option(None, "--views", min=1, help="Training views (default: the preset's)."),
    test_views: int | None = typer.Option(None, "--test-views", min=0, help="Held-out test views."),
    width: int | None = typer.Option(None, "--width", min=8, help="Image width in pixels."),
    height: int | None = typer.Option(None, "--height", min=8, help="Image height in pixels."),
    supersample: int | None = typer.Option(None, "--supersample", min=1, help="S for S×S samples per pixel."),
    max_depth: int | None = typer.Option(None, "--max-depth", min=0, help="Reflection/refraction bounces."),
    noise: float | None = typer.Option(None, "--lidar-noise", min=0.0, help="LiDAR range sigma in metres (0 = off)."),
    targets: int | None = typer.Option(
        None,
        "--targets",
        min=0,
        help="Coded survey targets (ArUco) to lay on the ground, half control, half check (default: the preset's: "
        "aerial and random-aerial 12, demo and tabletop 8, others 0).",
    ),
    georef: bool = typer.Option(False, "--georef", help="Put the scene at a UTM-like origin (500000, 5000000, 300)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing non-empty output folder."),
) -> None:
    """Ray-trace a synthetic survey scene: photos, held-out photos, true COLMAP cameras, GT mesh with materials,
    simulated LiDAR (PLY + LAS), depth and label maps, and scene.json with the materials legend."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from data_synth import generate_scene

    start = time.perf_counter()
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=Console(stderr=True),
    ) as bar:
        tasks: dict[str, int] = {}

        def progress(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done, total=total)

        path = generate_scene(
            preset,
            out,
            seed=seed,
            progress=progress,
            overwrite=overwrite,
            views=views,
            test_views=test_views,
            width=width,
            height=height,
            supersample=supersample,
            max_depth=max_depth,
            noise=noise,
            georef=georef or None,
            targets=targets,
        )
    typer.echo(f"wrote {path} (preset {preset}, seed {seed}) in {time.perf_counter() - start:.1f} s")


def register(app: typer.Typer) -> None:
    """Add the ``synth`` command."""
    app.command("synth")(synth)
