"""``hybridsplat eval c2c``, ``eval images`` and ``eval render``: measure clouds and renders against references;
``eval project``: score a project's products again (its eval and report stages)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer
from rich.console import Console
from rich.table import Table

from core.errors import ConfigError
from core.io import read_point_cloud, write_point_cloud
from core.io.atomic import check_output_dir, check_output_file, output_transaction, write_text_atomic
from core.io.json_io import write_json_atomic

if TYPE_CHECKING:
    from eval.metrics_io import ImageEval

eval_app = typer.Typer(
    help="Measure products against ground truth: cloud-to-cloud/mesh distances and image metrics.",
    no_args_is_help=True,
)


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.6f}" if abs(v) < 1e4 else f"{v:.1f}"
    return str(v)


def _write_json(path: Path, payload: dict[str, Any]) -> None:
    write_json_atomic(path, payload)


def _check_outputs(json_path: Path | None, folder: Path | None) -> None:
    if json_path is not None:
        check_output_file(json_path)
    if folder is not None:
        check_output_dir(folder)


def _lpips_model(weights: dict[str, Any]) -> Any:
    """The torch LPIPS network from weights checked by :func:`eval.lpips.read_weights` (imports torch)."""
    from eval.lpips import LPIPS

    return LPIPS(weights)


def _print_image_table(result: ImageEval, title: str) -> None:
    from eval.image_metrics import IMAGE_METRIC_NAMES

    table = Table(title=title)
    table.add_column("view")
    for k in IMAGE_METRIC_NAMES:
        table.add_column(k, justify="right")
    for v in result.per_view:
        table.add_row(v.view, *(_fmt(getattr(v.full, k)) for k in IMAGE_METRIC_NAMES))
        if v.masked is not None:
            table.add_row("  masked", *(_fmt(getattr(v.masked, k)) for k in IMAGE_METRIC_NAMES))
    for label, summary in (("mean (full)", result.full), ("mean (masked)", result.masked)):
        if summary is not None:
            table.add_row(label, *(_fmt(getattr(summary.mean, k)) for k in IMAGE_METRIC_NAMES))
            table.add_row("  std", *(_fmt(getattr(summary.std, k)) for k in IMAGE_METRIC_NAMES))
    Console().print(table)


@eval_app.command("c2c")
def c2c(
    compared: Path = typer.Argument(..., help="Cloud to measure (.ply/.las/.laz/.e57)."),
    reference: Path = typer.Argument(
        ..., help="Reference cloud (.ply/.las/.laz/.e57) or mesh (.ply with faces/.obj/.stl/.off/.glb)."
    ),
    max_dist: float | None = typer.Option(
        None, "--max-dist", help="Points farther than this (m) are outliers: counted, excluded from the statistics."
    ),
    tau: float | None = typer.Option(
        None, "--tau", help="Threshold (m) for completeness, precision, recall and F-score (Tanks and Temples)."
    ),
    json_path: Path | None = typer.Option(None, "--json", help="Write the statistics as JSON here."),
    out: Path | None = typer.Option(
        None, "--out", help="Write the compared cloud with a 'c2c' field (m) here (.ply/.las/.laz)."
    ),
    plots: Path | None = typer.Option(
        None, "--plots", help="Write a histogram (SVG) and a colour-mapped preview (PNG) into this folder."
    ),
    icp: float | None = typer.Option(
        None,
        "--icp",
        help="Register first with point-to-plane ICP using this correspondence distance (m); off by default.",
    ),
) -> None:
    """Cloud-to-cloud distances (CloudCompare's C2C), or cloud-to-mesh when the reference is a mesh.

    For each compared point, the distance to the nearest reference point; prints count, mean, std, median,
    RMSE, P90/P95/P99 and max, per-class statistics for classified clouds, and with --tau completeness,
    precision, recall and F-score."""
    from eval.geometry import GeometryOptions, load_reference, measure
    from eval.metrics_io import C2CSummary

    if tau is not None and tau <= 0:
        raise ConfigError(f"--tau must be a positive distance in metres, got {tau}")
    options = GeometryOptions(max_dist=max_dist, tau=tau, icp_max_correspondence=icp)
    for path in (json_path, out):
        if path is not None:
            check_output_file(path)
    if plots is not None:
        check_output_dir(plots)
    cloud = read_point_cloud(compared)
    ref = load_reference(reference)
    m = measure(cloud, ref, options)
    result, measured, registration, method = m.result, m.measured, m.registration, m.method
    summary = C2CSummary.from_result(result, method, str(reference), registration)
    s = result.stats

    table = Table(title=f"{method.upper()}: {compared.name} → {reference.name} (metres)")
    table.add_column("statistic")
    table.add_column("value", justify="right")
    rows: list[tuple[str, Any]] = [
        (k, getattr(s, k)) for k in ("count", "mean", "std", "median", "rmse", "p90", "p95", "p99", "max")
    ]
    if max_dist is not None:
        rows += [("outliers (> max dist)", s.outlier_count), ("outlier share", s.outlier_share)]
    if result.scores is not None:
        sc = result.scores
        rows += [
            ("tau", sc.tau),
            ("precision", sc.precision),
            ("recall / completeness", sc.recall),
            ("F-score", sc.fscore),
        ]
        if result.reverse is not None:
            rows += [("reference→compared mean", result.reverse.mean)]
    if registration is not None:
        rows += [("ICP fitness", registration["fitness"]), ("ICP inlier RMSE", registration["inlier_rmse"])]
    for name, value in rows:
        table.add_row(name, _fmt(value))
    Console().print(table)
    if result.per_class:
        pc = Table(title="per class")
        for col in ("class", "count", "mean", "std", "rmse", "p95", "max"):
            pc.add_column(col, justify="right")
        for k, st in sorted(result.per_class.items()):
            pc.add_row(str(k), *(_fmt(getattr(st, c)) for c in ("count", "mean", "std", "rmse", "p95", "max")))
        Console().print(pc)

    with output_transaction():  # the cloud, plots and JSON appear together or not at all
        _write_c2c_outputs(compared, method, measured, result, summary, out, plots, json_path, max_dist)


def _write_c2c_outputs(  # noqa: PLR0913 - the outputs of one c2c run
    compared: Path,
    method: str,
    measured: Any,
    result: Any,
    summary: Any,
    out: Path | None,
    plots: Path | None,
    json_path: Path | None,
    max_dist: float | None,
) -> None:
    from core.io.images import write_image
    from eval.geometry import with_distance_field
    from eval.plots import preview_image, svg_histogram

    s = result.stats
    files: dict[str, str] = {}
    if out is not None:
        write_point_cloud(out, with_distance_field(measured, result.distances))
        files["cloud"] = str(out)
    if plots is not None:
        hist = plots / f"{compared.stem}_c2c_hist.svg"
        prev = plots / f"{compared.stem}_c2c_preview.png"
        write_text_atomic(
            hist,
            svg_histogram(
                summary.histogram_edges, summary.histogram_counts, f"{method.upper()} distances: {compared.name}"
            ),
        )
        vmax = max_dist if max_dist is not None else max(s.p95, 1e-9)
        write_image(prev, preview_image(measured.positions, result.distances, vmax=vmax))
        files.update(histogram=str(hist), preview=str(prev))
    if json_path is not None:
        payload = summary.as_dict()
        payload["files"] = files
        payload["compared"] = str(compared)
        _write_json(json_path, payload)


@eval_app.command("images")
def images(
    renders: Path = typer.Argument(..., help="Folder of rendered images."),
    photos: Path = typer.Argument(..., help="Folder of photos; matched to renders by file name (stem)."),
    masks: Path | None = typer.Option(
        None, "--masks", help="Folder of PNG masks (non-zero = non-collaborative region), matched by stem."
    ),
    lpips_weights: Path | None = typer.Option(
        None,
        "--lpips-weights",
        help="LPIPS v0.1 AlexNet weights (.npz); default: $HYBRIDSPLAT_LPIPS_WEIGHTS or the shared data folder.",
    ),
    no_lpips: bool = typer.Option(False, "--no-lpips", help="Skip LPIPS (no weights needed)."),
    json_path: Path | None = typer.Option(None, "--json", help="Write per-view and aggregated metrics as JSON here."),
    panels: Path | None = typer.Option(
        None, "--panels", help="Write side-by-side panels (render, photo, error) into this folder."
    ),
) -> None:
    """Image metrics of renders against photos: MSE, PSNR, SSIM, MS-SSIM, LPIPS, ΔE.

    Every metric on the whole image and inside the mask (when a mask exists), per view and as mean ± std.
    Colours are compared in [0, 1]; ΔE is the mean CIEDE2000 difference."""
    from eval.lpips import find_weights, read_weights
    from eval.render_eval import evaluate_pairs, folder_pairs

    _check_outputs(json_path, panels)
    # every input is read and checked (weights, then images and masks) before torch is loaded for LPIPS
    weights = None if no_lpips else read_weights(find_weights(lpips_weights))
    pairs = folder_pairs(renders, photos, masks)
    model = None if weights is None else _lpips_model(weights)
    with output_transaction():  # panels and JSON appear together or not at all
        result = evaluate_pairs(pairs, model, panels, name=renders.name or "images")
        if json_path is not None:
            _write_json(json_path, result.as_dict())
    _print_image_table(result, f"{renders} vs {photos}")


@eval_app.command("render")
def render(
    gaussians: Path = typer.Argument(..., help="3DGS PLY to evaluate (e.g. export/merged.ply)."),
    model: Path = typer.Argument(..., help="COLMAP model folder with the held-out cameras (undistorted, pinhole)."),
    photos: Path = typer.Argument(..., help="Folder of the held-out photos, named as the model's images."),
    views: str | None = typer.Option(
        None, "--views", help="Comma-separated image names to use (default: every image of the model found in PHOTOS)."
    ),
    masks: Path | None = typer.Option(
        None, "--masks", help="Folder of PNG masks (non-zero = non-collaborative region), named <image stem>.png."
    ),
    lpips_weights: Path | None = typer.Option(
        None,
        "--lpips-weights",
        help="LPIPS v0.1 AlexNet weights (.npz); default: $HYBRIDSPLAT_LPIPS_WEIGHTS or the shared data folder.",
    ),
    no_lpips: bool = typer.Option(False, "--no-lpips", help="Skip LPIPS (no weights needed)."),
    json_path: Path | None = typer.Option(None, "--json", help="Write per-view and aggregated metrics as JSON here."),
    panels: Path | None = typer.Option(
        None, "--panels", help="Write side-by-side panels (render, photo, error) into this folder."
    ),
) -> None:
    """Render a Gaussian set at held-out cameras and score the renders against the photos.

    Same metrics as `eval images` (whole image and masked, per view, mean ± std)."""
    from core.io.colmap import read_model
    from core.io.gaussian_ply import read_gaussian_ply
    from eval.lpips import find_weights, read_weights
    from eval.render_eval import evaluate_gaussians

    _check_outputs(json_path, panels)
    gs = read_gaussian_ply(gaussians)
    cameras, _ = read_model(model)
    if views:
        wanted = [v.strip() for v in views.split(",") if v.strip()]
        chosen = [cameras.by_name(name) for name in wanted]
    else:
        chosen = [v for v in cameras if (photos / v.name).is_file()]
    if not chosen:
        raise ConfigError(f"no image of the model {model} has a photo in {photos}", photos)
    weights = None if no_lpips else read_weights(find_weights(lpips_weights))
    lpips_model = None if weights is None else _lpips_model(weights)  # torch from here on
    with output_transaction():  # panels and JSON appear together or not at all
        result = evaluate_gaussians(gs, cameras, chosen, photos, masks, lpips_model, panels, name=gaussians.stem)
        if json_path is not None:
            _write_json(json_path, result.as_dict())
    _print_image_table(result, f"{gaussians.name} at {len(chosen)} held-out views")


@eval_app.command("project")
def eval_project(
    project: Path = typer.Argument(..., help="Project folder (after 'hybridsplat run')."),
    force: bool = typer.Option(False, "--force", help="Measure again even when up to date."),
) -> None:
    """Score a project's products again with the options in PROJECT/config.toml: the eval stage, then the report
    (after 'hybridsplat mesh PROJECT --source survey', say; 'run' would rebuild config.toml from its own options)."""
    from hybridsplat.commands.common import run_project_stage

    run_project_stage(project, "eval", {}, force)
    run_project_stage(project, "report", {})


def register(app: typer.Typer) -> None:
    app.add_typer(eval_app, name="eval")
