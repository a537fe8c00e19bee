"""``hybridsplat run`` (every stage on an input) and ``hybridsplat demo`` (the built-in synthetic scene + run)."""

from __future__ import annotations

import inspect
import typing
from pathlib import Path
from typing import Any

import typer

from hybridsplat.commands.common import input_options_from_cli, print_result, stage_options_from_cli

DEMO_STAGES: dict[str, dict[str, Any]] = {
    "mesh": {"budget": 2_000},
    "train": {"training.iterations": 600},
    "baseline": {"enabled": True, "training.iterations": 1_000},
    "merge": {"viewer_formats": ["spz", "sog"]},
}
"""The demo's stage options (option paths as in config.toml): a small mesh and CPU-sized training budgets for the
hybrid and the whole-scene baseline, so that every stage of the demo scene runs in minutes on 2 cores
(``bench/bench_pipeline.py`` sweeps the budgets), and the viewer product also as SPZ and SOG."""


def _run_input(
    input_path: Path = typer.Argument(
        ..., help="A folder of photos (or with images/), a COLMAP workspace, or a data_synth scene."
    ),
    out: Path = typer.Option(..., "--out", help="Project folder (created); its layout: docs/conventions.md."),
    model: int | None = typer.Option(None, help="Model N of a COLMAP workspace with several (default: largest)."),
    cameras: Path | None = typer.Option(
        None, help="COLMAP model of known cameras: poses fixed, only matching and triangulation."
    ),
    full_sfm: bool = typer.Option(
        False, "--full-sfm", help="Ignore the cameras a scene or workspace brings; run SfM and align to them."
    ),
    reference: Path | None = typer.Option(
        None, help="Align to these camera centres: a text file 'NAME X Y Z' per line, or a COLMAP model."
    ),
    units: str = typer.Option("m", help="Unit of the reference coordinates: m | mm | cm | ft."),
    crs: str | None = typer.Option(None, help="CRS of the reference (EPSG:N), written to sidecars and LAS."),
    control: Path | None = typer.Option(
        None, help="Ground control and check points (CSV: id,X,Y,Z[,sigma_xy,sigma_z],role): adjust to them."
    ),
    marks: Path | None = typer.Option(
        None, help="Hand-made marks of those points in the photos (CSV: image,point_id,u,v), over the detected ones."
    ),
    holdout: int = typer.Option(
        -1, help="Hold out every N-th photo for evaluation (default: the input's own test views, else 8; 0: none)."
    ),
    splat_masks: Path | None = typer.Option(None, help="Masks of regions that need splats (white), NAME.png."),
    feature_masks: Path | None = typer.Option(None, help="COLMAP masks for feature extraction (black = ignore)."),
    seed: int = typer.Option(0, help="Seed of every random choice."),
    force: list[str] = typer.Option([], "--force", help="Rerun this stage even when up to date (repeatable)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """The parameters of ``run`` that are not stage options (the stages' come from their ``run_options``)."""


def _run_parameters() -> list[inspect.Parameter]:
    from hybridsplat.commands.stages import cli_parameters
    from hybridsplat.stages import registered_stages

    hints = typing.get_type_hints(_run_input)
    params = [p.replace(annotation=hints[p.name]) for p in inspect.signature(_run_input).parameters.values()]
    params = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) if p.name != "input_path" else p for p in params]
    own = {p.name for p in params}
    shared: dict[str, inspect.Parameter] = {}
    for stage in registered_stages():
        for param in cli_parameters(stage.Options, stage.run_options):
            if param.name in own or (param.name in shared and shared[param.name].annotation != param.annotation):
                raise TypeError(f"stage {stage.name}: run option --{param.name} clashes with another option")
            # a flag several stages declare (``--memory-limit``) is one parameter; its value sets each of them
            if param.name not in shared:
                shared[param.name] = param
                params.append(param)
    return params


def _run(input_path: Path, out: Path, model, cameras, full_sfm, reference, units, crs, control, marks, holdout,
         splat_masks, feature_masks, seed: int, force: list[str], quiet: bool,
         **stage_values: Any) -> None:  # fmt: skip
    from hybridsplat.commands.stages import apply_cli_values
    from hybridsplat.config import ProjectConfig
    from hybridsplat.pipeline import run_pipeline
    from hybridsplat.stages import registered_stages
    from hybridsplat.terminal import Terminal

    stages = {
        stage.name: apply_cli_values(stage.Options(), stage.run_options, stage_values)
        for stage in registered_stages()
        if stage.run_options
    }
    config = ProjectConfig(
        input=input_options_from_cli(
            input_path,
            model,
            cameras,
            full_sfm,
            reference,
            units,
            crs,
            holdout,
            splat_masks,
            feature_masks,
            control,
            marks,
        ),
        seed=seed,
        stages=stages,
    )
    _check_control_files(config.input)
    terminal = Terminal(quiet=quiet)
    terminal.line(f"hybridsplat run: {input_path} -> {out}")
    manifest = run_pipeline(out, config, terminal=terminal, force=force)
    print_result(terminal, out, manifest)


def _check_control_files(inp: Any) -> None:
    """Read the GCP and marks files before any stage runs: a bad one stops the run at once, naming its line (the
    control stage checks the marks against the photos later)."""
    from core.io.control import read_gcp_csv, read_marks_csv

    if inp.control:
        read_gcp_csv(inp.control, inp.units, inp.crs)
    if inp.marks:
        read_marks_csv(inp.marks)


def register(app: typer.Typer) -> None:
    from hybridsplat.commands.stages import build_command

    doc = "Run every stage end to end; stages already up to date are skipped, and say so."
    app.command("run")(build_command("run", _run_parameters(), _run, doc))

    @app.command("demo")
    def demo(
        out: Path = typer.Option(Path("demo_project"), "--out", help="Folder for the scene (OUT/scene) and project."),
        preset: str = typer.Option("demo", help="data_synth preset of the built-in scene (demo: a reduced tabletop)."),
        seed: int = typer.Option(0, help="Seed of the scene and the pipeline."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    ) -> None:
        """The main job on the built-in synthetic scene: generate it, then run every stage on it (held to the scene's
        coded targets when it has them)."""
        from data_synth import SceneLayout, generate_scene
        from hybridsplat.config import InputOptions, ProjectConfig
        from hybridsplat.pipeline import run_pipeline
        from hybridsplat.terminal import Terminal

        terminal = Terminal(quiet=quiet)
        scene = out / "scene"
        if not (scene / "scene.json").is_file():
            terminal.line(f"hybridsplat demo: generating the {preset} scene into {scene}")
            generate_scene(preset, scene, seed=seed, overwrite=True)
        else:
            terminal.line(f"hybridsplat demo: using the scene in {scene}")
        project = out / "project"
        gcp = SceneLayout(scene).gcp_csv  # the scene's coded targets: the run is held to them
        control = str(gcp.resolve()) if gcp.is_file() else None
        config = ProjectConfig(
            input=InputOptions(path=str(scene.resolve()), control=control),
            seed=seed,
            stages=stage_options_from_cli(**DEMO_STAGES),
        )
        manifest = run_pipeline(project, config, terminal=terminal)
        print_result(terminal, project, manifest)
