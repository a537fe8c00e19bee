"""The pipeline: a project folder, its configuration, and the ordered stages run over it.

``run_pipeline`` resolves the input, writes ``config.toml`` and runs the registered stages through the runner; the
per-stage commands call ``run_pipeline`` with one stage. See ``hybridsplat.stages`` for the registry of stages and
DESIGN.md for the data flow.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from os import PathLike
from pathlib import Path
from typing import Any

from core.errors import ConfigError
from core.io.atomic import write_text_atomic
from hybridsplat.config import ProjectConfig, read_config
from hybridsplat.layout import ProjectLayout
from hybridsplat.manifest import Manifest
from hybridsplat.project_lock import ProjectLock
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

    The input is resolved before anything is written, so a bad input leaves no project folder behind. The
    project's write lock (:mod:`hybridsplat.project_lock`) is held from before ``config.toml`` is written until the
    last stage ends: a second writer is refused with :class:`~core.errors.ProjectBusyError`, naming this one.
    """
    layout = ProjectLayout(project)
    if layout.root.exists() and not layout.root.is_dir():
        raise ConfigError("the project folder is a file", layout.root)
    source = resolve_source(config.input)
    layout.root.mkdir(parents=True, exist_ok=True)
    stages = registered_stages() if stages is None else stages
    terminal = terminal or Terminal(quiet=True)
    with ProjectLock(layout.root, stages=[s.name for s in stages]) as lock:
        if lock.took_over is not None:
            terminal.line(f"took over the project's lock from {lock.took_over.describe()}, which ended without it")
        text = _complete(config).to_toml()
        changed = config_changes(layout.config, text)
        if changed:
            terminal.line(f"config.toml: {describe_changes(changed)}")
        write_text_atomic(layout.config, text)
        ctx = StageContext(layout=layout, config=config, source=source)
        return run_stages(ctx, stages, terminal, force, on_stage=lock.note_stage)


def config_changes(path: Path, text: str) -> list[tuple[str, Any, Any]]:
    """The options (dotted TOML keys) whose value in the TOML ``text`` differs from that in the file at ``path``, as
    (key, old, new); old or new is None where a key is missing on that side. Nothing when the file does not exist
    or is not TOML (the run replaces it either way)."""
    import tomllib

    try:
        old = _flatten(tomllib.loads(path.read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return []
    new = _flatten(tomllib.loads(text))
    return [(k, old.get(k), new.get(k)) for k in sorted(old.keys() | new.keys()) if old.get(k) != new.get(k)]


def describe_changes(changes: list[tuple[str, Any, Any]], most: int = 4) -> str:
    """One line: how many options a run replaced in config.toml, the first ``most`` of them with old → new."""
    shown = ", ".join(f"{key} {old!r} -> {new!r}" for key, old, new in changes[:most])
    more = f" and {len(changes) - most} more" if len(changes) > most else ""
    return f"{len(changes)} option(s) replaced by this command's ({shown}{more}); the stages that use them rerun"


def _flatten(table: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in table.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _complete(config: ProjectConfig) -> ProjectConfig:
    """Every stage's options spelled out (defaults included), so config.toml documents the whole run."""
    for stage in registered_stages():
        config = config.with_stage_options(stage.name, config.options(stage.name, stage.Options))
    return config
