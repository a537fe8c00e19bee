"""``hybridsplat sfm INPUT --out PROJECT``: the ``sfm`` stage alone (camera poses and sparse model).

Its stage options are the ``sfm`` stage's ``command_options``; the input options are those of ``run``.
"""

from __future__ import annotations

import inspect
import typing
from pathlib import Path
from typing import Any

import typer


def _sfm_input(
    input_path: Path = typer.Argument(
        ..., help="A folder of photos (or with images/), a COLMAP workspace, or a data_synth scene."
    ),
    out: Path = typer.Option(..., "--out", help="Project folder; the model is written to PROJECT/sparse/."),
    cameras: Path | None = typer.Option(None, help="COLMAP model of known cameras (poses fixed)."),
    full_sfm: bool = typer.Option(False, "--full-sfm", help="Ignore the cameras a scene or workspace brings."),
    reference: Path | None = typer.Option(None, help="Camera centres to align to: 'NAME X Y Z' text or a model."),
    units: str = typer.Option("m", help="Unit of the reference coordinates: m | mm | cm | ft."),
    crs: str | None = typer.Option(None, help="CRS of the reference (EPSG:N)."),
    feature_masks: Path | None = typer.Option(None, help="COLMAP masks NAME.png (black = ignore features)."),
    seed: int = typer.Option(0, help="Seed (same inputs + seed -> same model)."),
    force: bool = typer.Option(False, "--force", help="Rerun even when up to date."),
) -> None:
    """The parameters of ``sfm`` that are not stage options."""


def _sfm(input_path: Path, out: Path, cameras, full_sfm, reference, units, crs, feature_masks, seed: int,
         force: bool, **stage_values: Any) -> None:  # fmt: skip
    from hybridsplat.commands.common import input_options_from_cli
    from hybridsplat.commands.stages import apply_cli_values
    from hybridsplat.config import ProjectConfig
    from hybridsplat.pipeline import run_pipeline
    from hybridsplat.stages import stage_named
    from hybridsplat.terminal import Terminal

    stage = stage_named("sfm")
    config = ProjectConfig(
        input=input_options_from_cli(
            input_path, cameras=cameras, full_sfm=full_sfm, reference=reference, units=units, crs=crs,
            feature_masks=feature_masks,
        ),
        seed=seed,
        stages={"sfm": apply_cli_values(stage.Options(), stage.command_options, stage_values)},
    )  # fmt: skip
    run_pipeline(out, config, [stage], Terminal(), ["sfm"] if force else [])


def register(app: typer.Typer) -> None:
    from hybridsplat.commands.stages import build_command, cli_parameters
    from hybridsplat.stages import stage_named

    stage = stage_named("sfm")
    hints = typing.get_type_hints(_sfm_input)
    params = [p.replace(annotation=hints[p.name]) for p in inspect.signature(_sfm_input).parameters.values()]
    params = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) if p.name != "input_path" else p for p in params]
    params += cli_parameters(stage.Options, stage.command_options)
    doc = "Structure from motion (or triangulation with known cameras) and alignment to a reference."
    app.command("sfm")(build_command("sfm", params, _sfm, doc))
