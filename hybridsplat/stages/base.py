"""What a pipeline stage is, and what it is given.

A stage is a small class in its own module: a ``name``, its ``Options`` (the domain's options dataclass, or one
composing it: one TOML table in ``config.toml``, see :mod:`hybridsplat.options`), the files it reads (``inputs``)
and writes (``outputs``), ``needs`` (a reason to skip, or None) and ``run`` (returns its ``Result``). It is a thin
shell: it reads files through :mod:`hybridsplat.project_io`, calls a function of
``recon``/``classify``/``fusion``/``eval``, and writes files (atomically, through ``core.io``). The runner
(``hybridsplat.runner``) decides whether it runs, times it and records it.

A stage's result is a small typed record declared in its module beside it::

    @dataclass(frozen=True)
    class MvsResult(StageResult):
        # (its docstring: what the stage made, each field's meaning and unit)
        backend: str = ""
        points: int = 0
        seconds_per_view: float = 0.0
        memory_limit_mb: float | None = omitted_if_none()  # only some runs have it


    class MvsStage(Stage):
        name = "mvs"
        Result = MvsResult

        def run(self, ctx) -> MvsResult: ...

        def summary(self, result: MvsResult) -> str: ...

Every field has a type hint and a default (the docstring states the units); nested values keyed by data (per class,
per tile) may be mappings, fixed groups are nested records. ``run`` returns it; the runner stores it in the
manifest as the stage record's ``counts`` (:meth:`hybridsplat.records.TypedRecord.as_dict`: one key a field, the
:func:`~hybridsplat.records.omitted_if_none` ones only when set) and ``summary`` and ``report_section`` are given
it back typed. Any other code (another stage, ``status``, the report) reads it through
:func:`hybridsplat.project_io.stage_result` (``stage_result(layout, TrainStage).iterations``), never by a string
key of the counts. A record of an earlier version still reads: unknown keys are ignored, missing ones take their
defaults (:meth:`hybridsplat.records.TypedRecord.from_json`).

What the command line and the report show of a stage comes from its declaration too: ``command`` and
``command_options`` make ``hybridsplat <command> PROJECT [--option V]`` (:mod:`hybridsplat.commands.stages`),
``run_options`` adds options to ``hybridsplat run``, and :meth:`Stage.report_section` gives its section of the
report. Registering a stage (one line in :mod:`hybridsplat.stages`) is all the rest needs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from hybridsplat.config import ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.records import TypedRecord, omitted_if_none
from hybridsplat.source import Source
from hybridsplat.terminal import ProgressCallback

__all__ = [
    "MEMORY_LIMIT_HELP",
    "CliOption",
    "NoOptions",
    "ReportSection",
    "Stage",
    "StageContext",
    "StageResult",
    "omitted_if_none",
]


@dataclass(frozen=True)
class NoOptions:
    """A stage without options."""


@dataclass(frozen=True)
class StageResult(TypedRecord):
    """Base of the stages' results: what ``run`` returns and the manifest records (see the module docstring)."""


MEMORY_LIMIT_HELP = (
    "Bound the memory (MiB, at least 704) of the stages that stream: conversion, classification, the survey point "
    "exports and the C2C evaluation work in chunks (the same files)."
)
"""The help of ``run --memory-limit``, one flag that sets ``memory_limit_mb`` of every stage that declares it."""


@dataclass(frozen=True)
class CliOption:
    """A stage option on the command line.

    path: the option's dotted path in the stage's options (``training.iterations``). flag: its spelling
    (``--train-iterations``; ``--a/--b`` for a boolean pair); default ``--`` + the last part of the path with
    dashes. help: one line. is_path: a file or folder, made absolute before it is recorded. value: for a flag
    that takes no value (``--baseline``), what it sets."""

    path: str
    flag: str = ""
    help: str = ""
    is_path: bool = False
    value: Any = None

    @property
    def spelling(self) -> str:
        return self.flag or "--" + self.path.split(".")[-1].replace("_", "-")

    @property
    def parameter(self) -> str:
        """The Python name of the command's parameter."""
        return self.spelling.split("/")[0].lstrip("-").replace("-", "_")


@dataclass(frozen=True)
class ReportSection:
    """What a stage shows in the report: a title, lines of text and figures (paths relative to the project,
    with captions)."""

    title: str
    lines: tuple[str, ...] = ()
    figures: tuple[tuple[str, str], ...] = ()


def _no_progress(label: str, done: int, total: int) -> None:
    return None


def _no_line(text: str) -> None:
    return None


@dataclass
class StageContext:
    """Everything a stage may use: the project layout, the configuration, the input, a progress callback, a line
    for the terminal (``say``: what the user must see before the stage ends, such as a prediction), and (while it
    runs) the content hashes the runner took of its ``inputs``."""

    layout: ProjectLayout
    config: ProjectConfig
    source: Source
    progress: ProgressCallback = field(default=_no_progress)
    say: Callable[[str], None] = field(default=_no_line)
    input_hashes: dict[Path, str] = field(default_factory=dict)

    def options(self, stage: Stage) -> Any:
        return self.config.options(stage.name, stage.Options)

    def content_hash(self, path: Path) -> str:
        """SHA-256 of a file or folder (``hybridsplat.manifest.hash_path``), the runner's when it hashed it already."""
        from hybridsplat.manifest import hash_path

        known = self.input_hashes.get(Path(path))
        return known if known is not None else hash_path(path)


class Stage:
    """Base class of the pipeline's stages (see the module docstring)."""

    name: ClassVar[str]
    Options: ClassVar[type] = NoOptions
    Result: ClassVar[type[StageResult]] = StageResult  # what ``run`` returns (the manifest's counts, typed)
    title: ClassVar[str] = ""  # a few words for the terminal
    command: ClassVar[str | None] = None  # ``hybridsplat <command> PROJECT`` runs this stage alone
    command_help: ClassVar[str] = ""  # that command's help (default: the title)
    command_options: ClassVar[tuple[CliOption, ...]] = ()  # its options
    run_options: ClassVar[tuple[CliOption, ...]] = ()  # options of ``hybridsplat run`` that set this stage's
    uses_seed: ClassVar[bool] = False  # its outputs depend on the project's seed (it reruns when the seed changes)

    def inputs(self, ctx: StageContext) -> list[Path]:
        """Files and folders whose content decides the outputs (hashed by the runner)."""
        return []

    def outputs(self, ctx: StageContext) -> list[Path]:
        """Files and folders this stage writes; removed when it fails, is interrupted or becomes unneeded."""
        return []

    def expected_bytes(self, ctx: StageContext) -> int:
        """About how many bytes the stage will write (its outputs and its log), from its inputs' sizes and counts;
        an upper estimate: the runner refuses to start the stage when it does not fit on the disk. The default,
        twice the size of its inputs, is for stages that declare no estimate of their own."""
        from hybridsplat.disk_space import tree_bytes

        return 2 * tree_bytes(self.inputs(ctx))

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        """Extra values that decide the outputs besides inputs and options (compared like the options)."""
        return {}

    def needs(self, ctx: StageContext) -> str | None:
        """None when the stage must run for this project, else the reason it is skipped."""
        return None

    def made_elsewhere(self, ctx: StageContext) -> str | None:
        """Why another stage of this project makes this stage's products, or None (the usual case). The runner then
        skips this stage and keeps its outputs: a tiled run's ``tiles`` stage stitches the mvs, classify, train and
        clean products from its tiles (:data:`hybridsplat.tile_projects.PER_TILE_IN_PARENT`)."""
        from hybridsplat.tile_projects import PER_TILE_IN_PARENT

        if self.name not in PER_TILE_IN_PARENT:
            return None
        from hybridsplat.stages.tiles import tiling_on

        return "made per tile (--tiles): stage 'tiles' stitched its products" if tiling_on(ctx) else None

    def run(self, ctx: StageContext) -> StageResult:
        """Do the work; return what it made (an instance of ``Result``, recorded in the manifest)."""
        raise NotImplementedError

    def summary(self, result: Any) -> str:
        """A few words about what the stage produced (its ``Result``), for the terminal's one-line summary."""
        return ""

    def report_section(self, result: Any) -> ReportSection | None:
        """This stage's section of the report, from the ``Result`` it recorded (None: no section)."""
        return None
