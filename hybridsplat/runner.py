"""Runs stages: skip what is current or not needed, run the rest, record everything in the manifest.

For each stage the runner hashes its inputs, options and fingerprint and compares them with the manifest: a stage
whose record matches and whose outputs exist is "up to date". A stage that runs is first invalidated (its record
dropped, its old outputs removed), so that a failure or an interruption (Ctrl-C, SIGTERM) never leaves an output
that looks current; on success its timings, peak memory and counts are recorded.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterable, Sequence
from dataclasses import replace
from pathlib import Path

from core.io.json_io import to_jsonable
from hybridsplat.config import options_digest
from hybridsplat.manifest import Manifest, PeakMemory, StageRecord, hash_path
from hybridsplat.stages.base import Stage, StageContext
from hybridsplat.terminal import Terminal


def run_stages(ctx: StageContext, stages: Sequence[Stage], terminal: Terminal, force: Iterable[str] = ()) -> Manifest:
    """Run ``stages`` in order on the project of ``ctx``; ``force`` names stages to rerun even when current."""
    manifest = Manifest(ctx.layout.manifest)
    forced = set(force)
    for stage in stages:
        record = run_stage(manifest, stage, ctx, terminal, force=stage.name in forced)
        terminal.line(describe(stage, record))
    return manifest


def run_stage(
    manifest: Manifest, stage: Stage, ctx: StageContext, terminal: Terminal, force: bool = False
) -> StageRecord:
    """Run one stage unless it is up to date or not needed; the manifest is saved after every change."""
    config = {"options": options_digest(ctx.options(stage)), "fingerprint": to_jsonable(stage.fingerprint(ctx))}
    reason = stage.needs(ctx)
    outputs = stage.outputs(ctx)
    if reason is not None:
        _remove(outputs)  # outputs of an earlier run that no longer applies are stale
        record = StageRecord(name=stage.name, skipped=True, reason=reason, config=config)
        return manifest.record(record)
    hashes = {Path(p): hash_path(p) for p in stage.inputs(ctx)}
    inputs = {manifest.relative(p): h for p, h in hashes.items()}
    previous = manifest.stages.get(stage.name)
    if not force and previous is not None and _is_current(previous, stage, inputs, config, manifest.project):
        previous.config = config  # a record of 0.2 takes the options' 0.3 form (same values)
        return manifest.mark_cached(stage.name)
    manifest.invalidate(stage.name)
    _remove(outputs)
    try:
        with terminal.stage(stage.name, ctx.layout.log(stage.name)) as progress, PeakMemory() as memory:
            ctx.progress, ctx.input_hashes = progress, hashes
            start = time.perf_counter()
            counts = stage.run(ctx)
            seconds = time.perf_counter() - start
    except BaseException:
        _remove(outputs)
        raise
    finally:
        ctx.progress, ctx.input_hashes = StageContext.progress, {}
    record = StageRecord(
        name=stage.name,
        seconds=round(seconds, 4),
        peak_mb=round(memory.peak_mb, 1),
        counts=to_jsonable(counts or {}),
        config=config,
        inputs=inputs,
        outputs=[manifest.relative(p) for p in outputs],
        finished_at=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    )
    return manifest.record(record)


def _is_current(previous: StageRecord, stage: Stage, inputs: dict[str, str], config: dict, project: Path) -> bool:
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
        return f"  {stage.name:<9} skipped: {record.reason}"
    if record.cached:
        return f"  {stage.name:<9} up to date (nothing it depends on changed)"
    what = stage.summary(record.counts)
    return f"  {stage.name:<9} {record.seconds:7.1f} s  peak {record.peak_mb:5.0f} MB" + (f"  {what}" if what else "")


def _remove(paths: Iterable[Path]) -> None:
    for path in paths:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        elif path.exists() or path.is_symlink():
            path.unlink()
