"""The project's one JSON reader and writer.

Every JSON file the toolkit writes (metrics, reports, manifests, sidecars, scene descriptions) goes
through :func:`write_json_atomic`, so that no file ever holds bare ``NaN``/``Infinity`` (invalid JSON
for every other tool) and no reader ever sees a half-written file. :func:`read_json` turns bad JSON
into a :class:`~core.errors.FormatError` naming the file.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
from collections.abc import Mapping
from os import PathLike
from pathlib import Path, PurePath
from typing import Any

import numpy as np

from core.errors import FormatError, InputFileError
from core.io.atomic import write_text_atomic


def to_jsonable(obj: Any) -> Any:
    """A copy of ``obj`` made of JSON types only (dict with str keys, list, str, int, float, bool, None).

    Converts dataclasses (field by field), objects with an ``as_dict()`` method, mappings, lists,
    tuples and sets, numpy scalars and arrays, paths (to ``str``), enums (to their value) and bytes
    (UTF-8 text). Non-finite floats (NaN, ±inf) become ``None``: the written JSON is valid for every
    reader, and a missing value is explicit. Raises :class:`TypeError` for anything else.
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, enum.Enum):
        return to_jsonable(obj.value)
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, PurePath):
        return str(obj)
    if isinstance(obj, (bytes, bytearray)):
        return bytes(obj).decode("utf-8", errors="replace")
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        as_dict = getattr(obj, "as_dict", None)
        if callable(as_dict):
            return to_jsonable(as_dict())
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, Mapping):
        return {_key(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return [to_jsonable(v) for v in sorted(obj, key=repr)]
    as_dict = getattr(obj, "as_dict", None)
    if callable(as_dict):
        return to_jsonable(as_dict())
    raise TypeError(f"cannot write {type(obj).__name__} as JSON")


def _key(key: Any) -> str:
    if isinstance(key, enum.Enum):
        key = key.value
    if isinstance(key, np.generic):
        key = key.item()
    return str(key)


def dumps_json(obj: Any, indent: int | None = 2) -> str:
    """``obj`` as strict JSON text (see :func:`to_jsonable`); never contains ``NaN`` or ``Infinity``."""
    return json.dumps(to_jsonable(obj), indent=indent, allow_nan=False)


def write_json_atomic(path: str | PathLike[str], obj: Any, indent: int | None = 2) -> Path:
    """Write ``obj`` as strict JSON (plus a final newline) to ``path`` atomically. Returns the path."""
    path = Path(path)
    write_text_atomic(path, dumps_json(obj, indent=indent) + "\n")
    return path


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON")


def read_json(path: str | PathLike[str]) -> Any:
    """Read a JSON file (a dict or a list, usually).

    Raises :class:`~core.errors.InputFileError` when the path is missing or is a folder, and
    :class:`~core.errors.FormatError` when the content is not UTF-8 or not strict JSON (bare ``NaN``
    and ``Infinity`` are refused); both name the file.
    """
    p = Path(path)
    if p.is_dir():
        raise InputFileError("is a folder, expected a JSON file", p)
    if not p.is_file():
        raise InputFileError("file does not exist", p)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise FormatError(f"not UTF-8 text (byte {err.start})", p) from err
    except OSError as err:
        raise InputFileError(f"cannot read ({err.strerror or err})", p) from err
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except ValueError as err:
        raise FormatError(f"not valid JSON ({err})", p) from err
    except RecursionError as err:
        raise FormatError("JSON nested too deeply", p) from err


def read_json_object(path: str | PathLike[str]) -> dict[str, Any]:
    """:func:`read_json`, and the top level must be an object."""
    data = read_json(path)
    if not isinstance(data, dict):
        raise FormatError(f"expected a JSON object at the top level, found {type(data).__name__}", path)
    return data
