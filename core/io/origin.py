"""The local-origin sidecar ``<name>.origin.json`` written next to PLY files.

PLY payloads are float32 (or float64) in a local frame; the sidecar holds the float64 world offset so that
georeferenced data keeps its coordinates: ``world = origin + local``. Format::

    {"origin": [x, y, z], "units": "m", "crs": null}
"""

from __future__ import annotations

import json
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import FormatError
from core.io.atomic import write_text_atomic


def sidecar_path(path: str | PathLike[str]) -> Path:
    """``scene.ply`` -> ``scene.origin.json`` (same folder)."""
    p = Path(path)
    return p.with_name(p.stem + ".origin.json")


def write_origin(path: str | PathLike[str], origin: np.ndarray, crs: str | None = None) -> Path:
    """Write the sidecar for data file ``path``; returns the sidecar's path."""
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    side = sidecar_path(path)
    # repr of a Python float round-trips float64 exactly.
    payload = {"origin": [float(v) for v in origin], "units": "m", "crs": crs}
    write_text_atomic(side, json.dumps(payload, indent=2) + "\n")
    return side


def read_origin(path: str | PathLike[str]) -> np.ndarray:
    """The origin recorded next to data file ``path``; zeros when there is no sidecar."""
    side = sidecar_path(path)
    if not side.exists():
        return np.zeros(3)
    try:
        payload = json.loads(side.read_text(encoding="utf-8"))
        origin = np.asarray(payload["origin"], dtype=np.float64).reshape(3)
    except (ValueError, KeyError, TypeError) as err:
        raise FormatError(f"origin sidecar is not valid ({err}); expected {{'origin': [x, y, z]}}", side) from err
    if not np.isfinite(origin).all():
        raise FormatError("origin sidecar holds non-finite values", side)
    return origin


def remove_origin(path: str | PathLike[str]) -> None:
    """Remove a stale sidecar (when a file is rewritten without an origin)."""
    sidecar_path(path).unlink(missing_ok=True)
