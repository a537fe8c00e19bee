"""The one reader of a scene description (``scene.json`` of a data_synth scene).

A scene description says what a scene folder holds beyond photos and cameras: the materials legend (which
material ids MVS can be trusted on), the unit and the float64 origin of the local frame, the ground-sample
distance, an optional CRS, and the names of the training and held-out views. Every package that needs one of
these reads it through :func:`read_scene_description`, so that the format is checked in one place.

Format (JSON object; keys beyond these are kept in ``extra`` and ignored here)::

    {"units": "m", "origin": [x, y, z], "gsd_m": 0.004, "crs": "EPSG:32632" (optional),
     "preset": "tiny", "seed": 0,
     "materials": [{"id": 0, "name": "bricks", "kind": "textured", "collaborative": true, "why": "..."}, ...],
     "views": {"train": ["train_000.png", ...], "test": ["test_000.png", ...]}}

``units`` must be ``"m"`` (the toolkit's internal unit, see DESIGN.md); a missing ``units`` means metres.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from types import MappingProxyType
from typing import Any

from core.errors import FormatError, InputFileError

SCENE_FILE_NAME = "scene.json"


@dataclass(frozen=True)
class MaterialEntry:
    """One entry of the materials legend: the integer id used in label maps and LiDAR ``material`` fields."""

    id: int
    name: str
    kind: str  # e.g. "textured", "mirror", "glass", "metal", "textureless", "thin"
    collaborative: bool  # True where MVS can be trusted (textured, view-independent, thick surfaces)
    why: str = ""


@dataclass(frozen=True)
class SceneDescription:
    """A parsed ``scene.json``.

    origin: world coordinates (metres, float64) of the local frame every file of the scene is written in.
    gsd_m: ground-sample distance of the training views (metres per pixel at the median depth), or None.
    splits: split name -> image names (``train``, ``test``); empty when the file lists none.
    extra: the other keys of the file, read-only (rig, statistics, ...).
    """

    path: Path
    units: str = "m"
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gsd_m: float | None = None
    crs: str | None = None
    preset: str | None = None
    seed: int | None = None
    materials: tuple[MaterialEntry, ...] = ()
    splits: Mapping[str, tuple[str, ...]] = field(default_factory=lambda: MappingProxyType({}))
    extra: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}), repr=False)

    def material_ids(self, collaborative: bool | None = None) -> tuple[int, ...]:
        """Ids of the legend's materials, optionally only the (non-)collaborative ones."""
        return tuple(m.id for m in self.materials if collaborative is None or m.collaborative == collaborative)

    @property
    def non_collaborative_ids(self) -> tuple[int, ...]:
        return self.material_ids(collaborative=False)

    def material(self, material_id: int) -> MaterialEntry:
        """The legend entry of ``material_id``; KeyError when the legend has none."""
        for m in self.materials:
            if m.id == material_id:
                return m
        raise KeyError(material_id)


_KNOWN = ("units", "origin", "gsd_m", "crs", "preset", "seed", "materials", "views")


def _bad(problem: str, path: Path) -> FormatError:
    return FormatError(f"{SCENE_FILE_NAME} is not valid: {problem}", path)


def _finite(value: Any, what: str, path: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _bad(f"{what} must be a number, got {value!r}", path)
    if not math.isfinite(float(value)):
        raise _bad(f"{what} must be finite, got {value!r}", path)
    return float(value)


def _material(entry: Any, index: int, path: Path) -> MaterialEntry:
    where = f"materials[{index}]"
    if not isinstance(entry, dict):
        raise _bad(f"{where} must be an object, got {type(entry).__name__}", path)
    for key in ("id", "name", "kind", "collaborative"):
        if key not in entry:
            raise _bad(f"{where} lacks '{key}'", path)
    mid = entry["id"]
    if isinstance(mid, bool) or not isinstance(mid, int) or not 0 <= mid <= 254:
        raise _bad(f"{where}.id must be an integer in 0..254 (255 = background), got {mid!r}", path)
    if not isinstance(entry["collaborative"], bool):
        raise _bad(f"{where}.collaborative must be true or false, got {entry['collaborative']!r}", path)
    why = str(entry.get("why", ""))
    return MaterialEntry(int(mid), str(entry["name"]), str(entry["kind"]), entry["collaborative"], why)


def parse_scene_description(data: Any, path: str | PathLike[str]) -> SceneDescription:
    """Validate a decoded ``scene.json`` object; ``path`` names the file in errors."""
    path = Path(path)
    if not isinstance(data, dict):
        raise _bad(f"expected a JSON object, got {type(data).__name__}", path)
    units = data.get("units", "m")
    if units != "m":
        raise _bad(f"units must be 'm' (scenes are written in metres), got {units!r}", path)
    origin_raw = data.get("origin", [0.0, 0.0, 0.0])
    if not isinstance(origin_raw, list) or len(origin_raw) != 3:
        raise _bad(f"origin must be a list of 3 numbers, got {origin_raw!r}", path)
    origin = tuple(_finite(v, "origin", path) for v in origin_raw)
    gsd = data.get("gsd_m")
    gsd_m = None if gsd is None else _finite(gsd, "gsd_m", path)
    if gsd_m is not None and gsd_m <= 0:
        raise _bad(f"gsd_m must be > 0, got {gsd_m!r}", path)
    crs = data.get("crs")
    if crs is not None and not isinstance(crs, str):
        raise _bad(f"crs must be a string such as 'EPSG:32632', got {crs!r}", path)
    seed = data.get("seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
        raise _bad(f"seed must be an integer, got {seed!r}", path)
    mats_raw = data.get("materials", [])
    if not isinstance(mats_raw, list):
        raise _bad("materials must be a list", path)
    materials = tuple(_material(m, i, path) for i, m in enumerate(mats_raw))
    ids = [m.id for m in materials]
    if len(set(ids)) != len(ids):
        raise _bad(f"materials repeat an id ({sorted(i for i in set(ids) if ids.count(i) > 1)})", path)
    views = data.get("views", {})
    if not isinstance(views, dict):
        raise _bad("views must be an object {split: [image names]}", path)
    splits: dict[str, tuple[str, ...]] = {}
    for split, names in views.items():
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise _bad(f"views.{split} must be a list of image names", path)
        splits[str(split)] = tuple(names)
    preset = data.get("preset")
    return SceneDescription(
        path=path,
        units="m",
        origin=origin,  # type: ignore[arg-type]
        gsd_m=gsd_m,
        crs=crs,
        preset=None if preset is None else str(preset),
        seed=seed,
        materials=materials,
        splits=MappingProxyType(splits),
        extra=MappingProxyType({k: v for k, v in data.items() if k not in _KNOWN}),
    )


def read_scene_description(path: str | PathLike[str]) -> SceneDescription:
    """Read ``scene.json`` (or a folder holding one). Raises InputFileError / FormatError naming the file."""
    path = Path(path)
    if path.is_dir():
        path = path / SCENE_FILE_NAME
    if not path.is_file():
        raise InputFileError(f"{SCENE_FILE_NAME} does not exist", path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as err:
        raise InputFileError(f"cannot read {SCENE_FILE_NAME} ({err})", path) from err
    except json.JSONDecodeError as err:
        raise FormatError(f"{SCENE_FILE_NAME} is not valid JSON ({err})", path) from err
    return parse_scene_description(data, path)
