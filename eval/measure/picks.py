"""The PICKS.json format: points picked as pixels in named images, and the distances wanted between them.

Format (UTF-8 JSON)::

    {
      "sigma_px": 0.5,                       # optional: default σ of every pick in pixels (default 1.0)
      "points": [
        {"id": "P1",                         # a unique label
         "picks": [
            {"image": "0001.png", "u": 153.2, "v": 88.9},
            {"image": "0007.png", "u": 201.7, "v": 95.1, "sigma_px": 0.8}   # optional per-pick σ
         ]},
        ...
      ],
      "distances": [["P1", "P2"], ...]       # optional: pairs of point ids
    }

``image`` is the image name as in the COLMAP model (``images.bin``); ``u``, ``v`` are COLMAP pixel
coordinates in the original (distorted) photo: x to the right, y down, the centre of the top-left pixel
at (0.5, 0.5); so the centre of pixel column ``c``, row ``r`` is ``(c + 0.5, r + 0.5)``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

from core.cameras import Cameras
from core.errors import DataError, FormatError, InputFileError
from core.io.atomic import write_text_atomic
from eval.measure.triangulate import Pick


@dataclass(frozen=True)
class ImagePick:
    """One pick: image name, COLMAP pixel coordinates (u right, v down) and σ in pixels."""

    image: str
    u: float
    v: float
    sigma_px: float


@dataclass(frozen=True)
class PointPicks:
    """All picks of one point."""

    id: str
    picks: tuple[ImagePick, ...]


@dataclass(frozen=True)
class PicksFile:
    """The content of a PICKS.json file."""

    points: tuple[PointPicks, ...]
    distances: tuple[tuple[str, str], ...] = ()


def _number(value: object, what: str, path: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FormatError(f"{what} must be a number, got {value!r}", path)
    return float(value)


def parse_picks(payload: object, path: str | PathLike[str] = "PICKS.json") -> PicksFile:
    """Validate a decoded PICKS.json payload; :class:`FormatError` names what is wrong and where."""
    path = Path(path)
    if not isinstance(payload, dict) or not isinstance(payload.get("points"), list):
        raise FormatError('expected an object with a "points" list (see eval.measure.picks for the format)', path)
    default_sigma = _number(payload.get("sigma_px", 1.0), '"sigma_px"', path)
    points: list[PointPicks] = []
    ids: set[str] = set()
    for i, entry in enumerate(payload["points"]):
        if not isinstance(entry, dict) or not isinstance(entry.get("picks"), list):
            raise FormatError(f'points[{i}] must be an object with "id" and a "picks" list', path)
        pid = str(entry.get("id", f"P{i + 1}"))
        if pid in ids:
            raise FormatError(f"point id {pid!r} appears twice", path)
        ids.add(pid)
        picks = []
        for j, pick in enumerate(entry["picks"]):
            where = f"points[{i}] ({pid}) picks[{j}]"
            if not isinstance(pick, dict) or not isinstance(pick.get("image"), str):
                raise FormatError(f'{where} must be an object with "image", "u", "v"', path)
            sigma = _number(pick.get("sigma_px", default_sigma), f"{where}.sigma_px", path)
            u = _number(pick.get("u"), f"{where}.u", path)
            v = _number(pick.get("v"), f"{where}.v", path)
            picks.append(ImagePick(pick["image"], u, v, sigma))
        points.append(PointPicks(pid, tuple(picks)))
    distances = []
    for k, pair in enumerate(payload.get("distances", [])):
        if not (isinstance(pair, list) and len(pair) == 2):
            raise FormatError(f"distances[{k}] must be a pair of point ids, got {pair!r}", path)
        a, b = str(pair[0]), str(pair[1])
        for pid in (a, b):
            if pid not in ids:
                raise FormatError(f"distances[{k}] names point {pid!r}, which is not among the points", path)
        distances.append((a, b))
    return PicksFile(tuple(points), tuple(distances))


def read_picks(path: str | PathLike[str]) -> PicksFile:
    """Read and validate a PICKS.json file."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError("picks file does not exist", path)
    try:
        payload = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise FormatError(f"not valid JSON ({err})", path) from err
    return parse_picks(payload, path)


def picks_to_payload(picks: PicksFile) -> dict:
    """The JSON payload of a :class:`PicksFile` (inverse of :func:`parse_picks`)."""
    return {
        "points": [
            {
                "id": p.id,
                "picks": [{"image": q.image, "u": q.u, "v": q.v, "sigma_px": q.sigma_px} for q in p.picks],
            }
            for p in picks.points
        ],
        "distances": [list(pair) for pair in picks.distances],
    }


def write_picks(path: str | PathLike[str], picks: PicksFile) -> None:
    """Write a PICKS.json file atomically."""
    write_text_atomic(path, json.dumps(picks_to_payload(picks), indent=2) + "\n")


def resolve(point: PointPicks, cameras: Cameras, source: str | PathLike[str] | None = None) -> list[Pick]:
    """The picks of one point bound to the cameras of a model; :class:`DataError` for unknown images."""
    by_name = {v.name: v for v in cameras}
    out = []
    for q in point.picks:
        view = by_name.get(q.image)
        if view is None:
            raise DataError(
                f"point {point.id!r}: image {q.image!r} is not in the camera model ({len(by_name)} images)", source
            )
        out.append(Pick(cameras.camera_of(view), view, (q.u, q.v), q.sigma_px))
    return out
