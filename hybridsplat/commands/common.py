"""What the pipeline commands share: building the configuration from options, and the closing lines."""

from __future__ import annotations

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
    )


def stage_options_from_cli(**given: dict[str, Any]) -> dict[str, Any]:
    """Stage options from ``stage=dict(option=value)``; None values keep the stage's default."""
    from hybridsplat.config import options_from_table
    from hybridsplat.pipeline import STAGE_OPTIONS

    return {
        name: options_from_table(STAGE_OPTIONS[name], {k: v for k, v in values.items() if v is not None}, "--options")
        for name, values in given.items()
    }


def print_result(terminal: Any, project: Path, manifest: Any) -> None:
    from hybridsplat.layout import ProjectLayout

    layout = ProjectLayout(project)
    if layout.report_html.is_file():
        terminal.line(f"report: {layout.report_html}")
    terminal.line(f"manifest: {layout.manifest}")


def run_project_stage(project: Path, name: str, overrides: dict[str, Any], force: bool = False, quiet: bool = False):
    """Run stage ``name`` of an existing project with its recorded configuration and ``overrides`` (None = keep)."""
    from dataclasses import replace

    from core.errors import ConfigError
    from hybridsplat.pipeline import STAGE_OPTIONS, load_config, run_pipeline
    from hybridsplat.stages import stage_named
    from hybridsplat.terminal import Terminal

    config = load_config(project)
    options = config.options(name, STAGE_OPTIONS[name])
    try:
        options = replace(options, **{k: v for k, v in overrides.items() if v is not None})
    except (TypeError, ValueError) as err:
        raise ConfigError(str(err)) from err
    terminal = Terminal(quiet=quiet)
    manifest = run_pipeline(
        project, config.with_stage_options(name, options), [stage_named(name)], terminal, [name] if force else []
    )
    return terminal, manifest
