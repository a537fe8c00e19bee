"""A tile of a tiled run as a project of its own (issue 34): made from the parent, run through the same runner.

A tile's project (``PROJECT/tiles/r0c1/``) has the parent's input and options (tiling off), a ``sparse/`` model with
the tile's photos and the sparse points in its bounds (:func:`recon.tile_models.write_tile_model`) and the parent's
sfm record (its origin: every tile is in the parent's local frame). The stages of :data:`TILE_STAGES` then run on
it through :func:`hybridsplat.pipeline.run_pipeline`, with the tile's own manifest: a second run finds the stages of
a finished tile up to date and redoes only what an interrupted one left. :func:`run_tile` is what a Ray task runs
(:mod:`hybridsplat.tile_execution`); it takes and returns only small, picklable values.
"""

from __future__ import annotations

import shutil
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hybridsplat.config import ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.records import TypedRecord, omitted_if_none
from recon.tiling import TilePlan

TILE_STAGES: tuple[str, ...] = ("mvs", "classify", "masks", "convert", "train", "clean")
"""The stages each tile runs. The parent runs the rest on the stitched products: its own masks (on the stitched
classified cloud, for every photo, held-out ones included) and conversion (exact neighbour spacing across tile
borders), then background, merge, mesh, baseline, eval and report on the whole scene, and appearance tile by tile
(:mod:`hybridsplat.tile_appearance`)."""

TRAINING_STAGES: tuple[str, ...] = ("train", "clean")
"""The tile stages that may wait for the neighbouring tiles (their splats frozen in the overlap,
:mod:`hybridsplat.tile_context`); the stages before them run in every tile at once."""

PER_TILE_IN_PARENT: frozenset[str] = frozenset({"mvs", "classify", "train", "clean"})
"""Stages whose product the parent takes stitched from its tiles: skipped in the parent while tiling is on."""


@dataclass(frozen=True)
class TileJob:
    """What a worker needs to run one tile: its name, its project folder, its configuration, which of
    :data:`TILE_STAGES` to run (in their order) and its predicted peak memory (MB; 0: unknown), which its Ray task
    declares."""

    name: str
    root: str
    config: ProjectConfig
    stages: tuple[str, ...] = TILE_STAGES
    memory_mb: float = 0.0


def tile_config(config: ProjectConfig) -> ProjectConfig:
    """The parent's configuration for a tile: the same input, seed and options, tiling off."""
    from hybridsplat.stages.tiles import TilesOptions

    return config.with_stage_options("tiles", TilesOptions())


def prepare_tile(
    parent: ProjectLayout, plan: TilePlan, tile: int, config: ProjectConfig, held_out: Collection[str]
) -> TileJob:
    """Write tile ``tile``'s model and sfm record into its project folder; the job that runs it."""
    from recon.tile_models import write_tile_model

    name = plan.tiles[tile].name
    layout = ProjectLayout(parent.tile_project(name))
    staging = layout.root / "sparse.new"
    if staging.exists():
        shutil.rmtree(staging)
    write_tile_model(parent.sparse, staging, plan, tile, exclude_names=held_out)
    if _same_model(staging, layout.sparse):  # unchanged: keep the files (and the tile's stages up to date)
        shutil.rmtree(staging)
    else:
        layout.empty_tile_record.unlink(missing_ok=True)  # a new model may fuse points
        if layout.sparse.exists():
            shutil.rmtree(layout.sparse)
        staging.rename(layout.sparse)
    layout.logs_dir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(parent.record("sfm"), layout.record("sfm"))
    return TileJob(name=name, root=str(layout.root), config=tile_config(config))


def _same_model(new: Path, old: Path) -> bool:
    from hybridsplat.manifest import hash_path

    return old.is_dir() and hash_path(new) == hash_path(old)


@dataclass(frozen=True)
class TileStageRun(TypedRecord):
    """What a tile's manifest recorded of one of its stages: seconds, peak memory (MB), whether it was up to date
    (``cached``) or ``skipped``, and its result as the manifest's ``counts`` (empty when skipped)."""

    seconds: float = 0.0
    peak_mb: float = 0.0
    cached: bool = False
    skipped: bool = False
    counts: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class TileRun(TypedRecord):
    """One tile's run (:func:`run_tile`): its name, its ``stages`` (stage name → :class:`TileStageRun`), why it
    fused no point (``empty``; then it ran nothing) and, as a Ray task, the resources Ray gave it."""

    tile: str = ""
    stages: dict[str, TileStageRun] = field(default_factory=dict)
    empty: str | None = omitted_if_none()
    resources: dict[str, float] | None = omitted_if_none()


def run_tile(job: TileJob) -> TileRun:
    """Run the job's stages (:data:`TILE_STAGES` or a part of them) in its project; per stage what the tile's
    manifest recorded (seconds, peak MB, cached or skipped), for the parent's record and the cost model."""
    from core.errors import EmptyFusionError
    from hybridsplat.pipeline import run_pipeline
    from hybridsplat.stages import stage_named
    from hybridsplat.terminal import Terminal

    layout = ProjectLayout(job.root)
    empty = _empty_record(layout)
    if empty is not None:
        return TileRun(job.name, empty=empty)
    stages = [stage_named(n) for n in job.stages]
    try:
        manifest = run_pipeline(job.root, job.config, stages=stages, terminal=Terminal(quiet=True))
    except EmptyFusionError as err:
        # nothing in the tile survives fusion (water, a textureless roof): it adds nothing, the others go on; the
        # record keeps a second run from redoing its MVS while its model is unchanged
        _write_empty_record(layout, err.problem)
        return TileRun(job.name, empty=err.problem)
    records = {}
    for name in job.stages:
        record = manifest.stages[name]
        records[name] = TileStageRun(
            seconds=float(record.seconds or 0.0),
            peak_mb=float(record.peak_mb or 0.0),
            cached=bool(record.cached),
            skipped=bool(record.skipped),
            counts=record.counts if not record.skipped else {},
        )
    return TileRun(job.name, records)


def _empty_record(layout: ProjectLayout) -> str | None:
    """Why the tile fused no point, when an earlier run recorded so for the tile's current model; else None."""
    from core.io.json_io import read_json_object
    from hybridsplat.manifest import hash_path

    path = layout.empty_tile_record
    if not path.is_file():
        return None
    record = read_json_object(path)
    return str(record.get("reason", "")) if record.get("sparse") == hash_path(layout.sparse) else None


def _write_empty_record(layout: ProjectLayout, reason: str) -> None:
    from core.io.json_io import write_json_atomic
    from hybridsplat.manifest import hash_path

    write_json_atomic(layout.empty_tile_record, {"reason": reason, "sparse": hash_path(layout.sparse)})
