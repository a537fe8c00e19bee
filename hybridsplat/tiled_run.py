"""The ``tiles`` stage's work: plan, make the tiles' projects, run them, stitch their products (issue 34).

See :mod:`hybridsplat.stages.tiles` for what the stage is; this module is the sequence, each step in the module
that owns it: :mod:`recon.tiling` (the plan), :mod:`hybridsplat.tile_projects` (a tile's project),
:mod:`hybridsplat.tile_execution` (here or on Ray), :mod:`hybridsplat.tile_cost` (the prediction) and
:mod:`hybridsplat.tile_stitch` (the parent's products).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from hybridsplat.layout import ProjectLayout
from hybridsplat.manifest import Manifest, PeakMemory
from hybridsplat.project_io import sparse_model
from hybridsplat.records import TypedRecord
from hybridsplat.stages.base import StageContext
from hybridsplat.stages.tiles import SeamCheck, StitchedProducts, TilePrediction
from hybridsplat.tile_cost import CostPrediction, TileSize, tile_peak_mb
from hybridsplat.tile_projects import TILE_STAGES, TileJob, TileRun
from recon.tiling import TilePlan


def plan_project_tiles(ctx: StageContext, options: Any) -> TilePlan:
    """The tile plan of the project's sparse model (written to ``tiles/plan.json``)."""
    from hybridsplat.project_io import read_project_model
    from recon.tiling import TileOptions, parse_tiles, plan_tiles, write_tile_plan

    cameras, sparse = read_project_model(ctx.layout, sparse_model(ctx.layout))
    tile_options = TileOptions(
        grid=parse_tiles(options.grid),
        overlap_m=options.overlap_m,
        up=options.up,
        photos_per_tile=options.photos_per_tile,
        points_per_tile=options.points_per_tile,
    )
    plan = plan_tiles(cameras, sparse.positions, tile_options, visibility=sparse.visibility)
    write_tile_plan(ctx.layout.tile_plan, plan)
    return plan


@dataclass(frozen=True)
class TiledRun(TypedRecord):
    """What :func:`run_tiled` did (the tiles stage's record, logs/tiles.json): the plan's ``tiles``, ``grid``
    (``CxR``) and overlap (m), the photos of each tile, the tiles left out (seen by fewer than 2 training photos;
    fusing no point), the tiles run at a time (``workers``) and ``where``, each tile's run, the stitch and the cost
    model's prediction against the measurement."""

    tiles: int = 0
    grid: str = ""
    overlap_m: float = 0.0
    photos_per_tile: tuple[int, ...] = ()
    without_photos: tuple[str, ...] = ()
    without_points: tuple[str, ...] = ()
    workers: int = 1
    where: str = ""
    per_tile: tuple[TileRun, ...] = ()
    stitched: StitchedProducts = field(default_factory=StitchedProducts)
    prediction: TilePrediction | None = None


def run_tiled(ctx: StageContext, options: Any) -> TiledRun:
    """Plan, run every tile, stitch."""
    from hybridsplat.tile_context import training_phases
    from hybridsplat.tile_execution import ExecutionOptions, execution_session
    from hybridsplat.tile_projects import prepare_tile

    layout = ctx.layout
    plan = plan_project_tiles(ctx, options)
    held_out = set(ctx.source.holdout_names)
    jobs: list[tuple[int, TileJob]] = []
    too_few: list[str] = []
    for tile in plan.tiles:
        if len([n for n in tile.photo_names if n not in held_out]) < 2:
            too_few.append(tile.name)  # its core is seen by fewer than two photos: nothing to match depth between
            continue
        jobs.append((tile.index, prepare_tile(layout, plan, tile.index, ctx.config, held_out)))
    execution = ExecutionOptions.of(options)

    phases = None  # the training phases as positions in ``jobs``, for the cost model
    if options.neighbour_context:
        position = {t: k for k, (t, _) in enumerate(jobs)}
        phases = [[position[t] for t in phase] for phase in training_phases(plan, list(position))]
    sizes = tile_sizes(ctx, plan, [t for t, _ in jobs], held_out)
    with PeakMemory(interval_s=0.2, children=True) as memory:
        start = time.perf_counter()
        with execution_session(execution) as workers:  # a cluster's size is known once joined
            prediction = predict_tiles(ctx, sizes, [job for _, job in jobs], workers, phases)
            jobs = [(t, replace(job, memory_mb=tile_peak_mb(size, prediction.rates)))
                    for (t, job), size in zip(jobs, sizes, strict=True)]  # fmt: skip
            ctx.say(
                f"  tiles      {len(jobs)} tiles on {_where(execution, workers)}: predicted {prediction.wall_s:.0f} "
                f"s, peak {prediction.peak_mb:.0f} MB ({prediction.rates.source} rates)"
            )
            results = run_in_phases(ctx, plan, jobs, execution, options.neighbour_context)
        measured_s = time.perf_counter() - start
    empty = {r.tile: r.empty for r in results if r.empty}
    if len(empty) == len(jobs):
        from core.errors import EmptyFusionError

        raise EmptyFusionError(f"no tile fused a point ({len(jobs)} tiles; see their logs)", layout.tiles_dir)
    stitched = stitch_products(ctx, plan, [t for t, job in jobs if job.name not in empty])
    return TiledRun(
        tiles=len(plan.tiles),
        grid=f"{plan.columns}x{plan.rows}",
        overlap_m=plan.overlap_m,
        photos_per_tile=tuple(len(t.photo_ids) for t in plan.tiles),
        without_photos=tuple(too_few),
        without_points=tuple(sorted(empty)),
        workers=workers,
        where=_where(execution, workers),
        per_tile=tuple(results),
        stitched=stitched,
        prediction=TilePrediction(**prediction.to_json(), measured_wall_s=measured_s, measured_peak_mb=memory.peak_mb),
    )


def run_in_phases(
    ctx: StageContext, plan: TilePlan, jobs: list[tuple[int, TileJob]], execution: Any, neighbour_context: bool
) -> list[TileRun]:
    """Run the tiles (``jobs``: plan index and job); their records in the order of ``jobs``. Without
    ``neighbour_context`` every tile runs all its stages at once; with it, the stages before training run in every
    tile at once, then the training stages in :func:`hybridsplat.tile_context.training_phases`, each tile given its
    finished neighbours' splats (:func:`hybridsplat.tile_context.write_neighbour_splats`)."""
    from hybridsplat.tile_context import training_phases, write_neighbour_splats
    from hybridsplat.tile_execution import run_tiles
    from hybridsplat.tile_projects import TRAINING_STAGES

    total = len(jobs) * (2 if neighbour_context else 1)
    finished_tasks = [0]

    def done(name: str, _finished: int, _total: int) -> None:
        finished_tasks[0] += 1
        ctx.progress(f"tiles: {name} done", finished_tasks[0], total)

    ctx.progress("tiles", 0, total)
    if not neighbour_context:
        for _, job in jobs:  # trained alone: a context an earlier run gave the tile is its input no more
            ProjectLayout(job.root).neighbour_splats.unlink(missing_ok=True)
        return run_tiles([job for _, job in jobs], execution, done)
    before = tuple(s for s in TILE_STAGES if s not in TRAINING_STAGES)
    records = {r.tile: r for r in run_tiles([replace(j, stages=before) for _, j in jobs], execution, done)}
    by_index = dict(jobs)
    ready = [t for t, job in jobs if not records[job.name].empty]
    finished: list[int] = []
    for phase in training_phases(plan, ready):
        for t in phase:
            write_neighbour_splats(ctx.layout, plan, t, finished)
        for record in run_tiles([replace(by_index[t], stages=TRAINING_STAGES) for t in phase], execution, done):
            first = records[record.tile]
            records[record.tile] = replace(first, stages={**first.stages, **record.stages})
        finished += phase
    return [records[job.name] for _, job in jobs]


def _where(execution: Any, workers: int) -> str:
    if execution.ray_address:
        return f"the Ray cluster at {execution.ray_address} ({workers} tiles at a time)"
    return f"{execution.workers} Ray workers" if execution.uses_ray else "this process, one at a time"


def tile_sizes(ctx: StageContext, plan: TilePlan, tiles: list[int], held_out: set[str]) -> list[TileSize]:
    """Each tile's size for the cost model: training photos, megapixels a dense photo, training iterations."""
    from hybridsplat.stages import sizes as stage_sizes
    from hybridsplat.stages.train import TrainStage
    from recon.mvs import MvsOptions

    # the photos' pixels as MVS sees them (capped by --max-image-size), as the reference rates were fitted: not the
    # mvs stage's disk estimate, which pads each side by 10 % for undistortion
    largest = stage_sizes.largest(stage_sizes.camera_sizes(sparse_model(ctx.layout)))
    max_size = ctx.config.options("mvs", MvsOptions).max_image_size
    width, height = stage_sizes.capped_size(largest, max_size)
    iterations = int(ctx.config.options("train", TrainStage.Options).training.iterations)
    return [
        TileSize(
            plan.tiles[t].name,
            sum(n not in held_out for n in plan.tiles[t].photo_names),
            width * height / 1e6,
            iterations,
        )  # fmt: skip
        for t in tiles
    ]


def predict_tiles(
    ctx: StageContext, sizes: list[TileSize], jobs: list[TileJob], workers: int, phases: list[list[int]] | None
) -> CostPrediction:
    """The cost model's prediction, with rates fitted to this project's tiles that finished every stage before
    (a resumed or repeated run), else the reference rates; ``phases``: the training phases (positions in
    ``sizes``), None when every tile runs all its stages at once."""
    from hybridsplat.tile_cost import REFERENCE_RATES, fit_rates, predict

    known_sizes, seconds, peaks = [], [], []
    for size, job in zip(sizes, jobs, strict=True):
        path = ProjectLayout(job.root).manifest
        records = Manifest(path).stages if path.is_file() else {}
        ran = [records.get(n) for n in TILE_STAGES]
        if all(r is not None for r in ran) and all(r.finished_at or r.skipped for r in ran):
            known_sizes.append(size)
            seconds.append(sum(r.seconds for r in ran))
            peaks.append(max(r.peak_mb for r in ran))
    rates = fit_rates(known_sizes, seconds, peaks) if known_sizes else REFERENCE_RATES
    import psutil

    return predict(sizes, rates, workers, driver_mb=psutil.Process().memory_info().rss / 2**20, phases=phases)


def stitch_products(ctx: StageContext, plan: TilePlan, tiles: list[int]) -> StitchedProducts:
    """The parent's dense workspace, classified cloud and splats from the tiles (``tiles``: indices in plan order)."""
    from hybridsplat.tile_stitch import gather_depth_maps, stitch_fused, stitch_ply
    from recon.mvs import MvsOptions
    from recon.tiling import seam_check
    from recon.workspace import setup_dense_workspace

    layout = ctx.layout
    subs = {t: ProjectLayout(layout.tile_project(plan.tiles[t].name)) for t in tiles}
    mvs: MvsOptions = ctx.config.options("mvs", MvsOptions)
    setup_dense_workspace(sparse_model(layout), ctx.source.image_dir, layout.dense, mvs.max_image_size)
    maps = gather_depth_maps([subs[t].dense for t in tiles], layout.dense)
    fused = stitch_fused(plan, [(t, subs[t].dense) for t in tiles if subs[t].fused_ply.is_file()], layout.dense)
    classified = [(t, subs[t].classified_points) for t in tiles if subs[t].classified_points.is_file()]
    n_classified = None
    if classified:
        n_classified = stitch_ply(plan, classified, layout.classified_points)[0].kept
        _merge_classify_reports([subs[t].classify_report for t, _ in classified], layout)
    splats = {}
    for key, path_of in (("trained", lambda lay: lay.trained_splats), ("cleaned", lambda lay: lay.cleaned_splats)):
        parts = [(t, path_of(subs[t])) for t in tiles if path_of(subs[t]).is_file()]
        splats[key] = stitch_ply(plan, parts, path_of(layout))[0].kept if parts else 0
    from recon.workspace import read_fused

    positions = read_fused(layout.dense).positions
    seam = None
    if len(positions) >= 2 and len(plan.tiles) > 1:
        found = seam_check(plan, positions)
        seam = SeamCheck(ratio=found.ratio, spacing_inside_m=found.spacing_inside, border_points=found.n_border)
    return StitchedProducts(depth_maps=maps, fused=fused.kept, fused_dropped=fused.dropped, classified=n_classified,
                            trained=splats["trained"], cleaned=splats["cleaned"], seam=seam)  # fmt: skip


def _merge_classify_reports(reports: list[Path], layout: ProjectLayout) -> None:
    """classify/report.json of the parent: the first tile's (its model, classes, threshold), with the counts of the
    stitched cloud and the tiles it came from."""
    from core.io.json_io import read_json_object, write_json_atomic
    from core.io.ply import read_ply

    report = dict(read_json_object(reports[0]))
    cloud = read_ply(layout.classified_points)
    classes = np.asarray(cloud.fields.get("classification", np.zeros(0)), dtype=np.int64)
    needs = np.asarray(cloud.fields.get("needs_splats", np.zeros(0)), dtype=bool)
    report["points"] = len(cloud)
    report["needs_splats"] = int(needs.sum())
    if isinstance(report.get("per_class"), dict):
        names = _class_names(report, layout.classify_report)
        codes, n = np.unique(classes, return_counts=True)
        report["per_class"] = {names.get(int(c), str(int(c))): int(k) for c, k in zip(codes, n, strict=True)}
    report["tiles"] = [str(p.parent.parent.name) for p in reports]
    write_json_atomic(layout.classify_report, json.loads(json.dumps(report)))


def _class_names(report: dict[str, Any], path: Path) -> dict[int, str]:
    stored = report.get("classes")
    if not stored:
        return {}
    from classify.classes import ClassSet

    return {c.code: c.name for c in ClassSet.from_dict(stored, path).classes}
