"""Stage ``tiles``: a large survey split into tiles, each run as a project of its own, the products stitched back.

Off by default (``--tiles off``). With ``--tiles auto|NxM`` the stage plans tiles from the sparse model
(:mod:`recon.tiling`, ``tiles/plan.json``), gives each tile a sub-project (:mod:`hybridsplat.tile_projects`:
``tiles/r0c1/`` with the photos that see its core and the sparse points in its bounds), runs the per-tile stages
(mvs, classify, masks, convert, train, clean) in each, one by one or as Ray tasks (:mod:`hybridsplat.tile_execution`,
``--workers``, ``--ray-address``), and stitches their products into the parent by core ownership
(:mod:`hybridsplat.tile_stitch`): ``dense/`` (the parent's undistorted photos, the tiles' depth maps, the stitched
fused cloud), ``classify/points.ply``, ``splats/trained.ply`` and ``splats/cleaned.ply``. The parent's mvs,
classify, train and clean stages are then skipped ("made per tile"); its masks and convert stages run on the
stitched cloud, and every later stage on the whole scene as untiled.

Before the tiles run, the stage prints the cost model's prediction of wall time and peak memory for the workers
given (:mod:`hybridsplat.tile_cost`) and records it beside what happened. The tiles train in two checkerboard
phases, the second with the first's splats frozen in its overlap (:mod:`hybridsplat.tile_context`; ``--no-tile-context``
trains every tile alone). The ``appearance`` stage then refines the survey layer tile by tile
(:mod:`hybridsplat.tile_appearance`); the background layer is trained on the whole scene after the stitch.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hybridsplat.project_io import sparse_model
from hybridsplat.records import TypedRecord
from hybridsplat.stages.base import CliOption, ReportSection, Stage, StageContext, StageResult, omitted_if_none


@dataclass(frozen=True)
class TilesOptions:
    """Options of the ``tiles`` stage.

    grid: ``off`` (one process on the whole scene), ``auto`` or ``NxM`` (N columns along x, M rows along y; see
    docs/tiling.md). overlap_m: metres each core grows by on every side (None: 10 % of the core's shorter side, at
    least 5 sparse spacings). up: ``z`` (surveys, georeferenced blocks) or ``pca`` (façades, object orbits).
    photos_per_tile / points_per_tile: what ``auto`` aims a tile at.
    workers: tiles run at a time (≤ 1: one by one in this process, no Ray; N > 1: a local Ray instance of N CPUs);
    ray_address: a running Ray cluster to join instead (``workers`` is then unused: the cluster runs its CPUs over
    ``cpus_per_tile`` tiles at once, which the cost model assumes); cpus_per_tile: CPUs (threads) each tile's task
    declares.
    These three decide how the tiles run, not what they make (a change reruns only the stitch: the tiles' own
    stages stay up to date). neighbour_context: the tiles train in two checkerboard phases, the second with the
    first's splats in its overlap frozen as context (:mod:`hybridsplat.tile_context`); off: every tile trains alone
    and at once.
    """

    grid: str = "off"
    overlap_m: float | None = None
    up: str = "z"
    photos_per_tile: int = 200
    points_per_tile: int = 200_000
    workers: int = 1
    ray_address: str = ""
    cpus_per_tile: int = 1
    neighbour_context: bool = True

    def __post_init__(self) -> None:
        from recon.tiling import parse_tiles

        parse_tiles(self.grid)  # a ConfigError naming the option for anything but off, auto, NxM


@dataclass(frozen=True)
class SeamCheck(TypedRecord):
    """The stitched cloud's spacing across the tiles' core borders against inside them (``ratio``; 1: no seam),
    the spacing inside (m) and the points near a border (:func:`recon.tiling.seam_check`)."""

    ratio: float = math.nan
    spacing_inside_m: float = math.nan
    border_points: int = 0


@dataclass(frozen=True)
class StitchedProducts(TypedRecord):
    """What the stitch made in the parent (:func:`hybridsplat.tiled_run.stitch_products`): the depth maps gathered,
    the fused points kept and those dropped per tile (outside its core), the classified points (None without a
    tile's), the trained and cleaned splats, and the seam check (None for one tile or fewer than 2 points)."""

    depth_maps: int = 0
    fused: int = 0
    fused_dropped: tuple[int, ...] = ()
    classified: int | None = omitted_if_none()
    trained: int = 0
    cleaned: int = 0
    seam: SeamCheck | None = omitted_if_none()


@dataclass(frozen=True)
class TilePrediction(TypedRecord):
    """The cost model's prediction for the run (:class:`hybridsplat.tile_cost.CostPrediction`: ``workers``, wall
    time s, peak memory MB, seconds per tile and the ``rates`` by their field names) and what was measured."""

    workers: int = 1
    wall_s: float = 0.0
    peak_mb: float = 0.0
    tile_seconds: tuple[float, ...] = ()
    rates: dict[str, Any] = field(default_factory=dict)
    measured_wall_s: float = 0.0
    measured_peak_mb: float = 0.0


@dataclass(frozen=True)
class TilesResult(StageResult):
    """What the tiles stage made: ``tiles`` tiles of a ``grid`` (``CxR``) with their photos, what the stitch made,
    the cost model's prediction against the measurement, the tiles run at a time (``workers``) and ``where`` they
    ran, and the tiles left out: seen by fewer than 2 training photos, or fusing no point."""

    tiles: int = 0
    grid: str = ""
    photos_per_tile: tuple[int, ...] = ()
    stitched: StitchedProducts = field(default_factory=StitchedProducts)
    prediction: TilePrediction | None = None
    workers: int = 1
    where: str = ""
    without_photos: tuple[str, ...] = ()
    without_points: tuple[str, ...] = ()


def tiling_on(ctx: StageContext) -> bool:
    """Whether this project runs tiled (``[tiles] grid`` is not off)."""
    from recon.tiling import parse_tiles

    return parse_tiles(ctx.config.options("tiles", TilesOptions).grid) is not None


class TilesStage(Stage):
    name = "tiles"
    Options = TilesOptions
    Result = TilesResult
    title = "tiles"
    uses_seed = True  # through its tile sub-projects' config
    run_options = (
        CliOption("grid", "--tiles", help="Split the survey into tiles: off | auto | NxM (docs/tiling.md)."),
        CliOption("overlap_m", "--tile-overlap", help="Metres each tile's core grows by (default: 10 % of a core)."),
        CliOption("workers", "--workers", help="Tiles at a time (N > 1: a local Ray instance of N CPUs)."),
        CliOption("ray_address", "--ray-address", help="Run the tiles on this Ray cluster (host:port)."),
        CliOption("neighbour_context", "--tile-context/--no-tile-context",
                  help="Train tiles in two phases, the second with its neighbours' splats frozen in the overlap."),
    )  # fmt: skip

    def inputs(self, ctx: StageContext) -> list[Path]:
        from classify.run import resolve_model_path

        model = resolve_model_path(ctx.config.options("classify", _options_type("classify")).model)
        return [
            sparse_model(ctx.layout),
            ctx.source.image_dir,
            *([model] if model is not None and model.is_file() else []),
        ]

    def outputs(self, ctx: StageContext) -> list[Path]:
        """The plan and record; while tiling is on also the stitched products, which are the untiled stages'
        outputs otherwise (a skipped stage's outputs are removed: an untiled project keeps them)."""
        layout = ctx.layout
        own = [layout.tile_plan, layout.record(self.name)]
        if not tiling_on(ctx):
            return own
        return [layout.dense, layout.classified_points, layout.classify_report, layout.trained_splats,
                layout.cleaned_splats, *own]  # fmt: skip

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of the tiles' projects and the parent's stitched products: each tile may see every photo, so each
        is bounded by what the untiled mvs, classify, masks, train and clean stages would write (their own
        estimates; classify's from the MVS estimate's cloud, as it does not exist yet), and the stitched products
        by one more such set (the tiles' projects under ``tiles/`` are not the stage's outputs, which a rerun
        removes: they stay for a resumed run, but they are counted here)."""
        from hybridsplat.stages import stage_named

        per_tile = sum(stage_named(n).expected_bytes(ctx) for n in ("mvs", "masks", "train", "clean"))
        per_tile += 2 * stage_named("mvs").expected_bytes(ctx)  # classified cloud and Gaussians: within a fused's
        return (_tile_count(ctx, ctx.options(self)) + 1) * per_tile

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        """The per-tile stages' options decide the stitched products too."""
        from hybridsplat.config import options_digest
        from hybridsplat.tile_projects import TILE_STAGES

        digests = {n: options_digest(ctx.config.options(n, _options_type(n))) for n in TILE_STAGES}
        return {"held_out": sorted(ctx.source.holdout_names), "tile_stages": digests}

    def needs(self, ctx: StageContext) -> str | None:
        return None if tiling_on(ctx) else "off (run --tiles auto|NxM to split a large survey into tiles)"

    def run(self, ctx: StageContext) -> TilesResult:
        from core.io.json_io import write_json_atomic
        from hybridsplat.tiled_run import run_tiled

        start = time.perf_counter()
        run = run_tiled(ctx, ctx.options(self))
        write_json_atomic(ctx.layout.record(self.name), {**run.as_dict(), "seconds": time.perf_counter() - start})
        return TilesResult(
            tiles=run.tiles,
            grid=run.grid,
            photos_per_tile=run.photos_per_tile,
            stitched=run.stitched,
            prediction=run.prediction,
            workers=run.workers,
            where=run.where,
            without_photos=run.without_photos,
            without_points=run.without_points,
        )

    def summary(self, result: TilesResult) -> str:
        stitched = result.stitched
        return (
            f"{result.tiles} tiles ({result.grid}) on {result.where or result.workers}: "
            f"{stitched.fused} fused points, {stitched.cleaned} splats stitched" + _left_out(result)
        )

    def report_section(self, result: TilesResult) -> ReportSection | None:
        if not result.tiles:
            return None
        pred = result.prediction
        lines = [
            f"{result.tiles} tiles ({result.grid}), photos per tile {list(result.photos_per_tile)}, "
            f"run on {result.where or result.workers}{_left_out(result)}.",
        ]
        if pred is not None:
            lines.append(
                f"Cost model: predicted {pred.wall_s:.0f} s and {pred.peak_mb:.0f} MB peak; "
                f"measured {pred.measured_wall_s:.0f} s and {pred.measured_peak_mb:.0f} MB."
            )
        return ReportSection("Tiles", tuple(lines))


def _left_out(result: TilesResult) -> str:
    """Which tiles added nothing, and why (empty when every tile did)."""
    parts = []
    if result.without_photos:
        parts.append(f"seen by fewer than 2 photos: {', '.join(result.without_photos)}")
    if result.without_points:
        parts.append(f"fused no point: {', '.join(result.without_points)}")
    return f" (tiles left out, {'; '.join(parts)})" if parts else ""


def _tile_count(ctx: StageContext, options: TilesOptions) -> int:
    """The number of tiles the grid asks for (``auto``: what the photo and sparse point counts need)."""
    import math

    from hybridsplat.stages import sizes
    from recon.tiling import parse_tiles

    grid = parse_tiles(options.grid)
    if grid is None:
        return 0
    if not grid.auto:
        return int(grid.columns) * int(grid.rows)
    photos = sizes.model_count(sparse_model(ctx.layout), "images") or len(ctx.source.spec.image_names)
    points = sizes.model_count(sparse_model(ctx.layout), "points3D")
    return max(1, math.ceil(photos / options.photos_per_tile), math.ceil(points / options.points_per_tile))


def _options_type(stage: str) -> type:
    from hybridsplat.stages import stage_named

    return stage_named(stage).Options
