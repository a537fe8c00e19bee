"""The local-origin sidecar ``<name>.origin.json`` written next to PLY files.

PLY payloads are float32 (or float64) in a local frame; the sidecar holds the float64 world offset so that
georeferenced data keeps its coordinates: ``world = origin + local``. Format::

    {"origin": [x, y, z], "units": "m", "crs": null}
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import DataError, FormatError, InputFileError
from core.io.atomic import remove_output
from core.io.json_io import read_json, write_json_atomic

#: Largest origin coordinate accepted (metres): above every projected or geocentric CRS (~1e7 m), far
#: below values whose float64 spacing exceeds a millimetre (~1e13 m).
MAX_ORIGIN = 1e9


def sidecar_path(path: str | PathLike[str]) -> Path:
    """``scene.ply`` -> ``scene.origin.json`` (same folder)."""
    p = Path(path)
    return p.with_name(p.stem + ".origin.json")


def write_origin(
    path: str | PathLike[str], origin: np.ndarray, crs: str | None = None, layers: dict[str, int] | None = None
) -> Path:
    """Write the sidecar for data file ``path``; returns the sidecar's path. ``layers``: the names of the ``source``
    codes the file holds (a merged product: ``{"survey": 1, "fill": 2, "background": 3}``), written as is."""
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    if not np.isfinite(origin).all():
        raise DataError(f"origin must be finite, got {origin.tolist()}", path)
    side = sidecar_path(path)
    # repr of a Python float round-trips float64 exactly.
    payload: dict = {"origin": [float(v) for v in origin], "units": "m", "crs": crs}
    if layers is not None:
        payload["layers"] = {str(k): int(v) for k, v in layers.items()}
    return write_json_atomic(side, payload)


def read_origin(path: str | PathLike[str]) -> np.ndarray:
    """The origin recorded next to data file ``path``; zeros when there is no sidecar."""
    side = sidecar_path(path)
    if not side.exists():
        return np.zeros(3)
    payload = read_json(side)  # names the sidecar on folders, bad JSON, bare NaN
    values = payload.get("origin") if isinstance(payload, dict) else None
    if (
        not isinstance(values, list)
        or len(values) != 3
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    ):
        found = str(payload)[:60]
        raise FormatError(f"origin sidecar must hold {{'origin': [x, y, z]}} (numbers), found {found}", side)
    origin = np.asarray(values, dtype=np.float64)
    if not np.isfinite(origin).all() or np.abs(origin).max() > MAX_ORIGIN:
        raise FormatError(f"origin {origin.tolist()} is not finite or beyond {MAX_ORIGIN:g} m", side)
    return origin


def read_crs(path: str | PathLike[str]) -> str | None:
    """The CRS recorded next to data file ``path`` (e.g. ``"EPSG:32633"``); None without a sidecar or a CRS."""
    side = sidecar_path(path)
    if not side.exists():
        return None
    payload = read_json(side)
    crs = payload.get("crs") if isinstance(payload, dict) else None
    if crs is not None and not isinstance(crs, str):
        raise FormatError(f"origin sidecar 'crs' must be a string or null, found {str(crs)[:60]}", side)
    return crs or None


def remove_origin(path: str | PathLike[str]) -> None:
    """Remove a stale sidecar (when a file is rewritten without an origin)."""
    side = sidecar_path(path)
    if side.is_dir():
        raise InputFileError("is a folder, expected an origin sidecar file (or nothing)", side)
    remove_output(side)
