"""The command-line reference (``docs/cli.md``), read from the command line itself.

Every command and option of ``hybridsplat`` (the typer app of :mod:`hybridsplat.cli`, whose per-stage commands and
``run`` options are built from the stages' :class:`~hybridsplat.stages.base.CliOption` declarations) with its help
line. An option that a stage declares also names the ``config.toml`` key it sets and that key's default (from the
stage's options dataclass). An option with a closed set of values lists them: its choices or enum members, the
``a | b | c`` list of its help, and ``none`` where the option may be None. ``scripts/gen_cli_reference.py`` writes
the file; ``tests/test_cli_reference.py`` fails when the file is out of date or an option has no help, and passes
every listed value through the parser.
"""

from __future__ import annotations

import re
import typing
from collections.abc import Iterator
from dataclasses import dataclass
from enum import Enum
from typing import Any

#: an item of a value list in a help line: a word (inner dots allowed) and an optional remark in parentheses
_ITEM = r"[A-Za-z0-9][\w:-]*(?:\.[\w-]+)*(?: \([^()]*\))?"
_VALUE_LIST = re.compile(rf"{_ITEM}(?: \| {_ITEM})+")
_WORD = re.compile(r"[A-Za-z0-9][\w:-]*(?:\.[\w-]+)*")


@dataclass(frozen=True)
class Declared:
    """A stage option behind a command-line option: the stage, the dotted path in its options, and the value a
    flag without a value sets (None otherwise)."""

    stage: str
    path: str
    tp: Any
    default: Any
    flag_value: Any = None


@dataclass(frozen=True)
class Entry:
    """One argument or option of one command, as the reference shows it."""

    command: str  # "run", "classify predict"
    name: str  # "--tiles", "-o, --out", "--tile-context / --no-tile-context", "PROJECT"
    kind: str  # "argument" or "option"
    metavar: str  # "<str>", "<int>", "" for a flag
    help: str  # typer's help text, with its "[default: ...]" / "[required]"
    values: tuple[str, ...]  # the documented values (empty: not a closed set)
    declared: tuple[Declared, ...]  # the stage options it sets (empty: a plain command option)
    param: Any  # the click parameter


def help_values(text: str) -> list[str]:
    """The values an ``a | b (remark) | c`` list in a help line names, in order (``[]`` without such a list)."""
    found: list[str] = []
    for match in _VALUE_LIST.finditer(text or ""):
        for item in match.group().split(" | "):
            word = _WORD.match(item).group()  # type: ignore[union-attr]
            if word not in found:
                found.append(word)
    return found


def _type_values(tp: Any) -> list[str]:
    """Enum members of an option type (``X | None`` adds ``none``; a tuple of X: X's)."""
    from hybridsplat.options import NONE_SPELLING

    args = typing.get_args(tp)
    optional = type(None) in args
    inner = [a for a in args if a is not type(None)] if optional else [tp]
    if len(inner) == 1 and typing.get_origin(inner[0]) is tuple:
        inner = [typing.get_args(inner[0])[0]]
    out = [str(m.value) for a in inner if isinstance(a, type) and issubclass(a, Enum) for m in a]
    return out + ([NONE_SPELLING] if optional else [])


def _declarations() -> dict[tuple[str, str], list[Declared]]:
    """(parameter name, help) → the stage options declared with them, over every registered stage."""
    from hybridsplat.options import option_paths, options_to_data
    from hybridsplat.stages import registered_stages

    found: dict[tuple[str, str], list[Declared]] = {}
    for stage in registered_stages():
        paths, data = option_paths(stage.Options), options_to_data(stage.Options())
        for opt in dict.fromkeys((*stage.run_options, *stage.command_options)):
            declared = Declared(stage.name, opt.path, paths[opt.path], _at(data, opt.path), opt.value)
            entries = found.setdefault((opt.parameter, opt.help), [])
            if declared not in entries:
                entries.append(declared)
    return found


def _at(data: dict[str, Any], path: str) -> Any:
    """The value at a dotted path of options data; a table that is off ("none") stands for its keys."""
    node: Any = data
    for part in path.split("."):
        if not isinstance(node, dict):
            return node
        node = node.get(part)
    return node


def _commands(cmd: Any, path: tuple[str, ...], parent: Any) -> Iterator[tuple[tuple[str, ...], Any, Any]]:
    from typer import _click

    ctx = _click.Context(cmd, info_name=path[-1], parent=parent)
    yield path, cmd, ctx
    for name in sorted(getattr(cmd, "commands", {})):
        yield from _commands(cmd.commands[name], (*path, name), ctx)


def command_tree() -> list[tuple[tuple[str, ...], Any, Any]]:
    """(path, click command, context) of ``hybridsplat`` and every command and group below it, by name."""
    import typer.main

    from hybridsplat.cli import build_app

    return list(_commands(typer.main.get_command(build_app()), ("hybridsplat",), None))


def entries() -> list[Entry]:
    """Every argument and option of every command, in the reference's order."""
    declarations = _declarations()
    out = []
    for path, cmd, ctx in command_tree():
        for param in cmd.params:
            record = param.get_help_record(ctx)
            name, _, metavar = record[0].partition(" <")
            kind = param.param_type_name
            if kind == "argument":
                name = param.name.upper() + ("..." if param.nargs == -1 else "")
            desc = param.type_descriptor
            choices = [c.value if isinstance(c, Enum) else str(c) for c in desc.choices or ()] if desc.is_choice else []
            declared = tuple(declarations.get((param.name, param.help or ""), ()))
            values = [*choices, *help_values(param.help or "")]
            for d in declared:
                values += [] if d.flag_value is not None else _type_values(d.tp)
            metavar = "<" + metavar if metavar else ""
            out.append(Entry(" ".join(path[1:]), name, kind, metavar, record[1], tuple(dict.fromkeys(values)),
                             declared, param))  # fmt: skip
    return out


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _what_cell(entry: Entry) -> str:
    """The help line, then the values and the config.toml keys the option sets (with their defaults)."""
    import json

    parts = [_cell(entry.help)]
    if entry.values == ("none",):
        parts.append("values: a value, or `none`")
    elif entry.values:
        parts.append("values: " + " ".join(f"`{_cell(v)}`" for v in entry.values))
    for d in entry.declared:
        default = json.dumps(d.default, ensure_ascii=False)
        sets = f", this flag sets `{json.dumps(d.flag_value)}`" if d.flag_value is not None else ""
        parts.append(f"config.toml: `[{d.stage}] {d.path}`, default `{default}`{sets}")
    return "<br>".join(parts)


def _usage(path: tuple[str, ...], cmd: Any) -> str:
    arguments = [
        p.name.upper() + ("..." if p.nargs == -1 else "") for p in cmd.params if p.param_type_name == "argument"
    ]
    sub = " COMMAND" if getattr(cmd, "commands", None) else ""
    return " ".join([*path, "[OPTIONS]", *arguments]) + sub


HEADER = """# Command-line reference

Generated from the command line itself (the commands, the stages' option declarations and their options'
defaults) by `scripts/gen_cli_reference.py`; do not edit by hand. After changing a command or an option, run
`PYTHONPATH=$PWD .venv/bin/python scripts/gen_cli_reference.py`: `tests/test_cli_reference.py` fails while this
file differs from what the command line says, when an option has no help, or when a value listed here is refused.

**values**: the whole set an option takes (placeholders such as `NxM` or `PATH` stand for a value of that form;
`none` leaves the option unset). **config.toml**: the key of the project's configuration the option sets (see
[the user guide](guide.md#configuration)) and its default there; an option of `run` sets it for this run, an option
of a per-stage command (`hybridsplat mvs PROJECT ...`) replaces the value the project recorded, and an option not
given keeps it. `hybridsplat COMMAND --help` prints the same help.
"""


def render() -> str:
    """The whole of ``docs/cli.md``."""
    rows: dict[str, list[Entry]] = {}
    for entry in entries():
        rows.setdefault(entry.command, []).append(entry)
    tree = command_tree()
    lines = [HEADER, "## Commands", ""]
    for path, cmd, _ in tree[1:]:
        anchor = "-".join(path)
        first = " ".join((cmd.help or "").split()).split(". ")[0].rstrip(".")
        lines.append(f"- [`{' '.join(path[1:])}`](#{anchor}): {_cell(first)}")
    lines.append("")
    for path, cmd, _ in tree:
        title = " ".join(path)
        lines += [f"## {title}" if len(path) < 3 else f"### {title}", "", f"`{_usage(path, cmd)}`", ""]
        lines += [" ".join((cmd.help or "").split()), ""]
        own = rows.get(" ".join(path[1:]), [])
        if not own:
            continue
        lines += ["| argument / option | what |", "|---|---|"]
        lines += [f"| `{e.name}{' ' + e.metavar if e.metavar else ''}` | {_what_cell(e)} |" for e in own]
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"
