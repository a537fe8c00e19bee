"""Options dataclasses ⇄ TOML tables: the one place that reads and writes a stage's options.

A stage's options are the domain's own options dataclass (``classify.masks.MaskOptions``, ``fusion.clean.CleanOptions``,
``recon.mvs.MvsOptions`` ...) or a small dataclass composing them, so every option has one definition and one
default. This module turns such a dataclass into TOML-ready data and back, driven by its type hints:

- ``bool``, ``int``, ``float``, ``str``, ``Enum`` (by value), ``tuple[T, ...]`` (a TOML array) and nested
  dataclasses (a TOML sub-table ``[stage.field]``);
- ``X | None``: ``None`` is written and read as the string ``"none"`` (``"off"`` is read too), because TOML has
  no null: ``max_scale_spacing = "none"`` turns that check off;
- fields the pipeline sets itself (the seed, the held-out photos...) are not configuration: a domain class marks
  them with :func:`core.options.runtime_field`, or a composing class lists a nested class's
  ones in its field's ``metadata={"runtime": ("seed", ...)}``. They are neither written nor read nor compared.

A nested table given in part keeps the composing class's default for the rest (``[train.training]`` with only
``iterations`` keeps the train stage's snapshot steps, not ``TrainOptions``'s).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from enum import Enum
from pathlib import Path
from typing import Any

from core.constraints import ConstraintError
from core.errors import ConfigError
from core.options import runtime_field

__all__ = [
    "options_digest",
    "options_from_table",
    "options_to_data",
    "options_with",
    "runtime_field",
    "toml_tables",
    "with_option",
    "with_options",
]

#: how ``None`` is spelled in config.toml (read case-insensitively, with "off")
NONE_SPELLING = "none"
NONE_WORDS = ("none", "off")  # read as None (case-insensitive)


def configurable_fields(options_type: type, runtime: tuple[str, ...] = ()) -> list[dataclasses.Field]:
    """The fields of ``options_type`` that config.toml holds (runtime fields and ``runtime`` names left out)."""
    return [
        f
        for f in dataclasses.fields(options_type)
        if f.init and f.metadata.get("runtime") is not True and f.name not in runtime
    ]


def _child_runtime(f: dataclasses.Field) -> tuple[str, ...]:
    value = f.metadata.get("runtime")
    return tuple(value) if isinstance(value, (tuple, list)) else ()


def _hints(options_type: type) -> dict[str, Any]:
    return typing.get_type_hints(options_type)


def _is_union(tp: Any) -> bool:
    return typing.get_origin(tp) in (typing.Union, types.UnionType)


# ----------------------------------------------------------------------------------------------------------- write


def options_to_data(options: Any, runtime: tuple[str, ...] = ()) -> dict[str, Any]:
    """The configurable fields of an options dataclass as plain data (nested dicts, lists, strings for enums and
    ``"none"`` for None): what config.toml holds and what the manifest compares."""
    data: dict[str, Any] = {}
    hints = _hints(type(options))
    for f in configurable_fields(type(options), runtime):
        value = getattr(options, f.name)
        data[f.name] = _value_to_data(value, hints[f.name], _child_runtime(f))
    return data


def _value_to_data(value: Any, tp: Any, runtime: tuple[str, ...]) -> Any:
    if value is None:
        return NONE_SPELLING
    if dataclasses.is_dataclass(value):
        return options_to_data(value, runtime)
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, (tuple, list, frozenset, set)):  # nested sequences (pairs) become nested TOML arrays
        return [_value_to_data(v, None, runtime) if isinstance(v, (tuple, list, Enum)) else v for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def options_digest(options: Any) -> dict[str, Any]:
    """Options as plain JSON data, the form recorded and compared in the manifest ({} for none)."""
    if options is None or not dataclasses.is_dataclass(options):
        return {}
    return options_to_data(options)


def toml_tables(name: str, options: Any) -> list[str]:
    """Lines of the TOML table ``[name]`` (and its sub-tables) holding ``options``."""
    return _toml_tables(name, options_to_data(options))


def _toml_tables(name: str, data: dict[str, Any]) -> list[str]:
    lines = [f"[{name}]"]
    nested = []
    for key, value in data.items():
        if isinstance(value, dict):
            nested.append((key, value))
        else:
            lines.append(f"{key} = {_toml_value(value)}")
    lines.append("")
    for key, value in nested:
        lines += _toml_tables(f"{name}.{key}", value)
    return lines


def _toml_value(value: Any) -> str:
    import json

    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return json.dumps(str(value))


# ------------------------------------------------------------------------------------------------------------ read


def options_from_table(
    options_type: type,
    table: dict[str, Any],
    where: Path | str,
    base: Any = None,
    prefix: str = "",
    runtime: tuple[str, ...] = (),
) -> Any:
    """Options of ``options_type`` from a TOML table: ``base`` (default: the type's defaults) with the table's values;
    ``runtime`` names fields that the composing class sets itself (not options: unknown here).

    Unknown keys, wrong types and values the dataclass refuses are a :class:`ConfigError` naming the option
    (``prefix`` + key, e.g. ``training.iterations``) and ``where`` (the file, or ``--options``); a value outside
    its declared constraint (:mod:`core.constraints`) reads ``option training.iterations must be ..., got ...``."""
    if not isinstance(table, dict):
        raise ConfigError(f"option {prefix.rstrip('.') or 'table'} must be a table, got {table!r}", where)
    try:
        base = options_type() if base is None else base
    except ConstraintError as err:
        raise err.renamed(prefix, where) from err
    except ConfigError as err:
        raise ConfigError(err.problem, where) from err
    known = {f.name: f for f in configurable_fields(options_type, runtime)}
    _refuse_removed(options_type, table, where, prefix)
    unknown = sorted(set(table) - set(known))
    if unknown:
        spelled = ", ".join(prefix + k for k in unknown)
        raise ConfigError(f"unknown option(s) {spelled} (known: {', '.join(sorted(known))})", where)
    hints = _hints(options_type)
    values = {}
    declared = getattr(options_type, "constraints", {})
    for key, value in table.items():
        child_runtime = _child_runtime(known[key])
        try:
            values[key] = _value_from_data(hints[key], value, getattr(base, key), where, prefix + key, child_runtime)
        except ConfigError as err:  # a wrong type for a declared option: the declaration's message
            if key not in declared or isinstance(err, ConstraintError):
                raise
            raise ConstraintError(prefix + key, value, declared[key].description, where) from err
    try:
        return dataclasses.replace(base, **values)
    except ConstraintError as err:  # a declared constraint: named by its dotted path
        raise err.renamed(prefix, where) from err
    except ConfigError as err:
        raise ConfigError(f"{prefix.rstrip('.') + ': ' if prefix else ''}{err.problem}", where) from err
    except (TypeError, ValueError) as err:
        raise ConfigError(str(err), where) from err


def _refuse_removed(options_type: type, table: dict[str, Any], where: Path | str, prefix: str) -> None:
    """A :class:`ConfigError` naming the first key of ``table`` that sets an option or a value a version removed
    (:data:`hybridsplat.config_migration.REMOVED_VALUES`)."""
    from hybridsplat.config_migration import removed_setting

    for key, value in table.items():
        entry = removed_setting(options_type, key, value)
        if entry is not None:
            raise ConfigError(entry.message(prefix), where)


def _value_from_data(tp: Any, value: Any, base: Any, where: Path | str, key: str, runtime: tuple[str, ...]) -> Any:
    if _is_union(tp):
        args = typing.get_args(tp)
        optional = type(None) in args
        if optional and isinstance(value, str) and value.lower() in NONE_WORDS:
            return None
        choices = [a for a in args if a is not type(None)]
        if len(choices) == 1:
            return _value_from_data(choices[0], value, base, where, key, runtime)
        return _union_from_data(choices, value, base, where, key)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f'option {key} must be a table ([...{key}]) or "none", got {value!r}', where)
        child_base = base if isinstance(base, tp) else None
        return options_from_table(tp, value, where, child_base, prefix=key + ".", runtime=runtime)
    if isinstance(tp, type) and issubclass(tp, Enum):
        try:
            return tp(value)
        except ValueError as err:
            allowed = ", ".join(str(m.value) for m in tp)
            raise ConfigError(f"option {key} must be one of {allowed}, got {value!r}", where) from err
    if typing.get_origin(tp) is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"option {key} must be a list, got {value!r}", where)
        args = typing.get_args(tp)
        item_types = [args[0]] * len(value) if len(args) == 2 and args[1] is Ellipsis else list(args)
        if len(item_types) != len(value):
            raise ConfigError(f"option {key} must be a list of {len(item_types)} values, got {value!r}", where)
        return tuple(_value_from_data(t, v, None, where, key, ()) for t, v in zip(item_types, value, strict=True))
    return _scalar_from_data(tp, value, where, key)


def _union_from_data(choices: list[Any], value: Any, base: Any, where: Path | str, key: str) -> Any:
    """A value of a union of types (not of dataclasses): the first choice that reads it."""
    for choice in choices:
        try:
            return _value_from_data(choice, value, base, where, key, ())
        except ConfigError:
            continue
    raise ConfigError(f"option {key}: {value!r} is not a valid value", where)


def _scalar_from_data(tp: Any, value: Any, where: Path | str, key: str) -> Any:
    if tp is Any:
        return value
    if tp is bool:
        ok = isinstance(value, bool)
    elif tp is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif tp is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif tp is str:
        ok = isinstance(value, str)
    elif tp is Path:
        ok = isinstance(value, (str, Path))
        value = Path(value) if ok else value
    else:
        ok = isinstance(value, tp) if isinstance(tp, type) else True
    if not ok:
        name = getattr(tp, "__name__", str(tp))
        raise ConfigError(f"option {key} must be {name}, got {type(value).__name__} {value!r}", where)
    return value


def option_paths(options_type: type, prefix: str = "") -> dict[str, Any]:
    """Every configurable scalar option of ``options_type`` by its dotted path (``training.iterations``) → its type
    hint; nested dataclasses are walked (their runtime fields left out)."""
    out: dict[str, Any] = {}
    hints = _hints(options_type)
    for f in configurable_fields(options_type):
        tp = hints[f.name]
        inner = [a for a in typing.get_args(tp) if a is not type(None)] if _is_union(tp) else [tp]
        if len(inner) == 1 and dataclasses.is_dataclass(inner[0]):  # a nested table
            runtime = _child_runtime(f)
            nested = option_paths(inner[0], prefix + f.name + ".")
            start = len(prefix + f.name) + 1
            out.update({k: v for k, v in nested.items() if k[start:].split(".")[0] not in runtime})
        else:
            out[prefix + f.name] = tp
    return out


def with_option(options: Any, path: str, value: Any, where: Path | str = "--options") -> Any:
    """``options`` with the option at dotted ``path`` set from plain data (as a TOML value would give it)."""
    table: dict[str, Any] = {}
    node = table
    parts = path.split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    node[parts[-1]] = value
    return options_from_table(type(options), table, where, base=options)


def with_options(options: Any, values: dict[str, Any], where: Path | str = "--options") -> Any:
    """``options`` with every ``{dotted path: value}`` set (values as config.toml spells them; None: left as is)."""
    for path, value in values.items():
        if value is not None:
            options = with_option(options, path, value, where)
    return options


def options_with(options_type: type, values: dict[str, Any], where: Path | str = "--options") -> Any:
    """Options of ``options_type`` (its defaults) with ``{dotted path: value}`` set, values as config.toml spells
    them: ``options_with(MaskedTrainingOptions, {"training.iterations": 40, "snapshot_iterations": [20]})``."""
    return with_options(options_type(), values, where)
