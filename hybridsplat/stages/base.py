"""What a pipeline stage is, and what it is given.

A stage is a small class in its own module: a ``name``, an ``Options`` frozen dataclass with documented defaults
(one TOML table in ``config.toml``), the files it reads (``inputs``) and writes (``outputs``), ``needs`` (a reason
to skip, or None) and ``run`` (returns counts for the manifest). It is a thin shell: it reads files, calls a pure
function of ``recon``/``classify``/``fusion``/``eval``, and writes files (atomically, through ``core.io``).
The runner (``hybridsplat.runner``) decides whether it runs, times it and records it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from core.cameras import Cameras
from core.pointcloud import PointCloud
from hybridsplat.config import ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.source import Source
from hybridsplat.terminal import ProgressCallback


@dataclass(frozen=True)
class NoOptions:
    """A stage without options."""


def _no_progress(label: str, done: int, total: int) -> None:
    return None


@dataclass
class StageContext:
    """Everything a stage may use: the project layout, the configuration, the input, a progress callback, and
    (while it runs) the content hashes the runner took of its ``inputs``."""

    layout: ProjectLayout
    config: ProjectConfig
    source: Source
    progress: ProgressCallback = field(default=_no_progress)
    input_hashes: dict[Path, str] = field(default_factory=dict)

    def options(self, stage: Stage) -> Any:
        return self.config.options(stage.name, stage.Options)

    def content_hash(self, path: Path) -> str:
        """SHA-256 of a file or folder (``hybridsplat.manifest.hash_path``), the runner's when it hashed it already."""
        from hybridsplat.manifest import hash_path

        known = self.input_hashes.get(Path(path))
        return known if known is not None else hash_path(path)


class Stage:
    """Base class of the pipeline's stages (see the module docstring)."""

    name: ClassVar[str]
    Options: ClassVar[type] = NoOptions
    title: ClassVar[str] = ""  # a few words for the terminal

    def inputs(self, ctx: StageContext) -> list[Path]:
        """Files and folders whose content decides the outputs (hashed by the runner)."""
        return []

    def outputs(self, ctx: StageContext) -> list[Path]:
        """Files and folders this stage writes; removed when it fails, is interrupted or becomes unneeded."""
        return []

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        """Extra values that decide the outputs besides inputs and options (compared like the options)."""
        return {}

    def needs(self, ctx: StageContext) -> str | None:
        """None when the stage must run for this project, else the reason it is skipped."""
        return None

    def run(self, ctx: StageContext) -> dict[str, Any]:
        """Do the work; return counts for the manifest (JSON-serialisable)."""
        raise NotImplementedError

    def summary(self, counts: dict[str, Any]) -> str:
        """A few words about what the stage produced, for the terminal's one-line summary."""
        return ""


def model_origin(ctx: StageContext) -> np.ndarray:
    """(3,) float64 world coordinates (metres) of the frame the project's COLMAP models are written in.

    COLMAP models hold no origin: the sfm stage records it (a georeferenced block is aligned into a local frame
    around a rounded centroid). Zeros before the sfm stage ran or without a georeference.
    """
    return recorded_model_origin(ctx.layout, np.zeros(3))


def recorded_model_origin(layout: ProjectLayout, fallback: np.ndarray) -> np.ndarray:
    """The ``origin`` the sfm stage recorded in ``layout.record("sfm")``, else ``fallback`` (see model_origin)."""
    from core.errors import FormatError
    from core.io.json_io import read_json_object

    record = layout.record("sfm")
    if record.is_file():
        origin = read_json_object(record).get("origin")
        if origin is not None:
            if not (isinstance(origin, list) and len(origin) == 3):
                raise FormatError(f'"origin" must be three numbers, got {origin!r}', record)
            return np.asarray(origin, np.float64).reshape(3)
    return np.asarray(fallback, np.float64).reshape(3)


def read_model_at(path: Path, origin: np.ndarray) -> tuple[Cameras, PointCloud]:
    """A COLMAP model (cameras and points) whose local frame lies at ``origin`` (world = origin + local)."""
    from core.io.colmap import read_model

    cameras, points = read_model(path)
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    return replace(cameras, origin=origin), replace(points, origin=origin)


def read_project_model(ctx: StageContext, path: Path) -> tuple[Cameras, PointCloud]:
    """A model of this project (``sparse/`` or the dense workspace's) in world coordinates, see model_origin."""
    return read_model_at(path, model_origin(ctx))
