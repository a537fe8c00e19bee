"""The project configuration: what ``run`` was given, and every stage's options, as ``PROJECT/config.toml``.

One TOML table per stage (``[mvs]``, ``[convert]``, ...) holds that stage's ``Options`` dataclass (sub-tables such as
``[train.training]`` hold the dataclasses it composes; see :mod:`hybridsplat.options` for the spelling of None, enums
and lists); ``[input]`` says where the photos and cameras came from; ``seed`` seeds every random choice. A
config.toml written by hybridsplat 0.2 (flat keys such as ``[train] iterations``) is read through
:mod:`hybridsplat.config_migration`. The per-stage commands read this file
back, so ``hybridsplat mvs PROJECT`` runs with the options ``run`` used unless told otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from os import PathLike
from pathlib import Path
from typing import Any, ClassVar

import tomllib

from core.constraints import Choice, Constrained, Constraints, Interval
from core.errors import ConfigError, FormatError
from core.units import Units
from hybridsplat.config_migration import migrate_table
from hybridsplat.options import options_digest, options_from_table

__all__ = ["InputOptions", "ProjectConfig", "options_digest", "options_from_table", "read_config"]

UNITS = tuple(u.value for u in Units)


@dataclass(frozen=True)
class InputOptions(Constrained):
    """Where the project's data comes from (``hybridsplat run INPUT ...``).

    path: a folder of photos (directly or under ``images/``), a COLMAP workspace, or a data_synth scene.
    model: which model of a COLMAP workspace with several (``sparse/N``); None = the largest.
    cameras: a COLMAP model of known cameras (poses fixed, only triangulation); a data_synth scene's own
        ``sparse/0`` is used when ``use_scene_cameras`` is true.
    use_scene_cameras: with a data_synth scene or COLMAP workspace, keep its cameras (known poses).
    reference: camera centres to align to: a text file ``NAME X Y Z`` or a COLMAP model.
    units: the unit of the reference's coordinates (converted to metres on input; reports print lengths in it).
    crs: coordinate reference system of the reference (``EPSG:N``), carried into sidecars and LAS files.
    control: ground control and check points (``id,X,Y,Z[,sigma_xy,sigma_z],role`` CSV, :mod:`core.io.control`)
        the model is adjusted to (the control stage); in ``units`` unless the file declares its own.
    marks: marks of those points in the photos made by hand (``image,point_id,u,v``), over the detected ones.
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
    control: str | None = None
    marks: str | None = None
    holdout: int = -1
    splat_masks: str | None = None
    feature_masks: str | None = None

    constraints: ClassVar[Constraints] = {"units": Choice(UNITS), "holdout": Interval(int, -1, None)}

    def __post_init__(self) -> None:
        super().__post_init__()
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
        from hybridsplat.options import toml_tables

        lines = ["# hybridsplat: the effective configuration of this project", f"seed = {self.seed}", ""]
        lines += toml_tables("input", self.input)
        for name, options in self.stages.items():
            if fields(options):
                lines += toml_tables(name, options)
        return "\n".join(lines)


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
        stages[name] = options_from_table(stage_options[name], migrate_table(name, table, path), path)
    return ProjectConfig(input=input_options, seed=seed, stages=stages)
