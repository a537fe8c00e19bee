"""``hybridsplat merge --splats S.ply --mvs M.ply --out merged.ply``: one Gaussian set from splats and MVS."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import typer

from core.gaussians import GaussianSet
from core.io.atomic import check_output_file, output_transaction
from core.io.gaussian_ply import read_gaussian_ply
from core.io.ply import scan_ply_header
from fusion.convert_options import ConversionWarning, ConvertMode
from fusion.export import export_gaussians, export_points
from fusion.merge import MergeOptions, Prefer, merge_gaussians
from hybridsplat.commands.convert import export_options, load_cloud, print_export


def is_gaussian_ply(path: Path) -> bool:
    """True when ``path`` is a PLY whose vertices carry 3DGS properties (``f_dc_0``, ``opacity``)."""
    if path.suffix.lower() != ".ply":
        return False
    vertex = scan_ply_header(path).element("vertex")
    names = {name for name, _, _ in vertex.properties} if vertex is not None else set()
    return "f_dc_0" in names and "opacity" in names


def load_gaussians(path: Path, mode: ConvertMode) -> GaussianSet:
    """A 3DGS PLY as it is, or any point cloud converted with ``mode`` (warnings printed to stderr)."""
    if is_gaussian_ply(path):
        return read_gaussian_ply(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConversionWarning)
        cloud = load_cloud(path)
        from fusion.convert import convert_points  # numba and scipy: once the input has been read and checked

        gs = convert_points(cloud, mode).gaussians
    for w in caught:
        print(f"hybridsplat: warning: {path}: {w.message}", file=sys.stderr)
    return gs


def merge(
    out: Path = typer.Option(..., "--out", "-o", help="Merged output: .ply (3DGS PLY), .splat, or .las/.laz."),
    splats: Path | None = typer.Option(None, help="Trained splats (3DGS PLY)."),
    mvs: Path | None = typer.Option(None, help="MVS Gaussians (3DGS PLY) or an MVS point cloud to convert."),
    mode: ConvertMode = typer.Option(ConvertMode.ADAPTIVE, help="Conversion mode when --mvs is a point cloud."),
    drop_class: list[int] = typer.Option([], "--drop-class", help="Non-collaborative class code (repeatable)."),
    tolerance: float = typer.Option(1e-3, help="Duplicate tolerance in metres."),
    prefer: Prefer = typer.Option(Prefer.MVS, help="Source kept when an MVS Gaussian and a splat coincide."),
    points_out: list[Path] = typer.Option(
        [], "--points-out", help="Also write centres with class and source fields (.ply, .las, .laz; repeatable)."
    ),
    crop_min: tuple[float, float, float] | None = typer.Option(None, help="Crop box minimum X Y Z (world, metres)."),
    crop_max: tuple[float, float, float] | None = typer.Option(None, help="Crop box maximum X Y Z (world, metres)."),
    min_opacity: float = typer.Option(1 / 255, help="Drop Gaussians with opacity below this (0 keeps all)."),
    sh_degree: int | None = typer.Option(None, help="SH degree written to the 3DGS PLY (default: highest input)."),
    extra_fields: bool = typer.Option(False, help="Append source/classification fields to the 3DGS PLY."),
) -> None:
    """Merge trained splats with MVS Gaussians: drop non-collaborative MVS classes, resolve duplicates, export."""
    exp = export_options(crop_min, crop_max, min_opacity, sh_degree, extra_fields)
    options = MergeOptions(non_collaborative_classes=tuple(drop_class), duplicate_tolerance=tolerance, prefer=prefer)
    for path in (out, *points_out):
        check_output_file(path)
    splat_set = read_gaussian_ply(splats) if splats is not None else None
    mvs_set = load_gaussians(mvs, mode) if mvs is not None else None
    if splat_set is None and mvs_set is None:
        raise typer.BadParameter("give --splats, --mvs or both")
    result = merge_gaussians(splat_set, mvs_set, options)
    s = result.stats
    typer.echo(
        f"merged {s.mvs_kept} MVS + {s.splats_kept} splat Gaussians (dropped {s.dropped_non_collaborative} "
        f"non-collaborative, {s.dropped_mvs_duplicates} MVS duplicates, {s.dropped_cross_duplicates} cross duplicates)"
    )
    with output_transaction():  # every output (and sidecar) appears, or none does
        reports = [export_gaussians(out, result.gaussians, exp)]
        reports += [export_points(path, result.gaussians, exp) for path in points_out]
    for report in reports:
        print_export(report)


def register(app: typer.Typer) -> None:
    app.command("merge")(merge)
