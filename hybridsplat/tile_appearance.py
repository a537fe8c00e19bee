"""The appearance stage of a tiled run: the survey layer refined tile by tile (issue 34).

Untiled, :func:`fusion.appearance.refine_survey_appearance` fits the whole survey layer, with the fill and
background layers beside it, to every pixel of every training photo, so its memory and time grow with the block.
Tiled, the parent's appearance stage gives each tile (:func:`prepare_tile_appearance`) the parent's survey Gaussians
that do not need splats and its cleaned fill splats that lie in the tile's bounds (core + overlap), in the parent's
order. The tile (:func:`run_tile_appearance`: here, or as a Ray task like the tile stages) refines both on its
training photos beside the background layer, which stays frozen, inside the pixels its own Gaussians cover
(:func:`covered_pixels`: α ≥ :data:`COVERED_ALPHA` rendered as converted): a pixel of content beyond the tile's
bounds, which the tile does not hold, is not fitted. :func:`stitch_tile_appearance` then gives each Gaussian the
attributes refined by the tile whose core holds it, as the tile stages' stitch does with their products.

What differs from the untiled fit: the background layer is not refined (splats/background_refined.ply is the layer as
trained: its pixels lie beyond every tile's content), and a Gaussian near a core border is fitted beside its own
tile's content only (the overlap's Gaussians as the tile refines them, not as their owner does).

A tile whose refined files and record match its inputs (the files the parent wrote, the background layer, its photos,
the options and the seed) is not fitted again, so a rerun of an interrupted stage redoes only the unfinished tiles.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from core.cameras import Cameras
from core.errors import DataError
from core.gaussians import GaussianSet
from fusion.appearance import AppearanceOptions, AppearanceResult, assign_attributes
from hybridsplat.layout import ProjectLayout, TileAppearanceFiles
from hybridsplat.stages.appearance import TileAppearanceRecord
from recon.tiling import TilePlan

if TYPE_CHECKING:
    from hybridsplat.stages.base import StageContext

COVERED_ALPHA = 0.5
"""A pixel is fitted in a tile when the tile's own Gaussians, rendered as converted, cover it at least this much: the
rest shows content beyond the tile's bounds (or the background, which every tile keeps frozen). Set by reasoning, not
by a measurement: where two layers meet at half coverage, the pixel is the nearer one's."""


@dataclass(frozen=True)
class TileAppearanceJob:
    """One tile's part of the appearance stage: its name, its project folder (``root``, the files of
    :meth:`ProjectLayout.tile_appearance_files`), the parent's folder (``parent``: its photos and background layer),
    the tile's training photos, the stage's options, the seed, whether the background layer is beside it, and the
    memory its Ray task declares (MB; 0: unknown)."""

    name: str
    root: str
    parent: str
    photos: tuple[str, ...]
    options: AppearanceOptions
    seed: int
    with_background: bool
    memory_mb: float = 0.0


def rows_in_tile(plan: TilePlan, tile: int, gaussians: GaussianSet | None) -> np.ndarray:
    """Indices of ``gaussians`` (local frame) in tile ``tile``'s bounds, ascending; none for None."""
    if gaussians is None or len(gaussians) == 0:
        return np.zeros(0, np.int64)
    return np.flatnonzero(plan.in_bounds(gaussians.means, tile))


def prepare_tile_appearance(
    parent: ProjectLayout,
    plan: TilePlan,
    tile: int,
    survey: GaussianSet,
    fill: GaussianSet | None,
    photos: Sequence[str],
    options: AppearanceOptions,
    seed: int,
    with_background: bool,
) -> TileAppearanceJob:
    """Write tile ``tile``'s inputs (the ``survey`` and ``fill`` Gaussians in its bounds) into its project folder;
    the job that refines them."""
    from core.io.gaussian_ply import write_gaussian_ply

    name = plan.tiles[tile].name
    layout = ProjectLayout(parent.tile_project(name))
    files = layout.tile_appearance_files()
    files.survey.parent.mkdir(parents=True, exist_ok=True)
    write_gaussian_ply(files.survey, survey.subset(rows_in_tile(plan, tile, survey)))
    if fill is not None:
        write_gaussian_ply(files.fill, fill.subset(rows_in_tile(plan, tile, fill)))
    else:
        files.fill.unlink(missing_ok=True)
    return TileAppearanceJob(name, str(layout.root), str(parent.root), tuple(photos), options, seed, with_background)


def covered_pixels(cameras: Cameras, content: GaussianSet, least_alpha: float = COVERED_ALPHA) -> dict[str, np.ndarray]:
    """Photo name → (H, W) bool at its camera's size: the pixels ``content`` (rendered as it is, black behind)
    covers at α ≥ ``least_alpha``."""
    from fusion.render.scene import render_gaussian_set

    masks = {}
    for view in cameras:
        camera = cameras.cameras[view.camera_id]
        rendered = render_gaussian_set(content, camera, view, cameras_origin=cameras.origin)
        masks[view.name] = rendered.alpha.numpy() >= least_alpha
    return masks


def run_tile_appearance(job: TileAppearanceJob) -> TileAppearanceRecord:
    """Refine one tile's survey (and fill) Gaussians; the tile's record (counts, seconds; ``cached`` when its files
    were up to date). A task of :func:`hybridsplat.tile_execution.run_tiles`: small values in and out."""
    from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply
    from core.io.json_io import read_json_object, write_json_atomic
    from hybridsplat import project_io
    from hybridsplat.manifest import PeakMemory

    files = ProjectLayout(job.root).tile_appearance_files()
    key = _inputs_key(job, files)
    if files.record.is_file() and files.survey_refined.is_file():
        record = read_json_object(files.record)
        if record.get("inputs") == key and (files.fill_refined.is_file() or not files.fill.is_file()):
            counts = TileAppearanceRecord.from_json(record.get("counts"), files.record, "counts")
            return replace(counts, tile=job.name, seconds=0.0, cached=True)
    start = time.perf_counter()
    files.record.unlink(missing_ok=True)
    with PeakMemory(interval_s=0.2) as memory:
        parent = ProjectLayout(job.parent)
        cameras, images = project_io.read_training_photos(parent, only=set(job.photos))
        survey = read_gaussian_ply(files.survey)
        fill = read_gaussian_ply(files.fill) if files.fill.is_file() else None
        background = read_gaussian_ply(parent.background_splats) if job.with_background else None
        own = [g.with_origin(survey.origin) for g in (survey, fill) if g is not None and len(g)]
        masks = covered_pixels(cameras, GaussianSet.concatenate(own)) if own else {}
        result = _refine(cameras, images, masks, survey, fill, background, job)
        write_gaussian_ply(files.survey_refined, result.gaussians)
        if fill is not None:
            write_gaussian_ply(files.fill_refined, result.context if result.context is not None else fill)
    counts = TileAppearanceRecord(
        peak_mb=round(memory.peak_mb, 1),
        survey_gaussians=len(survey),
        fill_gaussians=len(fill) if fill is not None else 0,
        photos=len(images),
        covered_share=float(np.mean([m.mean() for m in masks.values()])) if masks else 0.0,
        iterations=int(result.counts.get("iterations", 0)),
        holdout_psnr_db=result.counts.get("holdout_psnr_db"),
    )
    seconds = time.perf_counter() - start
    # the tile's file: its inputs' digest and what it made (the record less its name, seconds and cached flag)
    kept = {k: v for k, v in counts.as_dict().items() if k not in ("tile", "seconds", "cached")}
    write_json_atomic(files.record, json.loads(json.dumps({"inputs": key, "counts": kept, "seconds": seconds})))
    return replace(counts, tile=job.name, seconds=seconds, cached=False)


def _refine(
    cameras: Cameras,
    images: dict[str, np.ndarray],
    masks: dict[str, np.ndarray],
    survey: GaussianSet,
    fill: GaussianSet | None,
    background: GaussianSet | None,
    job: TileAppearanceJob,
) -> AppearanceResult:
    """The tile's fit: ``survey`` refined beside ``fill`` (refined too with ``refine_context``), the background
    fixed; a tile without survey Gaussians keeps what it has."""
    from fusion.appearance import refine_survey_appearance

    if len(survey) == 0 or not any(m.any() for m in masks.values()):
        return AppearanceResult(survey, None, {"iterations": 0}, None)
    context = fill if fill is not None and len(fill) else None
    return refine_survey_appearance(cameras, images, survey, context, job.options, job.seed, masks=masks,
                                    fixed=background)  # fmt: skip


def _inputs_key(job: TileAppearanceJob, files: TileAppearanceFiles) -> str:
    """A digest of everything the tile's fit reads: its input files, the background layer, the photos (names and
    the dense workspace's images), the options and the seed."""
    from hybridsplat.manifest import hash_path

    parent = ProjectLayout(job.parent)
    digest = hashlib.sha256()
    parts = [hash_path(files.survey), hash_path(files.fill),
             hash_path(parent.background_splats) if job.with_background else "none",
             hash_path(parent.dense_workspace.sparse), *sorted(job.photos),
             *(hash_path(parent.dense_workspace.images / n) for n in sorted(job.photos)),
             repr(job.options), str(job.seed)]  # fmt: skip
    for part in parts:
        digest.update(part.encode() + b"\0")
    return digest.hexdigest()


@dataclass(frozen=True)
class StitchedAppearance:
    """The survey Gaussians refined tile by tile (rows of the parent's survey subset, positions bit for bit), the
    fill refined likewise (rows of the parent's fill; None without one), how many of each no tile refined
    (``fill_unrefined`` None without a fill), and, from :func:`run_tiled_appearance`, each tile's record, the most
    steps a tile took and the peak memory with the Ray workers (MB)."""

    survey: GaussianSet
    fill: GaussianSet | None
    survey_unrefined: int
    fill_unrefined: int | None
    per_tile: tuple[TileAppearanceRecord, ...] = ()
    iterations: int = 0
    peak_mb_with_workers: float = 0.0


def stitch_tile_appearance(
    parent: ProjectLayout,
    plan: TilePlan,
    tiles: Sequence[int],
    survey: GaussianSet,
    fill: GaussianSet | None,
    degree: int,
) -> StitchedAppearance:
    """Each Gaussian of ``survey`` and ``fill`` (the parent's sets given to :func:`prepare_tile_appearance`) with
    the attributes refined by the tile whose core holds it (``tiles``: plan indices whose refined files exist), SH
    at ``degree``; a Gaussian of no such core keeps its own (counted as unrefined). Raises :class:`DataError` when a
    tile's refined file does not hold its inputs' rows at their positions."""
    from core.io.gaussian_ply import read_gaussian_ply

    layers = {"survey": survey, "fill": fill}
    # fancy-index subsets copy (a slice would share the inputs' arrays, which the rows below are written into)
    out = {k: g.subset(np.arange(len(g))).with_sh_degree(max(degree, g.sh_degree))
           for k, g in layers.items() if g is not None}  # fmt: skip
    refined = {k: np.zeros(len(g), bool) for k, g in out.items()}
    for t in tiles:
        files = ProjectLayout(parent.tile_project(plan.tiles[t].name)).tile_appearance_files()
        for key, path in (("survey", files.survey_refined), ("fill", files.fill_refined)):
            if key not in out:
                continue
            rows = rows_in_tile(plan, t, layers[key])
            part = read_gaussian_ply(path) if len(rows) else None
            if part is None:
                continue
            if len(part) != len(rows) or not _same_positions(
                part.with_origin(out[key].origin).means, out[key].means[rows]
            ):
                raise DataError(f"its {len(part)} Gaussians are not the {len(rows)} the tile was given", path)
            own = plan.owner(out[key].means[rows]) == t
            assign_attributes(out[key], rows[own], part.subset(np.flatnonzero(own)).with_sh_degree(out[key].sh_degree))
            refined[key][rows[own]] = True
    unrefined = {k: int((~r).sum()) for k, r in refined.items()}
    return StitchedAppearance(out["survey"], out.get("fill"), unrefined["survey"], unrefined.get("fill"))


def _same_positions(a: np.ndarray, b: np.ndarray, tolerance_m: float = 1e-3) -> bool:
    """Whether two (N, 3) position arrays are the same rows: equal to the files' float32 rounding (a Gaussian PLY
    stores local float32 positions), far below any spacing between points."""
    return a.shape == b.shape and (len(a) == 0 or float(np.abs(a - b).max()) <= tolerance_m)


def tile_budget(options: AppearanceOptions, tile_photos: int, all_photos: int) -> AppearanceOptions:
    """``options`` for a tile of ``tile_photos`` of the block's ``all_photos`` training photos: the steps the untiled
    fit would spend on the block (:func:`fusion.appearance.step_budget`) in the tile's share of its photos, so that
    a photo, and a Gaussian it shows, gets as many steps as untiled (at least one; the early stop as untiled, within
    those steps)."""
    from fusion.appearance import step_budget

    steps = max(1, round(step_budget(options, all_photos) * tile_photos / max(all_photos, 1)))
    training = replace(options.training, iterations=steps, min_iterations=min(options.training.min_iterations, steps))
    return replace(options, max_passes=0.0, training=training)


def run_tiled_appearance(
    ctx: StageContext, survey: GaussianSet, fill: GaussianSet | None, with_background: bool,
    options: AppearanceOptions,
) -> StitchedAppearance:  # fmt: skip
    """The appearance stage's fit on a tiled project: ``survey`` (the parent's survey Gaussians that do not need
    splats) and ``fill`` (its cleaned splats; None without) refined tile by tile on the tiles' training photos, the
    background layer frozen beside them when ``with_background``, run like the tile stages (``[tiles]`` workers,
    ray_address, cpus_per_tile) and stitched by core, with each tile's record."""
    from hybridsplat.manifest import PeakMemory
    from hybridsplat.stages.tiles import TilesOptions
    from hybridsplat.tile_execution import ExecutionOptions, run_tiles
    from recon.tiling import read_tile_plan

    layout = ctx.layout
    plan = read_tile_plan(layout.tile_plan)
    held_out = set(ctx.source.holdout_names)
    owners = plan.owner(survey.means)
    training_photos = len({n for tile in plan.tiles for n in tile.photo_names if n not in held_out})
    jobs, indices = [], []
    for tile in plan.tiles:
        photos = [n for n in tile.photo_names if n not in held_out]
        if len(photos) < 2 or not (owners == tile.index).any():
            continue  # nothing to fit to, or no survey Gaussian of its own: its neighbours' rows stay theirs
        tile_options = tile_budget(options, len(photos), training_photos)
        jobs.append(prepare_tile_appearance(layout, plan, tile.index, survey, fill, photos, tile_options,
                                            ctx.config.seed, with_background))  # fmt: skip
        indices.append(tile.index)
    execution = ExecutionOptions.of(ctx.config.options("tiles", TilesOptions))
    ctx.progress("appearance: tiles", 0, len(jobs))

    def done(name: str, finished: int, total: int) -> None:
        ctx.progress(f"appearance: tile {name} done", finished, total)

    with PeakMemory(interval_s=0.2, children=True) as memory:  # the Ray workers' memory too
        records = run_tiles(jobs, execution, done, task=run_tile_appearance)
    stitched = stitch_tile_appearance(layout, plan, indices, survey, fill, options.training.sh_degree)
    return replace(stitched, per_tile=tuple(records), peak_mb_with_workers=round(memory.peak_mb, 1),
                   iterations=max((r.iterations for r in records), default=0))  # fmt: skip
