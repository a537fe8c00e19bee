"""``hybridsplat measure``: triangulate picked points (PICKS.json) with a project's cameras; print and export.

The PICKS.json format is documented in :mod:`eval.measure.picks`: per point an id and a list of picks
``{"image": NAME, "u": X, "v": Y}`` in COLMAP pixel coordinates, optional ``sigma_px`` (global or per pick) and
optional ``distances`` between point ids.
"""

from __future__ import annotations

import sys
from pathlib import Path

import typer


def measure_command(
    picks: Path = typer.Argument(
        ...,
        help="PICKS.json: per point an id and picks {image, u, v} in COLMAP pixels (format: eval/measure/picks.py).",
    ),
    project: Path = typer.Option(
        ..., "--project", "-p", help="Project folder (cameras from sparse/, origin from export/merged.ply)."
    ),
    out: Path = typer.Option(
        None,
        "--out",
        help="Folder for measurements.csv, measurements_distances.csv, measurements.geojson (default: PROJECT/export).",
    ),
    crs: str = typer.Option(
        None, "--crs", help="CRS of the world coordinates (e.g. EPSG:32632) when the project records none."
    ),
    min_angle_deg: float = typer.Option(
        1.0, "--min-angle", help="Refuse points whose rays meet at less than this angle (degrees)."
    ),
    keep_going: bool = typer.Option(
        False, "--keep-going", help="Report degenerate points and go on instead of stopping."
    ),
) -> None:
    """Multi-ray intersection of picked points: world coordinates, σ, error ellipsoids and distances; CSV/GeoJSON."""
    from hybridsplat.project_lock import ProjectLock
    from hybridsplat.viewer.project import open_project

    open_project(project)  # a missing project is named before a lock is tried in it
    with ProjectLock(project, exclusive=out is None):  # writes into PROJECT/export unless --out says otherwise
        _measure(picks, project, out, crs, min_angle_deg, keep_going)


def _measure(picks: Path, project: Path, out: Path | None, crs: str | None, min_angle_deg: float,
             keep_going: bool) -> None:  # fmt: skip
    from dataclasses import replace

    from eval.measure import TriangulationOptions, write_csv, write_geojson
    from eval.measure.picks import read_picks
    from eval.measure.project import measure_picks, read_cameras, read_georeference
    from hybridsplat.viewer.project import cameras_origin, open_project

    layout = open_project(project)
    spec = read_picks(picks)
    from hybridsplat.project_io import sparse_model

    cameras = read_cameras(sparse_model(layout))
    georef = read_georeference(layout.merged_ply)
    georef = replace(georef, origin=cameras_origin(layout, georef.origin), crs=crs or georef.crs)
    failed: list[str] = []

    def report(pid: str, err: Exception) -> None:
        failed.append(pid)
        typer.echo(f"warning: {err}", err=True)

    result = measure_picks(
        spec,
        cameras,
        georef,
        TriangulationOptions(min_angle_deg=min_angle_deg),
        source=picks,
        on_error=report if keep_going else None,
    )
    typer.echo(format_table(result))
    out_dir = out or layout.measurements_csv.parent
    csv_path = out_dir / layout.measurements_csv.name
    dist_path = out_dir / layout.measurement_distances_csv.name
    write_csv(csv_path, result, dist_path if result.distances else None)
    typer.echo(f"wrote {csv_path}" + (f" and {dist_path}" if result.distances else ""))
    if result.crs:
        geo_path = out_dir / layout.measurements_geojson.name
        write_geojson(geo_path, result)
        typer.echo(f"wrote {geo_path} (WGS84, from {result.crs})")
    else:
        typer.echo("no CRS known (project sidecar or --crs): GeoJSON not written")
    if failed:
        typer.echo(f"{len(failed)} point(s) not measured: {', '.join(failed)}", err=True)
        sys.exit(1)  # typer.Exit's code is lost in the CLI's non-standalone mode


def format_table(result) -> str:  # result: eval.measure.Measurements
    """A fixed-width text table of points (world coordinates, σ) and distances."""
    unit = result.unit
    lines = [
        f"{'point':<12} {'x':>16} {'y':>16} {'z':>12} {'σx':>9} {'σy':>9} {'σz':>9} {'rays':>4} {'angle°':>7} {'σ0':>6}"
    ]
    for p in result.points:
        x, y, z = p.world
        sx, sy, sz = p.sigma
        lines.append(
            f"{p.name:<12} {x:16.4f} {y:16.4f} {z:12.4f} {sx:9.5f} {sy:9.5f} {sz:9.5f} {p.n_rays:4d} "
            f"{p.max_angle_deg:7.2f} {p.sigma0:6.2f}"
        )
    lines.append(f"(world coordinates and σ in {unit}; CRS: {result.crs or 'unknown'})")
    for d in result.distances:
        lines.append(f"distance {d.a} – {d.b}: {d.length:.5f} ± {d.sigma:.5f} {unit}")
    return "\n".join(lines)


def register(app: typer.Typer) -> None:
    """Add ``measure`` to the CLI."""
    app.command("measure", help=measure_command.__doc__)(measure_command)
