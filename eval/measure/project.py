"""What a measurement needs from a project: cameras, the local origin, the unit and the CRS.

The cameras are a COLMAP model (local frame); the origin / unit / CRS come from the ``<name>.origin.json``
sidecar of a data file (``{"origin": [x, y, z], "units": "m", "crs": "EPSG:…" | null}``, :mod:`core.io.origin`),
in a project the merged product's. The application passes the paths (it alone knows the project layout).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from os import PathLike

import numpy as np

from core.cameras import Cameras
from core.errors import DataError, FormatError
from core.io.origin import read_origin, sidecar_path
from eval.measure.export import Measurements, measurements_from
from eval.measure.picks import PicksFile, resolve
from eval.measure.triangulate import MeasuredPoint, TriangulationOptions, triangulate


@dataclass(frozen=True)
class Georeference:
    """origin: (3,) float64 world coordinates of the local frame; unit: linear unit; crs: CRS string or None."""

    origin: np.ndarray
    unit: str = "m"
    crs: str | None = None


def read_georeference(data_file: str | PathLike[str]) -> Georeference:
    """Origin, unit and CRS from the ``<name>.origin.json`` sidecar of ``data_file`` (zeros, m, None without one)."""
    origin = read_origin(data_file)
    side = sidecar_path(data_file)
    unit, crs = "m", None
    if side.exists():
        try:
            payload = json.loads(side.read_text(encoding="utf-8"))
        except ValueError as err:
            raise FormatError(f"origin sidecar is not valid JSON ({err})", side) from err
        unit = str(payload.get("units") or "m")
        crs = payload.get("crs") or None
        if crs is not None and not isinstance(crs, str):
            raise FormatError(f'"crs" must be a string such as "EPSG:32632" or null, got {crs!r}', side)
    return Georeference(origin, unit, crs)


def read_cameras(sparse_dir: str | PathLike[str]) -> Cameras:
    """The cameras of a COLMAP model folder (local frame)."""
    from core.io.colmap import read_model

    cameras, _points = read_model(sparse_dir)
    if len(cameras) == 0:
        raise DataError("the COLMAP model has no registered images", sparse_dir)
    return cameras


def measure_picks(
    picks: PicksFile,
    cameras: Cameras,
    georef: Georeference,
    options: TriangulationOptions = TriangulationOptions(),
    source: str | PathLike[str] | None = None,
    on_error: Callable[[str, Exception], None] | None = None,
) -> Measurements:
    """Triangulate every point of a picks file and the distances it asks for.

    A degenerate point raises :class:`DataError` (naming ``source``) unless ``on_error`` is given, in which
    case it is called with the point id and the error and the point is left out (distances that need it too).
    """
    points: list[MeasuredPoint] = []
    for point in picks.points:
        try:
            points.append(triangulate(resolve(point, cameras, source), georef.origin, options, point.id))
        except DataError as err:
            if on_error is None:
                raise DataError(err.problem, source or err.path) from None
            on_error(point.id, err)
    measured = {p.name for p in points}
    pairs = [(a, b) for a, b in picks.distances if a in measured and b in measured]
    if len(pairs) != len(picks.distances) and on_error is not None:
        on_error("distances", DataError(f"{len(picks.distances) - len(pairs)} distance(s) skipped: a point failed"))
    return measurements_from(points, pairs, georef.unit, georef.crs)
