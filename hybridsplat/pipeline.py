"""The pipeline: a project folder, its configuration, and the ordered stages run over it.

``run_pipeline`` resolves the input, writes ``config.toml`` and runs the registered stages through the runner; the
per-stage commands call ``run_pipeline`` with one stage. See ``hybridsplat.stages`` for the registry of stages and
DESIGN.md for the data flow.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from os import PathLike

from core.errors import ConfigError
from core.io.atomic import write_text_atomic
from hybridsplat.config import ProjectConfig, read_config
from hybridsplat.layout import ProjectLayout
from hybridsplat.manifest import Manifest
from hybridsplat.runner import run_stages
from hybridsplat.source import resolve_source
from hybridsplat.stages import Stage, StageContext, registered_stages, stage_options_types
from hybridsplat.terminal import Terminal


def load_config(project: str | PathLike[str]) -> ProjectConfig:
    """The configuration a project was run with (``PROJECT/config.toml``)."""
    return read_config(ProjectLayout(project).config, stage_options_types())


def run_pipeline(
    project: str | PathLike[str],
    config: ProjectConfig,
    stages: Sequence[Stage] | None = None,
    terminal: Terminal | None = None,
    force: Iterable[str] = (),
) -> Manifest:
    """Run ``stages`` (default: every registered stage) of the project at ``project`` with ``config`` (written to
    ``config.toml`` first).

    The input is resolved before anything is written, so a bad input leaves no project folder behind.
    """
    layout = ProjectLayout(project)
    if layout.root.exists() and not layout.root.is_dir():
        raise ConfigError("the project folder is a file", layout.root)
    source = resolve_source(config.input)
    layout.root.mkdir(parents=True, exist_ok=True)
    write_text_atomic(layout.config, _complete(config).to_toml())
    ctx = StageContext(layout=layout, config=config, source=source)
    stages = registered_stages() if stages is None else stages
    return run_stages(ctx, stages, terminal or Terminal(quiet=True), force)


def _complete(config: ProjectConfig) -> ProjectConfig:
    """Every stage's options spelled out (defaults included), so config.toml documents the whole run."""
    for stage in registered_stages():
        config = config.with_stage_options(stage.name, config.options(stage.name, stage.Options))
    return config
