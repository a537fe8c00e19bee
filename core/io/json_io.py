"""The project's one JSON writer and reader.

``to_jsonable`` turns dataclasses, numpy scalars and arrays, paths and enums into plain JSON data, and NaN/±inf
into ``null``: a bare ``NaN`` or ``Infinity`` is not JSON, and other tools refuse such files.
"""

from __future__ import annotations

import json
import math
from dataclasses import fields, is_dataclass
from enum import Enum
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import FormatError, InputFileError
from core.io.atomic import write_text_atomic


def to_jsonable(value: Any) -> Any:
    """Plain JSON data (dict, list, str, int, float, bool, None) from ``value``; non-finite floats become None."""
    if isinstance(value, Enum):
        return to_jsonable(value.value)
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, PathLike):
        return str(value)
    if is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_jsonable(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, dict):
        return {str(k.value if isinstance(k, Enum) else k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [to_jsonable(v) for v in value]
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def dumps(value: Any, indent: int | None = 2) -> str:
    """Strict JSON text of ``value`` (see :func:`to_jsonable`)."""
    return json.dumps(to_jsonable(value), indent=indent, allow_nan=False)


def write_json_atomic(path: str | PathLike[str], value: Any) -> Path:
    """Write ``value`` as strict JSON to ``path`` atomically; returns the path."""
    write_text_atomic(path, dumps(value) + "\n")
    return Path(path)


def read_json(path: str | PathLike[str]) -> Any:
    """Parsed JSON of ``path``; a missing, unreadable or invalid file is an error naming it."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError) as err:
        raise InputFileError("missing or not a file", path) from err
    except (OSError, UnicodeDecodeError) as err:
        raise InputFileError(f"cannot read ({err})", path) from err
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except ValueError as err:
        raise FormatError(f"not valid JSON ({err})", path) from err


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not JSON")
