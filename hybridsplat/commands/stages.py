"""Per-stage commands, built from the stages' declarations: ``hybridsplat <command> PROJECT [--option V] [--force]``.

Every registered stage with a ``command`` gets one (``mvs``, ``masks``, ``train``, ``clean``, ``mesh``...): its
options are the stage's ``command_options`` (:class:`~hybridsplat.stages.base.CliOption`), typed from the stage's
options dataclass; a value given replaces the one recorded in ``PROJECT/config.toml``, the others keep it.
:func:`cli_parameters` also serves ``hybridsplat run`` (the stages' ``run_options``) and the custom commands
(``sfm``, ``classify predict``).
"""

from __future__ import annotations

import inspect
import types
import typing
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import typer


def _cli_type(tp: Any) -> Any:
    """The type typer parses an option as (None: it is not given)."""
    args = [a for a in typing.get_args(tp) if a is not type(None)]
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return str if type(None) in typing.get_args(tp) else _cli_type(args[0])
    if typing.get_origin(tp) is tuple:
        item = typing.get_args(tp)[0]
        return list[item] if item in (int, float, str) else list[str]
    if tp in (bool, int, float, str):
        return tp
    return str  # enums, paths: checked when the options are built


def _option_type(options_type: type, path: str) -> Any:
    from hybridsplat.options import option_paths

    paths = option_paths(options_type)
    if path not in paths:
        raise KeyError(f"{options_type.__name__} has no option {path!r} (known: {', '.join(paths)})")
    return paths[path]


def cli_parameters(options_type: type, declared: Iterable[Any]) -> list[inspect.Parameter]:
    """Keyword parameters (default None = not given) for the declared CLI options of ``options_type``."""
    params = []
    for opt in declared:
        tp = _option_type(options_type, opt.path)
        if opt.value is not None:  # a flag without a value
            annotation, default = bool, typer.Option(False, opt.spelling, help=opt.help)
        elif tp is bool:
            spelling = opt.spelling
            flags = spelling if "/" in spelling else f"{spelling}/--no-{spelling.lstrip('-')}"
            annotation, default = bool | None, typer.Option(None, flags, help=opt.help)
        elif typing.get_origin(_cli_type(tp)) is list:
            annotation, default = _cli_type(tp), typer.Option([], opt.spelling, help=opt.help)
        else:
            annotation, default = _cli_type(tp) | None, typer.Option(None, opt.spelling, help=opt.help)
        params.append(inspect.Parameter(opt.parameter, inspect.Parameter.KEYWORD_ONLY, default=default,
                                        annotation=annotation))  # fmt: skip
    return params


def _value(tp: Any, given: Any, opt: Any) -> Any:
    """A CLI value as config.toml would spell it (paths absolute, lists as lists, "none" for None)."""
    if opt.value is not None:
        return opt.value if given else None
    if isinstance(given, list):
        return list(given) if given else None
    if given is None:
        return None
    if opt.is_path:
        return str(Path(given).resolve()) if str(given) else ""
    from hybridsplat.options import NONE_SPELLING, NONE_WORDS

    optional = type(None) in typing.get_args(tp)
    if optional and isinstance(given, str) and given.lower() in NONE_WORDS:
        return NONE_SPELLING  # only an option that can be None: ``--tiles off`` is the value "off", not None
    inner = [a for a in typing.get_args(tp) if a is not type(None)]
    if isinstance(given, str) and inner and inner[0] in (int, float):
        from core.errors import ConfigError

        try:
            return inner[0](given)
        except ValueError as err:
            raise ConfigError(f"{opt.spelling} must be a number or none, got {given!r}") from err
    return given


def apply_cli_values(options: Any, declared: Iterable[Any], values: dict[str, Any]) -> Any:
    """``options`` with every declared option that was given on the command line set (the others unchanged)."""
    from hybridsplat.options import with_option

    for opt in declared:
        value = _value(_option_type(type(options), opt.path), values.get(opt.parameter), opt)
        if value is not None:
            options = with_option(options, opt.path, value, opt.spelling)
    return options


def build_command(name: str, params: list[inspect.Parameter], body: Callable[..., None], doc: str) -> Callable:
    """A function typer can register: ``body(**values)`` with the signature ``params``."""

    def command(**values: Any) -> None:
        body(**values)

    command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    command.__name__ = name.replace("-", "_")
    command.__doc__ = doc
    return command


def stage_command(stage: Any) -> Callable:
    """``hybridsplat <stage.command> PROJECT [options] [--force]`` for a registered stage."""
    project_help = "Project folder (after 'hybridsplat run')."
    project = inspect.Parameter("project", inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation=Path,
                                default=typer.Argument(..., help=project_help))  # fmt: skip
    force = inspect.Parameter("force", inspect.Parameter.KEYWORD_ONLY, annotation=bool,
                              default=typer.Option(False, "--force", help="Rerun even when up to date."))  # fmt: skip
    params = [project, *cli_parameters(stage.Options, stage.command_options), force]

    def body(project: Path, force: bool, **values: Any) -> None:
        from hybridsplat.commands.common import run_project_stage

        run_project_stage(project, stage.name, lambda o: apply_cli_values(o, stage.command_options, values), force)

    return build_command(stage.command or stage.name, params, body, stage.command_help or stage.title)


def register(app: typer.Typer) -> None:
    from hybridsplat.stages import registered_stages

    for stage in registered_stages():
        if stage.command:
            app.command(stage.command)(stage_command(stage))
