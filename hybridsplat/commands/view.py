"""``hybridsplat view``: a local web viewer of a project's merged result with multi-ray measurement."""

from __future__ import annotations

import time
from pathlib import Path

import typer


def view_command(
    target: Path = typer.Argument(..., help="A project folder, or a 3DGS PLY (splats only, no measurement)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on (default: this machine only)."),
    port: int = typer.Option(8080, "--port", min=0, max=65535, help="Port of the web page (0: any free port)."),
    test_cameras: Path = typer.Option(
        None, "--test-cameras", help="COLMAP model of held-out cameras to draw too (e.g. SCENE/sparse/test)."
    ),
    max_splats: int = typer.Option(2_000_000, "--max-splats", min=1, help="Show at most this many Gaussians."),
    max_points: int = typer.Option(1_000_000, "--max-points", min=1, help="Show at most this many MVS points."),
    sigma_px: float = typer.Option(1.0, "--sigma-px", min=0.01, help="Default σ of a pick in pixels."),
    seconds: float = typer.Option(0.0, "--seconds", min=0.0, help="Stop after this many seconds (0: until Ctrl-C)."),
    layers: str | None = typer.Option(
        None, "--layers", help="Layers of a merged product to keep, comma-separated: survey | fill | background."
    ),
) -> None:
    """Open the merged splats, MVS cloud, mesh and cameras in the browser; pick points, see error ellipsoids."""
    from dataclasses import replace

    from eval.measure.project import read_cameras
    from fusion.convert_options import parse_layers
    from hybridsplat.project_lock import reading_project
    from hybridsplat.viewer.app import ViewerApp, ViewerOptions
    from hybridsplat.viewer.project import open_project
    from hybridsplat.viewer.scene import load_ply_alone, load_project

    chosen = parse_layers(layers) if layers is not None else None
    with reading_project(target):  # the viewer shows what it read: the lock is held while it reads
        if target.is_dir():
            scene = load_project(target, max_splats=max_splats, max_points=max_points, layers=chosen)
            files = open_project(target)
        else:
            scene = load_ply_alone(target, max_splats=max_splats, layers=chosen)
            files = None
    if test_cameras is not None:
        scene = replace(scene, test_cameras=read_cameras(test_cameras))
    app = ViewerApp(scene, ViewerOptions(host=host, port=port, pick_sigma_px=sigma_px), files)
    layers = ", ".join(app.layers) or "no layers"
    typer.echo(f"hybridsplat view: http://{host}:{app.port}/  ({layers}; {len(scene.cameras)} cameras)")
    typer.echo("press Ctrl-C to stop", err=True)
    start = time.monotonic()
    try:
        while seconds == 0 or time.monotonic() - start < seconds:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()


def register(app: typer.Typer) -> None:
    """Add ``view`` to the CLI."""
    app.command("view", help=view_command.__doc__)(view_command)
