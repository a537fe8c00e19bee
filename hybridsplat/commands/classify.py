"""``hybridsplat classify train|predict|features``: the random forest of the dense cloud.

``predict PROJECT`` runs the ``classify`` stage (classify/points.ply). ``train`` fits a model from labelled
projects: data_synth truth (``--scene``), a labelled PLY/LAS (``--labels-file``, LAS classification codes or
the project's class codes) or 2D label masks (``--label-masks``). ``features`` lists every feature.
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

classify_app = typer.Typer(help="Train or apply the point classifier; list its features.", no_args_is_help=True)


@classify_app.command("train")
def train_cmd(
    projects: list[Path] = typer.Argument(..., help="Project folders (dense/fused.ply + .vis) to learn from."),
    out: Path = typer.Option(..., "--out", "-o", help="Model file to write (.skops)."),
    scene: list[Path] = typer.Option([], help="data_synth scene of each project (truth labels), in order."),
    labels_file: Path | None = typer.Option(None, help="Labelled PLY/LAS (CloudCompare export) for one project."),
    field: str = typer.Option("classification", help="Scalar field of --labels-file holding the labels."),
    las_codes: bool = typer.Option(True, help="Read --labels-file values as LAS codes (else as class codes)."),
    label_masks: Path | None = typer.Option(None, help="Folder of 2D label images NAME.png (class codes, 255 none)."),
    classes: Path | None = typer.Option(None, help="Class definitions TOML (default: the shipped classes)."),
    features: str | None = typer.Option(None, help="Comma-separated feature/group names (default: all)."),
    max_distance: float = typer.Option(0.0, help="Label transfer distance in metres (0: 2 × point spacing)."),
    trees: int = typer.Option(32, help="Number of trees."),
    max_depth: int = typer.Option(14, help="Tree depth limit."),
    seed: int = typer.Option(0, help="Seed of every random choice."),
    report: Path | None = typer.Option(None, help="Write the training report (JSON) here."),
) -> None:
    """Train a random forest; print held-out per-class precision/recall/F1, confusion matrix, importances."""
    from classify.training import train_from_projects
    from hybridsplat.layout import ProjectLayout

    names = tuple(n.strip() for n in features.split(",")) if features else None
    dense = [ProjectLayout(p).dense for p in projects]
    result = train_from_projects(
        dense, out, scenes=scene, labels_file=labels_file, field=field, las_codes=las_codes,
        label_masks=label_masks, classes_toml=classes, feature_names=names, max_distance=max_distance,
        trees=trees, max_depth=max_depth, seed=seed,
    )  # fmt: skip
    rep = result.to_dict()
    for c in rep["per_class"]:
        typer.echo(f"{c['name']:>14}: P {c['precision']:.3f} R {c['recall']:.3f} F1 {c['f1']:.3f} ({c['support']})")
    b = rep["needs_splats"]
    typer.echo(f"  needs splats: P {b['precision']:.3f} R {b['recall']:.3f} F1 {b['f1']:.3f}")
    typer.echo("confusion (rows true, columns predicted): " + json.dumps(rep["confusion"]))
    top = sorted(rep["importances"].items(), key=lambda kv: -kv[1])[:8]
    typer.echo("top features: " + ", ".join(f"{k} {v:.3f}" for k, v in top))
    if report is not None:
        from core.io.json_io import write_json_atomic

        write_json_atomic(report, rep)
    typer.echo(f"wrote {out}")


@classify_app.command("features")
def features_cmd(scales: int = typer.Option(3, help="Number of geometric scales.")) -> None:
    """List every feature: name, unit, group and meaning."""
    from classify.features import feature_specs

    for spec in feature_specs(scales).values():
        typer.echo(f"{spec.name:28} {spec.unit:6} {spec.group.value:12} {spec.meaning}")


def register(app: typer.Typer) -> None:
    from hybridsplat.commands.stages import stage_command
    from hybridsplat.stages import stage_named

    classify_app.command("predict")(stage_command(stage_named("classify")))
    app.add_typer(classify_app, name="classify")
