"""Typed records stored as JSON: a stage's result (:class:`hybridsplat.stages.base.StageResult`) and the small
records inside it or passed between the tile modules.

A record is a frozen dataclass subclassing :class:`TypedRecord`, every field with a type hint and a default. Its
JSON (:meth:`TypedRecord.as_dict`, which :func:`core.io.json_io.to_jsonable` writes) holds each field by name, in
declaration order, except a field declared with :func:`omitted_if_none` while it is None (what only some runs
have: a streamed path's memory, a tiled run's tiles). :meth:`TypedRecord.from_json` reads it back tolerantly: a key
it does not know is ignored and a missing one takes its default, so a manifest written by an earlier (or later)
version still reads; a value of the wrong type is a :class:`~core.errors.FormatError` naming the file and the key.

On construction every value is normalised to its declared type: a list to a tuple, a mapping to a nested record
(or any dataclass), numpy scalars to Python numbers, an int to a float, and JSON's null to NaN for a plain ``float``
(:func:`~core.io.json_io.to_jsonable` writes NaN as null). So the record a stage returns and the same record read
back from the manifest are equal, and a stage that passes a value of another type fails at once (``TypeError``
naming the field) instead of writing it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import types
import typing
from collections.abc import Mapping
from enum import Enum
from os import PathLike
from pathlib import PurePath
from typing import Any, TypeVar

import numpy as np

from core.errors import FormatError

_OMIT = "omit_if_none"
R = TypeVar("R", bound="TypedRecord")


def omitted_if_none(default: Any = None) -> Any:
    """A field left out of the record's JSON while it is None (``default``: None)."""
    return dataclasses.field(default=default, metadata={_OMIT: True})


@dataclasses.dataclass(frozen=True)
class TypedRecord:
    """Base of the typed records (see the module docstring)."""

    def __post_init__(self) -> None:
        for name, tp in _field_types(type(self)).items():
            object.__setattr__(self, name, _convert(tp, getattr(self, name), name))

    def as_dict(self) -> dict[str, Any]:
        """The record as JSON data: every field by name, the :func:`omitted_if_none` ones only when set."""
        from core.io.json_io import to_jsonable

        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is None and f.metadata.get(_OMIT):
                continue
            out[f.name] = to_jsonable(value)
        return out

    @classmethod
    def from_json(cls: type[R], data: Any, where: str | PathLike[str] | None = None, key: str = "") -> R:
        """The record from JSON data (``None``: every default); unknown keys ignored, missing ones defaulted.

        where: the file the data came from, named in the :class:`FormatError` of a value of the wrong type, with
        ``key`` (the data's place in it, e.g. ``stages.sfm.counts``)."""
        if data is None:
            data = {}
        try:
            return _from_mapping(cls, data, key)
        except (TypeError, ValueError) as err:
            raise FormatError(str(err), where) from err


@functools.cache
def _field_types(cls: type) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls) if f.init}


def _from_mapping(cls: type, data: Any, key: str) -> Any:
    if not isinstance(data, Mapping):
        raise TypeError(f"{key or cls.__name__} must be an object, got {type(data).__name__} {data!r}")
    known = _field_types(cls)
    values = {name: _convert(tp, data[name], _join(key, name)) for name, tp in known.items() if name in data}
    missing = [
        f.name
        for f in dataclasses.fields(cls)
        if f.init and f.name not in values
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise TypeError(f"{key or cls.__name__} has no {', '.join(repr(m) for m in missing)}")
    return cls(**values)


def _join(key: str, name: str) -> str:
    return f"{key}.{name}" if key else name


def _convert(tp: Any, value: Any, key: str) -> Any:
    """``value`` as type ``tp`` (see the module docstring); TypeError naming ``key`` when it is not one."""
    if tp is Any:
        return value
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        errors = []
        for choice in (a for a in args if a is not type(None)):
            try:
                return _convert(choice, value, key)
            except (TypeError, ValueError) as err:
                errors.append(err)
        raise errors[0] if len(errors) == 1 else TypeError(f"{key}: {value!r} is none of {tp}")
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return value if isinstance(value, tp) else _from_mapping(tp, value, key)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise TypeError(f"{key} must be a list, got {type(value).__name__} {value!r}")
        args = typing.get_args(tp)
        types_ = [args[0]] * len(value) if len(args) == 2 and args[1] is Ellipsis else list(args)
        if len(types_) != len(value):
            raise TypeError(f"{key} must be a list of {len(types_)} values, got {value!r}")
        return tuple(_convert(t, v, f"{key}[{k}]") for k, (t, v) in enumerate(zip(types_, value, strict=True)))
    if origin is list:
        if not isinstance(value, (list, tuple)):
            raise TypeError(f"{key} must be a list, got {type(value).__name__} {value!r}")
        (item,) = typing.get_args(tp) or (Any,)
        return [_convert(item, v, f"{key}[{k}]") for k, v in enumerate(value)]
    if origin in (dict, Mapping) or tp in (dict, Mapping):
        if not isinstance(value, Mapping):
            raise TypeError(f"{key} must be an object, got {type(value).__name__} {value!r}")
        _, item = typing.get_args(tp) or (str, Any)
        return {str(k): _convert(item, v, f"{key}.{k}") for k, v in value.items()}
    return _scalar(tp, value, key)


def _scalar(tp: Any, value: Any, key: str) -> Any:
    if tp is bool:
        if isinstance(value, (bool, np.bool_)):
            return bool(value)
    elif tp is int:
        if isinstance(value, numbers.Integral) and not isinstance(value, bool):
            return int(value)
    elif tp is float:
        if value is None:
            return math.nan  # to_jsonable writes NaN as null
        if isinstance(value, numbers.Real) and not isinstance(value, bool):
            return float(value)
    elif tp is str:
        if isinstance(value, (str, PurePath)):
            return str(value)
    elif isinstance(tp, type) and issubclass(tp, Enum):
        return tp(value)
    elif isinstance(tp, type) and isinstance(value, tp):
        return value
    name = getattr(tp, "__name__", str(tp))
    raise TypeError(f"{key} must be {name}, got {type(value).__name__} {value!r}")
