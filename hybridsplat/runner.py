"""Runs stages: skip what is current or not needed, run the rest, record everything in the manifest.

For each stage the runner hashes its inputs, options and fingerprint and compares them with the manifest: a stage
whose record matches and whose outputs exist is "up to date". A stage that runs is first invalidated (its record
dropped, its old outputs removed), so that a failure or an interruption (Ctrl-C, SIGTERM) never leaves an output
that looks current; on success its timings, peak memory, result (the stage's typed ``Result``, stored as the
record's ``counts``) and the bytes it wrote are recorded.

Before a stage touches anything the runner checks that its estimate of what it will write
(:meth:`Stage.expected_bytes`) fits on the disk (:mod:`hybridsplat.disk_space`); a failure is told in the user's
words (:mod:`hybridsplat.stage_failures`: a full disk, a permission denied, naming the stage and the file) after
the stage's partial outputs are removed. The caller holds the project's lock (:mod:`hybridsplat.project_lock`);
``on_stage`` tells it which stage starts, for ``hybridsplat status``.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import replace
from pathlib import Path

from core.io.json_io import to_jsonable
from hybridsplat.config import options_digest
from hybridsplat.disk_space import check_space, tree_bytes
from hybridsplat.manifest import Manifest, PeakMemory, StageRecord, hash_path
from hybridsplat.stage_failures import explain_failure
from hybridsplat.stages.base import Stage, StageContext
from hybridsplat.terminal import Terminal

StageStarted = Callable[[str], None]


def run_stages(
    ctx: StageContext,
    stages: Sequence[Stage],
    terminal: Terminal,
    force: Iterable[str] = (),
    on_stage: StageStarted | None = None,
) -> Manifest:
    """Run ``stages`` in order on the project of ``ctx``; ``force`` names stages to rerun even when current;
    ``on_stage(name)`` is called as a stage starts its work."""
    manifest = Manifest(ctx.layout.manifest)
    forced = set(force)
    for stage in stages:
        record = run_stage(manifest, stage, ctx, terminal, force=stage.name in forced, on_stage=on_stage)
        terminal.line(describe(stage, record))
    return manifest


def run_stage(
    manifest: Manifest,
    stage: Stage,
    ctx: StageContext,
    terminal: Terminal,
    force: bool = False,
    on_stage: StageStarted | None = None,
) -> StageRecord:
    """Run one stage unless it is up to date or not needed; the manifest is saved after every change."""
    config = stage_config(stage, ctx)
    elsewhere = stage.made_elsewhere(ctx)
    if elsewhere is not None:  # its outputs belong to the stage that made them: kept
        return manifest.record(StageRecord(name=stage.name, skipped=True, reason=elsewhere, config=config))
    reason = stage.needs(ctx)
    outputs = stage.outputs(ctx)
    if reason is not None:
        try:
            _remove(outputs)  # outputs of an earlier run that no longer applies are stale
        except OSError as err:
            raise explain_failure(stage.name, err, ctx.layout.root, outputs) or err from err
        record = StageRecord(name=stage.name, skipped=True, reason=reason, config=config)
        return manifest.record(record)
    hashes = {Path(p): hash_path(p) for p in stage.inputs(ctx)}
    inputs = {manifest.relative(p): h for p, h in hashes.items()}
    previous = manifest.stages.get(stage.name)
    if not force and previous is not None and record_is_current(previous, stage, inputs, config, manifest.project):
        previous.config = config  # a record of 0.2 takes the options' 0.3 form (same values)
        return manifest.mark_cached(stage.name)
    expected = stage.expected_bytes(ctx)
    check_space(stage.name, ctx.layout.root, expected, reclaimable=tree_bytes(outputs))
    if on_stage is not None:
        on_stage(stage.name)
    try:
        manifest.invalidate(stage.name)
        _remove(outputs)
        with terminal.stage(stage.name, ctx.layout.log(stage.name)) as progress, PeakMemory() as memory:
            ctx.progress, ctx.input_hashes, ctx.say = progress, hashes, terminal.line
            start = time.perf_counter()
            result = stage.run(ctx)
            seconds = time.perf_counter() - start
            if not isinstance(result, stage.Result):
                made, wanted = type(result).__name__, stage.Result.__name__
                raise TypeError(f"stage {stage.name!r} returned a {made}, not its {wanted}")
    except BaseException as err:
        told = explain_failure(stage.name, err, ctx.layout.root, outputs)
        try:
            _remove(outputs)
        except OSError as cleanup:  # what could not be removed is named below the first error
            err.add_note(f"and its outputs could not be removed: {cleanup}")
        if told is not None:
            raise told from err
        raise
    finally:
        ctx.progress, ctx.input_hashes, ctx.say = StageContext.progress, {}, StageContext.say
    record = StageRecord(
        name=stage.name,
        seconds=round(seconds, 4),
        peak_mb=round(memory.peak_mb, 1),
        counts=result.as_dict(),
        config=config,
        inputs=inputs,
        outputs=[manifest.relative(p) for p in outputs],
        bytes_expected=int(expected),
        bytes_written=tree_bytes(outputs),
        finished_at=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    )
    return manifest.record(record)


def stage_config(stage: Stage, ctx: StageContext) -> dict:
    """What the manifest records and compares of a stage besides its inputs: its options and fingerprint (with the
    project's seed for a stage that ``uses_seed``)."""
    fingerprint = stage.fingerprint(ctx)
    if stage.uses_seed:
        fingerprint = {**fingerprint, "seed": ctx.config.seed}
    return {"options": options_digest(ctx.options(stage)), "fingerprint": to_jsonable(fingerprint)}


def record_is_current(previous: StageRecord, stage: Stage, inputs: dict[str, str], config: dict, project: Path) -> bool:
    """Whether ``previous`` matches: as recorded, or with its options recorded by hybridsplat 0.2 read in their 0.3
    form (:mod:`hybridsplat.config_migration`), so that a finished project is not re-run because options moved."""
    if previous.is_current(inputs, config, project):
        return True
    recorded = previous.config.get("options")
    if not isinstance(recorded, dict) or recorded == config["options"]:
        return False
    from core.errors import ConfigError
    from hybridsplat.config_migration import migrate_table
    from hybridsplat.options import options_from_table

    try:
        upgraded = options_digest(options_from_table(stage.Options, migrate_table(stage.name, recorded), "manifest"))
    except ConfigError:
        return False
    candidate = {**previous.config, "options": upgraded}
    return candidate == config and replace(previous, config=candidate).is_current(inputs, config, project)


def describe(stage: Stage, record: StageRecord) -> str:
    """The stage's one-line summary for the terminal."""
    if record.skipped:
        return f"  {stage.name:<10} skipped: {record.reason}"
    if record.cached:
        return f"  {stage.name:<10} up to date (nothing it depends on changed)"
    what = stage.summary(record.result(stage.Result))
    return f"  {stage.name:<10} {record.seconds:7.1f} s  peak {record.peak_mb:5.0f} MB" + (f"  {what}" if what else "")


def _remove(paths: Iterable[Path]) -> None:
    for path in paths:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, onerror=_name_the_file)
        elif path.exists() or path.is_symlink():
            path.unlink()


def _name_the_file(function: object, path: str, info: tuple) -> None:
    """shutil.rmtree's error handler: its errors name the file by its full path (it reports bare names)."""
    err = info[1]
    if isinstance(err, OSError):
        raise OSError(err.errno, err.strerror, path) from err
    raise err
