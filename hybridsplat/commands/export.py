"""``hybridsplat export GAUSSIANS.ply --out FILE``: re-export a 3DGS PLY for viewers or survey tools, filtered."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import typer

from core.errors import ConfigError
from core.io.atomic import check_output_file, output_transaction
from core.io.gaussian_ply import read_gaussian_ply
from fusion.convert_options import parse_layers, select_layers
from fusion.export import export_gaussians, export_points, export_tileset, is_compressed_ply_path, is_tileset_path
from fusion.sog_format import is_sog_path
from fusion.spz_format import SPZ_VERSION
from hybridsplat.commands.convert import export_options, print_export


def export(
    gaussians: Path = typer.Argument(..., help="A 3DGS PLY (with its .origin.json sidecar when georeferenced)."),
    out: list[Path] = typer.Option(
        ...,
        "--out",
        "-o",
        help="Output(s): .ply (3DGS PLY), .compressed.ply (PlayCanvas), .spz (SPZ v2), .sog or meta.json "
        "(PlayCanvas SOG, bundled or unbundled), .splat, tileset.json "
        "(3D Tiles of glTF KHR_gaussian_splatting, placed on the earth by the input's CRS), or .las/.laz (centres); "
        "repeatable.",
    ),
    points: bool = typer.Option(
        False, help="Write .ply outputs (not .compressed.ply) as point clouds (class/source fields) instead."
    ),
    crop_min: tuple[float, float, float] | None = typer.Option(None, help="Crop box minimum X Y Z (world, metres)."),
    crop_max: tuple[float, float, float] | None = typer.Option(None, help="Crop box maximum X Y Z (world, metres)."),
    min_opacity: float = typer.Option(1 / 255, help="Drop Gaussians with opacity below this (0 keeps all)."),
    sh_degree: int | None = typer.Option(
        None, help="SH degree written to .ply, .compressed.ply, .spz and .sog outputs (default: as read)."
    ),
    extra_fields: bool = typer.Option(False, help="Append per-Gaussian fields to 3DGS PLY outputs."),
    spz_version: int = typer.Option(
        SPZ_VERSION, help="SPZ version of .spz outputs: 2 (every reader) | 3 (rotations exact near 180°)."
    ),
    gltf_compression: str = typer.Option(
        "spz",
        "--gltf-compression",
        help="glTF tiles of a tileset.json output: spz (KHR_gaussian_splatting_compression_spz_2, SPZ v2: what "
        "CesiumJS draws as splats) | none (float32 KHR_gaussian_splatting attributes; CesiumJS shows points).",
    ),
    layers: str | None = typer.Option(
        None, "--layers", help="Layers of a merged product to keep, comma-separated: survey | fill | background."
    ),
    survey_points: Path | None = typer.Option(
        None,
        "--survey-points",
        help="tileset.json outputs only: add these survey points (e.g. export/merged_points.ply, with its origin "
        "sidecar) as a 3D Tiles point-cloud layer (survey_points/).",
    ),
    mesh: Path | None = typer.Option(
        None,
        "--mesh",
        help="tileset.json outputs only: add this mesh (a .glb such as export/mesh.glb, with its origin sidecar) as "
        "one tile (mesh/mesh.glb).",
    ),
    memory_limit: float | None = typer.Option(
        None,
        "--memory-limit",
        help="Point-cloud outputs (.las, .laz, .ply with --points): write them in chunks within about this memory "
        "(MB), the same bytes (fusion/export_stream.py).",
    ),
) -> None:
    """Export Gaussians to viewer formats (.ply, .compressed.ply, .spz, .sog, .splat, tileset.json) or point clouds
    with class/source fields (.ply, .las). A tileset.json output can carry the survey points and the mesh beside the
    splats (--survey-points, --mesh)."""
    _refuse_layers_without_tileset(out, survey_points, mesh)
    for path in out:
        check_output_file(path)
    from core.io.origin import read_crs
    from hybridsplat.project_lock import reading_project

    chosen = parse_layers(layers) if layers is not None else None
    with reading_project(gaussians):
        gs = select_layers(read_gaussian_ply(gaussians), chosen)
        crs = read_crs(gaussians)  # the input's CRS goes with every output
    options = export_options(crop_min, crop_max, min_opacity, sh_degree, extra_fields, crs, spz_version)
    options = replace(options, gltf_compression=gltf_compression.lower())
    chunk = _chunk(memory_limit)
    with output_transaction():  # every output (and sidecar) appears, or none does
        reports = [_export_one(path, gs, options, points, chunk, survey_points, mesh) for path in out]
    for report in reports:
        print_export(report)


def _chunk(memory_limit_mb: float | None) -> int | None:
    """Points a chunk of the point-cloud outputs for ``--memory-limit`` (MB), None without one."""
    from fusion.export_stream import export_chunk_points

    return export_chunk_points(memory_limit_mb) if memory_limit_mb is not None else None


def _export_one(path: Path, gs, options, points: bool, chunk: int | None, survey_points: Path | None,
                mesh: Path | None):  # noqa: ANN001, ANN202  # fmt: skip
    """One output of the command: survey points (.las/.laz, or .ply with ``points``; ``chunk`` points at a time when
    given), a tileset, or a viewer format; its :class:`fusion.export.ExportReport`."""
    suffix = path.suffix.lower()
    if suffix in (".las", ".laz") or (points and suffix == ".ply" and not is_compressed_ply_path(path)):
        return export_points(path, gs, options, chunk=chunk)
    if _is_tileset(path):
        return export_tileset(path, gs, options, points=survey_points, mesh=mesh)
    return export_gaussians(path, gs, options)


def _is_tileset(path: Path) -> bool:
    """A 3D Tiles output as :func:`fusion.export.export_gaussians` reads it: ``*.json``, not SOG's ``meta.json``."""
    return is_tileset_path(path) and not is_sog_path(path)


def _refuse_layers_without_tileset(out: list[Path], survey_points: Path | None, mesh: Path | None) -> None:
    """--survey-points and --mesh only go into 3D Tiles: refuse them for any other output, in one line."""
    given = [flag for flag, value in (("--survey-points", survey_points), ("--mesh", mesh)) if value is not None]
    others = [str(p) for p in out if not _is_tileset(p)]
    if given and others:
        raise ConfigError(
            f"{' and '.join(given)} {'apply' if len(given) > 1 else 'applies'} to a tileset.json output only, "
            f"not to {', '.join(others)}: "
            "export those in a separate command"
        )


def register(app: typer.Typer) -> None:
    app.command("export")(export)
