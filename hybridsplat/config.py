"""The project configuration: what ``run`` was given, and every stage's options, as ``PROJECT/config.toml``.

One TOML table per stage (``[mvs]``, ``[convert]``, ...) holds that stage's ``Options`` dataclass; ``[input]`` says
where the photos and cameras came from; ``seed`` seeds every random choice. The per-stage commands read this file
back, so ``hybridsplat mvs PROJECT`` runs with the options ``run`` used unless told otherwise.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from enum import Enum
from os import PathLike
from pathlib import Path
from typing import Any

import tomllib

from core.errors import ConfigError, FormatError
from core.units import Units

UNITS = tuple(u.value for u in Units)


@dataclass(frozen=True)
class InputOptions:
    """Where the project's data comes from (``hybridsplat run INPUT ...``).

    path: a folder of photos (directly or under ``images/``), a COLMAP workspace, or a data_synth scene.
    model: which model of a COLMAP workspace with several (``sparse/N``); None = the largest.
    cameras: a COLMAP model of known cameras (poses fixed, only triangulation); a data_synth scene's own
        ``sparse/0`` is used when ``use_scene_cameras`` is true.
    use_scene_cameras: with a data_synth scene or COLMAP workspace, keep its cameras (known poses).
    reference: camera centres to align to: a text file ``NAME X Y Z`` or a COLMAP model.
    units: the unit of the reference's coordinates (converted to metres on input; reports print lengths in it).
    crs: coordinate reference system of the reference (``EPSG:N``), carried into sidecars and LAS files.
    holdout: every N-th photo (name order) held out for evaluation; -1 = the input's own held-out views if it has
        them, else every 8th; 0 = none.
    splat_masks: folder of user masks of regions that need splats (white = needs splats).
    feature_masks: folder of COLMAP-convention masks for feature extraction (black = ignore).
    """

    path: str = ""
    model: int | None = None
    cameras: str | None = None
    use_scene_cameras: bool = True
    reference: str | None = None
    units: str = "m"
    crs: str | None = None
    holdout: int = -1
    splat_masks: str | None = None
    feature_masks: str | None = None

    def __post_init__(self) -> None:
        if self.units not in UNITS:
            raise ConfigError(f"units must be one of {', '.join(UNITS)}, got {self.units!r}")
        if self.holdout < -1:
            raise ConfigError(f"holdout must be -1 (default), 0 (none) or N > 0, got {self.holdout}")
        if self.crs is not None and not _looks_like_crs(self.crs):
            raise ConfigError(f"crs must look like EPSG:N (or another AUTHORITY:CODE), got {self.crs!r}")


def _looks_like_crs(crs: str) -> bool:
    authority, _, code = crs.partition(":")
    return bool(authority.isalpha() and code.strip())


@dataclass(frozen=True)
class ProjectConfig:
    """The whole configuration: input, seed, and each stage's options (keyed by stage name)."""

    input: InputOptions = field(default_factory=InputOptions)
    seed: int = 0
    stages: dict[str, Any] = field(default_factory=dict)

    def options(self, name: str, options_type: type) -> Any:
        """The options of stage ``name`` (the type's defaults when the configuration has none)."""
        found = self.stages.get(name)
        return found if found is not None else options_type()

    def with_stage_options(self, name: str, options: Any) -> ProjectConfig:
        return replace(self, stages={**self.stages, name: options})

    def to_toml(self) -> str:
        lines = ["# hybridsplat: the effective configuration of this project", f"seed = {self.seed}", ""]
        lines += _table("input", self.input)
        for name, options in self.stages.items():
            if fields(options):
                lines += _table(name, options)
        return "\n".join(lines)


def _table(name: str, options: Any) -> list[str]:
    lines = [f"[{name}]"]
    for f in fields(options):
        lines.append(_toml_line(f.name, getattr(options, f.name)))
    return [*lines, ""]


def _toml_line(key: str, value: Any) -> str:
    if value is None:
        return f"# {key} = (not set)"
    if isinstance(value, Enum):
        value = value.value
    if isinstance(value, bool):
        return f"{key} = {'true' if value else 'false'}"
    if isinstance(value, (int, float)):
        return f"{key} = {value!r}"
    if isinstance(value, (tuple, list)):
        return f"{key} = {json.dumps([v.value if isinstance(v, Enum) else v for v in value])}"
    return f"{key} = {json.dumps(str(value))}"


def options_from_table(options_type: type, table: dict[str, Any], where: Path | str) -> Any:
    """Build an options dataclass from a TOML table; unknown keys and wrong types are a :class:`ConfigError`."""
    known = {f.name: f for f in fields(options_type)}
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise ConfigError(f"unknown option(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})", where)
    defaults = options_type()
    values = {}
    for key, value in table.items():
        default = getattr(defaults, key)
        if isinstance(default, tuple) and isinstance(value, list):
            value = tuple(value)
        if isinstance(default, Enum):
            try:
                value = type(default)(value)
            except ValueError as err:
                raise ConfigError(f"option {key}: {err}", where) from err
        elif default is not None and isinstance(default, float) and isinstance(value, int):
            value = float(value)
        elif default is not None and type(value) is not type(default):
            raise ConfigError(
                f"option {key} must be {type(default).__name__}, got {type(value).__name__} {value!r}", where
            )
        values[key] = value
    try:
        return options_type(**values)
    except ConfigError as err:
        raise ConfigError(err.problem, where) from err
    except (TypeError, ValueError) as err:
        raise ConfigError(str(err), where) from err


def read_config(path: str | PathLike[str], stage_options: dict[str, type]) -> ProjectConfig:
    """Read ``config.toml`` (as written by :meth:`ProjectConfig.to_toml`); ``stage_options`` maps names to types."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as err:
        raise ConfigError(
            "no config.toml: this folder is not a hybridsplat project (run 'hybridsplat run')", path
        ) from err
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise FormatError(f"not valid TOML ({err})", path) from err
    seed = data.pop("seed", 0)
    if not isinstance(seed, int):
        raise ConfigError(f"seed must be an integer, got {seed!r}", path)
    input_options = options_from_table(InputOptions, data.pop("input", {}), path)
    stages = {}
    for name, table in data.items():
        if name not in stage_options:
            raise ConfigError(f"unknown section [{name}] (stages: {', '.join(stage_options)})", path)
        if not isinstance(table, dict):
            raise ConfigError(f"[{name}] must be a table", path)
        stages[name] = options_from_table(stage_options[name], table, path)
    return ProjectConfig(input=input_options, seed=seed, stages=stages)


def options_digest(options: Any) -> dict[str, Any]:
    """Options as plain JSON data (enums as values), the form recorded and compared in the manifest."""
    if options is None:
        return {}
    data = asdict(options) if is_dataclass(options) else dict(options)
    return json.loads(json.dumps(data, default=lambda v: v.value if isinstance(v, Enum) else str(v)))
