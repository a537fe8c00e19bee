"""What the pipeline commands share: building the configuration from options, and the closing lines."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from hybridsplat.config import InputOptions


def _abs(path: Path | None) -> str | None:
    return str(path.resolve()) if path is not None else None


def input_options_from_cli(
    input_path: Path,
    model: int | None = None,
    cameras: Path | None = None,
    full_sfm: bool = False,
    reference: Path | None = None,
    units: str = "m",
    crs: str | None = None,
    holdout: int = -1,
    splat_masks: Path | None = None,
    feature_masks: Path | None = None,
    control: Path | None = None,
    marks: Path | None = None,
) -> InputOptions:
    """``[input]`` of config.toml from command-line values (paths made absolute)."""
    return InputOptions(
        path=str(input_path.resolve()),
        model=model,
        cameras=_abs(cameras),
        use_scene_cameras=not full_sfm,
        reference=_abs(reference),
        units=units,
        crs=crs,
        holdout=holdout,
        splat_masks=_abs(splat_masks),
        feature_masks=_abs(feature_masks),
        control=_abs(control),
        marks=_abs(marks),
    )


def stage_options_from_cli(**given: dict[str, Any]) -> dict[str, Any]:
    """Stage options from ``stage={"option.path": value}`` (values as config.toml spells them; None keeps the
    stage's default)."""
    from hybridsplat.options import options_with
    from hybridsplat.stages import stage_options_types

    types = stage_options_types()
    return {name: options_with(types[name], values) for name, values in given.items()}


def print_result(terminal: Any, project: Path, manifest: Any) -> None:
    from hybridsplat.layout import ProjectLayout

    layout = ProjectLayout(project)
    if layout.report_html.is_file():
        terminal.line(f"report: {layout.report_html}")
    terminal.line(f"manifest: {layout.manifest}")


def run_project_stage(
    project: Path, name: str, update: Callable[[Any], Any] | dict[str, Any], force: bool = False, quiet: bool = False
):
    """Run stage ``name`` of an existing project with its recorded configuration, changed by ``update`` (a function
    of the recorded options, or ``{option path: value}`` where None keeps the recorded value)."""
    from hybridsplat.options import with_options
    from hybridsplat.pipeline import load_config, run_pipeline
    from hybridsplat.stages import stage_named
    from hybridsplat.terminal import Terminal

    stage = stage_named(name)
    config = load_config(project)
    options = config.options(name, stage.Options)
    options = update(options) if callable(update) else with_options(options, update)
    terminal = Terminal(quiet=quiet)
    manifest = run_pipeline(
        project, config.with_stage_options(name, options), [stage], terminal, [name] if force else []
    )
    return terminal, manifest
