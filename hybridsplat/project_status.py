"""Where a project stands, without running anything: per stage current, stale (and why), skipped, running.

The same questions the runner asks (:mod:`hybridsplat.runner`): are the stage's inputs, options and fingerprint
those recorded in the manifest, do its outputs exist, does it need to run at all. A stage whose inputs are the
outputs of a stage that will rerun is stale too ("after <stage>"), although its files have not changed yet.
While a writer holds the project's lock (:mod:`hybridsplat.project_lock`), its running stage and the stages it will
run next are reported from the lock's holder file and not examined (their files are being written); otherwise
the status is read under a shared lock, so no stage changes while it is read.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from os import PathLike
from pathlib import Path
from typing import Any

from core.errors import HybridSplatError, InputFileError
from hybridsplat.layout import ProjectLayout
from hybridsplat.manifest import Manifest, StageRecord, hash_path
from hybridsplat.project_io import stage_result
from hybridsplat.project_lock import LockHolder, ProjectLock, read_holder
from hybridsplat.stages.base import Stage, StageContext, StageResult

CURRENT, STALE, SKIPPED, NOT_RUN, RUNNING, QUEUED = "current", "stale", "skipped", "not run", "running", "queued"
UNKNOWN = "unknown"  # the project's input cannot be read, so nothing can be compared
WAITING = "waiting"  # not needed as the project is now, but its inputs come from stages that will run first
WILL_CHANGE = {STALE, NOT_RUN, RUNNING, QUEUED, UNKNOWN, WAITING}
"""States of a stage whose outputs will change, so that the stages reading them are stale too."""


@dataclass(frozen=True)
class StageStatus:
    """One stage: ``state`` (one of the module's constants), why (``reasons``), and its last run's record.

    seconds, peak_mb, finished_at, bytes_written, result (the stage's typed ``Result``): from the manifest (the run
    that made its outputs; None without one).
    """

    name: str
    state: str
    reasons: tuple[str, ...] = ()
    summary: str = ""
    seconds: float | None = None
    peak_mb: float | None = None
    bytes_written: int | None = None
    finished_at: str | None = None
    result: StageResult | None = None


@dataclass(frozen=True)
class ProjectStatus:
    """Every registered stage's status; ``writer``: the process writing the project now (None when none);
    ``abandoned``: a writer that ended without releasing its lock (killed), whose last stage did not finish."""

    project: Path
    stages: tuple[StageStatus, ...]
    writer: LockHolder | None = None
    abandoned: LockHolder | None = None

    def to_json(self) -> dict[str, Any]:
        """The status as JSON data (``status --json``): each stage's result as the manifest's ``counts``."""
        data = asdict(self)
        data["project"] = str(self.project)
        for stage, status in zip(data["stages"], self.stages, strict=True):
            stage.pop("result")
            stage["counts"] = status.result.as_dict() if status.result is not None else {}
        return data


def project_status(project: str | PathLike[str]) -> ProjectStatus:
    """The status of the project folder ``project`` (:class:`InputFileError` when it is not one)."""
    layout = ProjectLayout(project)
    if not layout.config.is_file():
        problem = "no project here" if not layout.root.exists() else "not a hybridsplat project (no config.toml)"
        raise InputFileError(problem, layout.root)
    holder = read_holder(layout.root)
    alive = holder is not None and holder.is_alive() is not False
    if alive:
        return _status(layout, holder)
    with ProjectLock(layout.root, exclusive=False):
        return _status(layout, None, abandoned=holder)


def _status(layout: ProjectLayout, writer: LockHolder | None, abandoned: LockHolder | None = None) -> ProjectStatus:
    from hybridsplat.pipeline import load_config
    from hybridsplat.source import resolve_source
    from hybridsplat.stages import registered_stages

    config = load_config(layout.root)
    manifest = Manifest(layout.manifest)
    try:
        ctx = StageContext(layout=layout, config=config, source=resolve_source(config.input))
    except HybridSplatError as err:
        unreadable = StageStatus("", UNKNOWN, (f"the project's input cannot be read: {err.one_line()}",))
        ctx = None
    busy = _busy_stages(writer)
    statuses: list[StageStatus] = []
    changing: dict[str, str] = {}  # output path (relative) -> the stage that will rewrite it
    for stage in registered_stages():
        status = busy.get(stage.name)
        if status is None and ctx is None:
            status = replace(unreadable, name=stage.name)
        elif status is None:
            status = _stage_status(stage, ctx, manifest, changing)
        status = _with_record(status, manifest, stage)
        if status.state in WILL_CHANGE and ctx is not None:
            for out in stage.outputs(ctx):
                changing[manifest.relative(out)] = stage.name
        statuses.append(status)
    return ProjectStatus(layout.root, tuple(statuses), writer=writer, abandoned=abandoned)


def _busy_stages(writer: LockHolder | None) -> dict[str, StageStatus]:
    """The writer's running stage and the stages its run comes to after it."""
    if writer is None:
        return {}
    names = list(writer.stages)
    run = f"in the run of pid {writer.pid}"
    if writer.stage is None:  # between taking the lock and starting its first stage
        return {name: StageStatus(name, QUEUED, (run,)) for name in names}
    out = {writer.stage: StageStatus(writer.stage, RUNNING, (f"pid {writer.pid}, since {writer.stage_started}",))}
    later = names[names.index(writer.stage) + 1 :] if writer.stage in names else []
    out.update({name: StageStatus(name, QUEUED, (f"after {writer.stage}, {run}",)) for name in later})
    return out


def _stage_status(stage: Stage, ctx: StageContext, manifest: Manifest, changing: dict[str, str]) -> StageStatus:
    from hybridsplat.runner import record_is_current, stage_config

    name = stage.name
    try:
        skip = stage.made_elsewhere(ctx) or stage.needs(ctx)
        config = stage_config(stage, ctx)
        inputs = {manifest.relative(p): hash_path(p) for p in stage.inputs(ctx)}
    except Exception as err:  # an input that cannot be read: the run would tell the same
        return StageStatus(name, STALE, (f"cannot be examined: {type(err).__name__}: {err}",))
    record = manifest.stages.get(name)
    upstream = sorted({changing[p] for p in inputs if p in changing} | _under(inputs, changing))
    reasons = [f"after {', '.join(upstream)}, which will run first"] if upstream else []
    if skip is not None:  # with its inputs still to come, the decision is taken again once they are there
        recorded = record is not None and record.skipped and record.reason == skip
        if reasons and not recorded:
            return StageStatus(name, WAITING, (*reasons, f"not needed now: {skip}"))
        return StageStatus(name, SKIPPED, (skip,))
    if record is None:
        return StageStatus(name, NOT_RUN, (*reasons, "no record in the manifest"))
    if record.skipped:
        return StageStatus(name, STALE, (*reasons, f"was skipped ({record.reason}), now needed"))
    if not record_is_current(record, stage, inputs, config, manifest.project):
        reasons += _why_stale(record, inputs, config, manifest.project)
    return StageStatus(name, STALE if reasons else CURRENT, tuple(reasons))


def _under(inputs: dict[str, str], changing: dict[str, str]) -> set[str]:
    """Stages that will rewrite a folder holding one of ``inputs``, or a file inside an input folder."""
    found = set()
    for path in inputs:
        for out, stage in changing.items():
            if path.startswith(out.rstrip("/") + "/") or out.startswith(path.rstrip("/") + "/"):
                found.add(stage)
    return found


def _why_stale(record: StageRecord, inputs: dict[str, str], config: dict[str, Any], project: Path) -> list[str]:
    reasons = []
    for path in sorted(set(inputs) | set(record.inputs)):
        was, now = record.inputs.get(path), inputs.get(path)
        if was != now:
            reasons.append(f"input {path} {'missing' if now == 'missing' else 'is new' if was is None else 'changed'}")
    was_options, now_options = _flat(record.config.get("options", {})), _flat(config["options"])
    for key in sorted(set(was_options) | set(now_options)):
        if was_options.get(key) != now_options.get(key):
            reasons.append(f"option {key}: {_show(was_options.get(key))} -> {_show(now_options.get(key))}")
    if record.config.get("fingerprint") != config["fingerprint"]:
        reasons.append("its fingerprint changed (what it depends on besides inputs and options)")
    reasons += [f"output {o} missing" for o in record.outputs if not (project / o).exists()]
    return reasons or ["its record does not match (rerun to refresh it)"]


def _flat(data: Any, prefix: str = "") -> dict[str, Any]:
    if not isinstance(data, dict):
        return {prefix: data}
    out: dict[str, Any] = {}
    for key, value in data.items():
        out.update(_flat(value, f"{prefix}.{key}" if prefix else str(key)))
    return out


def _show(value: Any) -> str:
    return "(none)" if value is None else repr(value)


def _with_record(status: StageStatus, manifest: Manifest, stage: Stage) -> StageStatus:
    record = manifest.stages.get(stage.name)
    result = stage_result(manifest, stage)
    if record is None or result is None:
        return status
    return StageStatus(
        status.name,
        status.state,
        status.reasons,
        summary=stage.summary(result),
        seconds=record.seconds,
        peak_mb=record.peak_mb,
        bytes_written=record.bytes_written,
        finished_at=record.finished_at,
        result=result,
    )


def format_status(status: ProjectStatus) -> str:
    """The status as lines for the terminal."""
    from hybridsplat.disk_space import format_bytes

    lines = [f"project {status.project}"]
    if status.writer is not None:
        lines.append(f"being written by {status.writer.describe()}")
    if status.abandoned is not None:
        lines.append(f"the last writer, {status.abandoned.describe()}, ended without finishing (killed?)")
    for s in status.stages:
        ran = ""
        if s.seconds is not None:
            size = f"{format_bytes(s.bytes_written):>9}" if s.bytes_written else f"{'':9}"
            ran = f"{s.seconds:7.1f} s {s.peak_mb or 0:6.0f} MB peak {size}  {s.finished_at}"
        lines.append(f"  {s.name:<10} {s.state:<8} {ran}".rstrip())
        if s.summary and s.state == CURRENT:
            lines.append(f"{'':14}{s.summary}")
        lines += [f"{'':14}{reason}" for reason in s.reasons]
    return "\n".join(lines)
