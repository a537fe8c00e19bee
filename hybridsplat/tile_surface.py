"""The splat-surface points of a tiled run, found tile by tile (issue 34; ``merge --splat-surface``).

Untiled, :func:`fusion.splat_surface.splat_surface_points` renders the fill layer's surface in every training view
inside its region mask, holding every view's depth, normal and colour maps at once, and fuses the depths that agree
across views. Tiled, the merge stage gives each tile (:func:`prepare_tile_surface`) the fill splats, the trusted
MVS points (the front surface of mirrors and glass) and the fused MVS points (the σ model's anchors) that lie in
the tile's bounds (core + overlap), and the tile (:func:`run_tile_surface`: here, or as a Ray task like the tile
stages) finds the points in its own training views, which are every photo that sees its core: a point near a core
border is checked across the same views as untiled, with the overlap's splats rendered around it.
:func:`stitch_tile_surface` keeps each point from the tile whose core holds it.

What differs from untiled: a view's pixel found in one tile may be fused again in the neighbouring tile (each tile
marks only its own views' pixels as used), which the core ownership resolves; and the pixel counts are summed over
tiles, so a pixel of an overlap counts once per tile that rendered it.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from core.gaussians import GaussianSet
from fusion.splat_surface import SplatSurfaceOptions, SplatSurfacePoints
from hybridsplat.layout import ProjectLayout
from hybridsplat.records import TypedRecord, omitted_if_none
from recon.tiling import TilePlan

if TYPE_CHECKING:
    from core.cameras import Cameras
    from hybridsplat.stages.base import StageContext

_ARRAYS = ("positions", "normals", "colours", "sigma", "confidence", "n_views", "reference", "spread", "footprint")


@dataclass(frozen=True)
class TileSurfaceRecord(TypedRecord):
    """One tile's splat-surface points (:func:`run_tile_surface`, its ``record.json``): the points ``found``, the
    pixels per outcome (``counts``, by the outcomes of :class:`fusion.splat_surface.SplatSurfacePoints`), its
    seconds and, as a Ray task, the resources Ray gave it."""

    tile: str = ""
    found: int = 0
    counts: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0
    resources: dict[str, float] | None = omitted_if_none()


@dataclass(frozen=True)
class TileSurfaceJob:
    """One tile's splat-surface points: its name, its project folder (``root``, the files of
    :meth:`ProjectLayout.tile_surface_files`), the parent's folder (its dense cameras and region masks), the
    tile's training views with a region mask (``views``, in the parent's camera order), the options, and the memory
    its Ray task declares (MB; 0: unknown)."""

    name: str
    root: str
    parent: str
    views: tuple[str, ...]
    options: SplatSurfaceOptions
    memory_mb: float = 0.0


def prepare_tile_surface(
    parent: ProjectLayout,
    plan: TilePlan,
    tile: int,
    splats: GaussianSet,
    trusted: np.ndarray,
    anchors: np.ndarray,
    views: Sequence[str],
    options: SplatSurfaceOptions,
) -> TileSurfaceJob:
    """Write tile ``tile``'s inputs into its project folder: the fill ``splats`` (any origin), ``trusted`` and
    ``anchors`` ((N, 3), the cameras' local frame) that lie in its bounds; the job that finds its points."""
    from core.io.gaussian_ply import write_gaussian_ply

    name = plan.tiles[tile].name
    layout = ProjectLayout(parent.tile_project(name))
    files = layout.tile_surface_files()
    files.splats.parent.mkdir(parents=True, exist_ok=True)
    write_gaussian_ply(files.splats, splats.subset(plan.in_bounds(splats.means, tile)))
    np.savez(files.points, trusted=_in_bounds(plan, tile, trusted), anchors=_in_bounds(plan, tile, anchors))
    return TileSurfaceJob(name, str(layout.root), str(parent.root), tuple(views), options)


def _in_bounds(plan: TilePlan, tile: int, points: np.ndarray) -> np.ndarray:
    points = np.asarray(points, np.float64).reshape(-1, 3)
    return points[plan.in_bounds(points, tile)] if len(points) else points


def run_tile_surface(job: TileSurfaceJob) -> TileSurfaceRecord:
    """Find one tile's splat-surface points (in the parent's local frame) and write them; the tile's record
    (points found, pixel counts). A task of :func:`hybridsplat.tile_execution.run_tiles`."""
    import time

    from core.io.gaussian_ply import read_gaussian_ply
    from core.io.json_io import write_json_atomic
    from fusion.splat_surface import front_depths_from_points, splat_surface_points
    from hybridsplat import project_io

    start = time.perf_counter()
    parent = ProjectLayout(job.parent)
    files = ProjectLayout(job.root).tile_surface_files()
    cameras = project_io.dense_cameras(parent, only=set(job.views))
    masks = project_io.read_region_masks(parent, cameras, training=True)
    splats = read_gaussian_ply(files.splats)
    with np.load(files.points) as points:
        trusted, anchors = points["trusted"], points["anchors"]
    masks = {k: m for k, m in masks.items() if m.any() and len(splats)}
    front = front_depths_from_points(trusted, cameras, sorted(masks))
    found = splat_surface_points(splats, cameras, masks, front, job.options, anchors)
    np.savez(files.found, **{k: getattr(found, k) for k in _ARRAYS},
             views=np.array([v.name for v in cameras if v.name in masks]))  # fmt: skip
    record = TileSurfaceRecord(job.name, len(found), dict(found.counts), time.perf_counter() - start)
    write_json_atomic(files.record, record)
    return record


def stitch_tile_surface(
    parent: ProjectLayout, plan: TilePlan, tiles: Sequence[int], views: Sequence[str]
) -> SplatSurfacePoints:
    """The points of ``tiles`` (plan indices whose files exist), each kept from the tile whose core holds it, in
    tile order; ``reference`` re-indexed to ``views`` (the parent's masked views, in camera order); the pixel
    counts summed over the tiles."""
    from core.io.json_io import read_json_object

    index = {name: k for k, name in enumerate(views)}
    parts: dict[str, list[np.ndarray]] = {k: [] for k in _ARRAYS}
    counts: dict[str, int] = {}
    for t in tiles:
        files = ProjectLayout(parent.tile_project(plan.tiles[t].name)).tile_surface_files()
        with np.load(files.found) as found:
            own = plan.owner(found["positions"].reshape(-1, 3)) == t
            tile_views = [str(v) for v in found["views"]]
            for key in _ARRAYS:
                parts[key].append(found[key][own])
            parts["reference"][-1] = np.array([index[tile_views[r]] for r in parts["reference"][-1]], np.int32)
        record = TileSurfaceRecord.from_json(read_json_object(files.record), files.record)
        for key, value in record.counts.items():
            counts[key] = counts.get(key, 0) + value
    if not tiles:
        empty = np.zeros((0, 3))
        return SplatSurfacePoints(empty, empty.copy(), np.zeros((0, 3), np.float32), np.zeros(0), np.zeros(0),
                                  np.zeros(0, np.int32), np.zeros(0, np.int32), counts)  # fmt: skip
    return SplatSurfacePoints(**{k: np.concatenate(v) for k, v in parts.items()}, counts=counts)


def run_tiled_surface(
    ctx: StageContext,
    splats: GaussianSet,
    cameras: Cameras,
    masked: Collection[str],
    trusted: np.ndarray,
    anchors: np.ndarray,
    options: SplatSurfaceOptions,
) -> SplatSurfacePoints:
    """The merge stage's splat-surface points on a tiled project: ``splats`` (the fill layer, any origin) rendered
    tile by tile in the ``masked`` training views of each tile (``cameras``: the dense model, whose local frame the
    plan and ``trusted`` / ``anchors`` share), run like the tile stages (``[tiles]`` workers, ray_address,
    cpus_per_tile) and stitched by core."""
    from hybridsplat.stages.tiles import TilesOptions
    from hybridsplat.tile_execution import ExecutionOptions, run_tiles
    from recon.tiling import read_tile_plan

    layout = ctx.layout
    plan = read_tile_plan(layout.tile_plan)
    local = splats.with_origin(cameras.origin)
    views = [v.name for v in cameras if v.name in masked]
    jobs, indices = [], []
    for tile in plan.tiles:
        seen = set(tile.photo_names)
        tile_views = [n for n in views if n in seen]
        if len(tile_views) <= options.min_agreeing:
            continue  # no pixel of it could be confirmed by enough other views
        jobs.append(prepare_tile_surface(layout, plan, tile.index, local, trusted, anchors, tile_views, options))
        indices.append(tile.index)
    execution = ExecutionOptions.of(ctx.config.options("tiles", TilesOptions))

    def done(name: str, finished: int, total: int) -> None:
        ctx.progress(f"splat surface: tile {name} done", finished, total)

    run_tiles(jobs, execution, done, task=run_tile_surface)
    return stitch_tile_surface(layout, plan, indices, views)
