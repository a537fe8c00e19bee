"""``hybridsplat convert CLOUD --mode paper|adaptive --out FILE``: MVS point cloud → Gaussians, written for viewers."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import typer

from core.io import read_point_cloud
from core.io.atomic import check_output_file, output_transaction
from core.io.colmap_vis import read_vis
from core.pointcloud import PointCloud
from fusion.convert_options import DEFAULT_MODE, ConversionWarning, ConvertMode, ConvertOptions
from fusion.export import ExportOptions, ExportReport, export_gaussians
from fusion.spz_format import SPZ_VERSION


def load_cloud(path: Path, visibility: Path | None = None) -> PointCloud:
    """A point cloud plus, when present, its ``<cloud>.vis`` visibility (or the file given)."""
    cloud = read_point_cloud(path)
    vis = visibility or path.with_name(path.name + ".vis")
    if visibility is not None or vis.is_file():
        cloud.visibility = read_vis(vis, len(cloud))
    return cloud


def export_options(
    crop_min: tuple[float, float, float] | None,
    crop_max: tuple[float, float, float] | None,
    min_opacity: float,
    sh_degree: int | None,
    extra_fields: bool,
    crs: str | None = None,
    spz_version: int = SPZ_VERSION,
) -> ExportOptions:
    return ExportOptions(
        crop_min=crop_min,
        crop_max=crop_max,
        min_opacity=min_opacity,
        sh_degree=sh_degree,
        extra_fields=extra_fields,
        crs=crs,
        spz_version=spz_version,
    )


def print_export(report: ExportReport) -> None:
    typer.echo(
        f"wrote {report.path} ({report.format}): {report.num_written} Gaussians of {report.num_input} "
        f"(cropped {report.dropped_crop}, below opacity {report.dropped_opacity}), SH degree {report.sh_degree}, "
        f"origin {list(report.origin)}"
    )
    for line in report.notes:
        typer.echo(f"  {line}")


def convert(
    cloud: Path = typer.Argument(..., help="MVS point cloud (.ply, .las, .laz, .e57); a CLOUD.vis next to it is used."),
    out: Path = typer.Option(..., "--out", "-o", help="Output: .ply (3DGS PLY), .splat, or .las/.laz (points)."),
    mode: ConvertMode = typer.Option(
        DEFAULT_MODE, "--mode", help="adaptive (default): surfels; paper: Eq. 1-4 exactly."
    ),
    visibility: Path | None = typer.Option(None, help="COLMAP fused.ply.vis file (default: CLOUD.vis if present)."),
    k: int = typer.Option(8, "--k", help="adaptive: neighbours for the per-point spacing."),
    tangent_scale: float = typer.Option(0.4, help="adaptive: in-surface sigma as a multiple of the spacing."),
    thickness_ratio: float = typer.Option(0.1, help="adaptive: normal sigma as a multiple of the in-surface sigma."),
    opacity_logit_min: float = typer.Option(-5.0, help="Lower clamp of the stored opacity (logit)."),
    opacity_logit_max: float = typer.Option(10.0, help="Upper clamp of the stored opacity (logit)."),
    crop_min: tuple[float, float, float] | None = typer.Option(None, help="Crop box minimum X Y Z (world, metres)."),
    crop_max: tuple[float, float, float] | None = typer.Option(None, help="Crop box maximum X Y Z (world, metres)."),
    min_opacity: float = typer.Option(1 / 255, help="Drop Gaussians with opacity below this (0 keeps all)."),
    sh_degree: int | None = typer.Option(None, help="SH degree written to the 3DGS PLY (default: 0)."),
    extra_fields: bool = typer.Option(False, help="Append source/classification fields to the 3DGS PLY."),
) -> None:
    """Convert an MVS point cloud to Gaussians (paper or adaptive mode) and write a viewer-ready file."""
    options = ConvertOptions(
        k_neighbors=k,
        tangent_scale=tangent_scale,
        thickness_ratio=thickness_ratio,
        opacity_logit_min=opacity_logit_min,
        opacity_logit_max=opacity_logit_max,
    )
    exp = export_options(crop_min, crop_max, min_opacity, sh_degree, extra_fields)
    check_output_file(out)
    points = load_cloud(cloud, visibility)
    from fusion.convert import convert_points  # numba and scipy: once the input has been read and checked

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConversionWarning)
        result = convert_points(points, mode, options)
    for w in caught:
        print(f"hybridsplat: warning: {w.message}", file=sys.stderr)
    s = result.stats
    typer.echo(
        f"converted {s.num_points} points ({mode.value}): mean NN spacing {s.mean_nn_spacing:.6g} m, "
        f"median spacing used {s.median_spacing:.6g} m, {s.seconds_total:.2f} s"
    )
    with output_transaction():  # the file and its origin sidecar appear together or not at all
        report = export_gaussians(out, result.gaussians, exp)
    print_export(report)


def register(app: typer.Typer) -> None:
    app.command("convert")(convert)
