"""Paths of the recon stages inside a project folder, and the SfM record that MVS reads back.

PROJECT/sparse/            COLMAP sparse model (aligned to the reference frame when one was given)
PROJECT/dense/             COLMAP dense workspace (see recon.workspace)
PROJECT/logs/sfm.json      where the images came from, the origin of the model's frame, the SfM report
PROJECT/logs/mvs.json      the MVS report
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, is_dataclass
from pathlib import Path

import numpy as np

from core.errors import FormatError, InputFileError
from core.io.atomic import write_text_atomic


@dataclass(frozen=True)
class ProjectPaths:
    root: Path

    @property
    def sparse(self) -> Path:
        return self.root / "sparse"

    @property
    def dense(self) -> Path:
        return self.root / "dense"

    @property
    def logs(self) -> Path:
        return self.root / "logs"

    @property
    def sfm_record(self) -> Path:
        return self.logs / "sfm.json"

    @property
    def mvs_record(self) -> Path:
        return self.logs / "mvs.json"


@dataclass(frozen=True)
class SceneInput:
    """What ``hybridsplat sfm INPUT`` was given: an image folder, plus the reference model of a data_synth scene."""

    image_dir: Path
    reference_model: Path | None  # sparse/0 of a data_synth scene (true cameras)
    gsd_m: float | None  # ground-sample distance from scene.json, metres
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)  # world coordinates of the model's local frame (scene.json)


def resolve_input(path: str | Path) -> SceneInput:
    """A folder of photos, or a data_synth scene folder (``images/``, ``sparse/0/``, ``scene.json``)."""
    p = Path(path)
    if not p.is_dir():
        raise InputFileError("input is not a folder (expected a folder of photos or a data_synth scene)", p)
    if (p / "images").is_dir() and (p / "sparse" / "0").is_dir():
        meta: dict = {}
        if (p / "scene.json").is_file():
            try:
                meta = json.loads((p / "scene.json").read_text(encoding="utf-8"))
            except json.JSONDecodeError as err:
                raise FormatError(f"scene.json is not valid JSON ({err})", p / "scene.json") from err
        gsd = meta.get("gsd_m")
        origin = tuple(float(v) for v in meta.get("origin", (0.0, 0.0, 0.0)))
        return SceneInput(p / "images", p / "sparse" / "0", float(gsd) if gsd else None, origin)
    return SceneInput(p, None, None)


def _jsonable(x):
    if is_dataclass(x):
        return {k: _jsonable(v) for k, v in asdict(x).items()}
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    if isinstance(x, Path):
        return str(x)
    if hasattr(x, "value") and not isinstance(x, (int, float, str)):
        return x.value
    return x


def write_record(path: Path, record: dict) -> None:
    """Write a JSON record (dataclasses, numpy arrays and paths converted) atomically."""
    write_text_atomic(path, json.dumps(_jsonable(record), indent=2) + "\n")


def read_sfm_record(project: ProjectPaths) -> dict:
    if not project.sfm_record.is_file():
        raise InputFileError("no SfM record (run 'hybridsplat sfm' first, or pass --images)", project.sfm_record)
    return json.loads(project.sfm_record.read_text(encoding="utf-8"))
