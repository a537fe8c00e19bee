"""``hybridsplat render``: preview a Gaussian PLY from the survey's own COLMAP viewpoints."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import typer

from core.errors import ConfigError, DataError


def _load_gaussians(path: Path):  # -> GaussianSet
    from core.io.gaussian_ply import read_gaussian_ply

    return read_gaussian_ply(path)


def _load_cameras(path: Path):  # -> Cameras
    from core.io.colmap import read_model

    cameras, _points = read_model(path)
    return cameras


def _select_views(cameras, names: list[str] | None, model_dir: Path) -> list:
    views = list(cameras)
    if not names:
        return views
    by_name = {v.name: v for v in views}
    missing = [n for n in names if n not in by_name]
    if missing:
        raise DataError(f"images not in the model: {', '.join(missing[:5])} ({len(by_name)} images known)", model_dir)
    return [by_name[n] for n in names]


def _write_outputs(out_dir: Path, name: str, image, depth: bool, alpha: bool, depth_scale: float) -> int:
    from core.io.images import write_image

    stem = Path(name).with_suffix("").as_posix().replace("/", "__")
    write_image(out_dir / f"{stem}.png", image.colour)
    clipped = 0
    if depth:
        import cv2

        from core.io.atomic import atomic_path

        units = np.round(image.depth / depth_scale)
        clipped = int((units > 65535).sum())
        ok, encoded = cv2.imencode(".png", np.clip(units, 0, 65535).astype(np.uint16))
        if not ok:
            raise DataError("cannot encode the depth image as 16-bit PNG", out_dir / f"{stem}.depth.png")
        with atomic_path(out_dir / f"{stem}.depth.png") as tmp:
            tmp.write_bytes(encoded.tobytes())
    if alpha:
        write_image(out_dir / f"{stem}.alpha.png", image.alpha)
    return clipped


def render_command(
    gaussians: Path = typer.Argument(..., help="3DGS PLY to render (origin sidecar <name>.origin.json honoured)."),
    cameras: Path = typer.Option(..., "--cameras", help="COLMAP sparse model folder (cameras/images .bin or .txt)."),
    out: Path = typer.Option(..., "--out", help="Output folder for <image>.png (created if missing)."),
    images: list[str] = typer.Option(None, "--images", help="Render only these image names (repeatable)."),
    backend: str = typer.Option(
        "auto", "--backend", help="auto (gsplat on CUDA, else cpu) | cpu | reference | gsplat (needs CUDA)."
    ),
    depth: bool = typer.Option(False, "--depth", help="Also write <image>.depth.png: 16-bit z-depth."),
    depth_scale: float = typer.Option(0.001, "--depth-scale", help="Metres per depth-PNG unit (0.001: millimetres)."),
    alpha: bool = typer.Option(False, "--alpha", help="Also write <image>.alpha.png: 8-bit accumulated opacity."),
    background: str = typer.Option("0,0,0", "--background", help="Background RGB in [0, 1], e.g. 1,1,1."),
    sh_degree: int = typer.Option(None, "--sh-degree", help="Evaluate SH up to this degree (default: all)."),
    ignore_distortion: bool = typer.Option(
        False, "--ignore-distortion", help="Render distorted cameras as their pinhole part instead of refusing."
    ),
    layers: str | None = typer.Option(
        None, "--layers", help="Layers of a merged product to keep, comma-separated: survey | fill | background."
    ),
) -> None:
    """Render a Gaussian PLY at the cameras of a COLMAP model and write PNGs (colour, optional depth/alpha)."""
    from rich.progress import Progress

    from core.io.atomic import check_output_dir, output_transaction

    try:
        bg = np.array([float(v) for v in background.split(",")], dtype=np.float32)
    except ValueError:
        bg = np.zeros(0)
    if bg.shape != (3,) or not ((bg >= 0) & (bg <= 1)).all():
        raise ConfigError(f"--background must be three numbers in [0, 1] like 1,1,1, got {background!r}")
    if depth_scale <= 0:
        raise ConfigError(f"--depth-scale must be positive, got {depth_scale}")
    check_output_dir(out)
    from fusion.convert_options import parse_layers, select_layers
    from hybridsplat.project_lock import reading_project

    chosen = parse_layers(layers) if layers is not None else None
    with reading_project(gaussians), reading_project(cameras):
        splats = select_layers(_load_gaussians(gaussians), chosen)  # inputs are checked before torch is imported
        model = _load_cameras(cameras)
    views = _select_views(model, images, cameras)
    from fusion.render import render_gaussian_set, resolve_backend

    chosen = resolve_backend(backend)
    clipped = 0
    # all renders appear together, or none (an error or Ctrl-C half-way leaves the folder as it was)
    with output_transaction(), Progress(transient=True) as progress, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        task = progress.add_task(f"rendering {len(views)} views ({chosen.value})", total=len(views))
        for view in views:
            result = render_gaussian_set(
                splats,
                model.camera_of(view),
                view,
                cameras_origin=model.origin,
                background=bg,
                sh_degree=sh_degree,
                backend=chosen,
                ignore_distortion=ignore_distortion,
            )
            clipped += _write_outputs(out, view.name, result.to_numpy(), depth, alpha, depth_scale)
            progress.advance(task)
    typer.echo(f"wrote {len(views)} renders of {len(splats)} Gaussians to {out}")
    if clipped:
        typer.echo(f"warning: {clipped} depth pixels exceeded 65535 × {depth_scale} m and were clipped", err=True)


def register(app: typer.Typer) -> None:
    """Add ``render`` to the CLI."""
    app.command("render", help=render_command.__doc__)(render_command)
