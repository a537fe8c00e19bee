"""``hybridsplat info PATH``: summary of a point cloud, a 3DGS PLY or a COLMAP sparse model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from core.io import read_point_cloud
from core.io.gaussian_ply import read_gaussian_ply
from core.io.ply import scan_ply_header


def _is_gaussian_ply(path: Path) -> bool:
    vertex = scan_ply_header(path).element("vertex")
    return vertex is not None and any(name == "f_dc_0" for name, _, _ in vertex.properties)


def info(
    path: Path = typer.Argument(..., help="A .ply/.las/.laz/.e57 cloud, a 3DGS .ply or a COLMAP model folder."),
) -> None:
    """Print what a file holds: point count, origin, bounds, fields; Gaussians' SH degree; cameras and images."""
    from hybridsplat.project_lock import reading_project

    with reading_project(path):  # a file of a project that another command writes now is refused, not half-read
        _info(path)


def _info(path: Path) -> None:
    if path.is_dir():
        from core.io.colmap import read_model  # pycolmap

        cameras, points = read_model(path)
        typer.echo(f"COLMAP model {path}: {len(cameras.cameras)} cameras, {len(cameras)} images, {len(points)} points")
        for cam in cameras.cameras.values():
            params = np.round(cam.params, 4).tolist()
            typer.echo(f"  camera {cam.camera_id}: {cam.model.value} {cam.width}x{cam.height} {params}")
        return
    if path.suffix.lower() == ".ply" and _is_gaussian_ply(path):
        gs = read_gaussian_ply(path)
        world = gs.world_means
        typer.echo(f"3DGS PLY {path}: {len(gs)} Gaussians, SH degree {gs.sh_degree}, origin {gs.origin.tolist()}")
        if len(gs):
            typer.echo(f"  bounds min {world.min(0).tolist()} max {world.max(0).tolist()}")
        return
    cloud = read_point_cloud(path)
    typer.echo(f"point cloud {path}: {len(cloud)} points, origin {cloud.origin.tolist()}")
    if len(cloud):
        world = cloud.world_positions
        typer.echo(f"  bounds min {world.min(0).round(4).tolist()} max {world.max(0).round(4).tolist()}")
    typer.echo(f"  colours: {cloud.colors is not None}, normals: {cloud.normals is not None}")
    for name, values in cloud.fields.items():
        span = f"{values.min()}..{values.max()}" if len(values) else "empty"
        typer.echo(f"  field {name}: {values.dtype}, range {span}")


def register(app: typer.Typer) -> None:
    app.command("info")(info)
