"""Out-of-core classification of a dense cloud with bounded memory (issue 34): x-y cells with halos.

:func:`classify_stream` writes the ``classify/points.ply`` that :func:`classify.run.write_classified` writes for
:func:`classify.run.classify_cloud` (same features, model, threshold; byte for byte, see below) for clouds larger
than memory. The input is a :class:`core.io.point_stream.PointSource` (``recon.workspace.fused_source``: the fused
cloud with its visibility). Passes (the source gives the same points in the same order every time):

1. scan: count, bounding box, attributes, finite coordinates.
2. bucket: every point (position, index, colour, normal, visibility) into the file of its cell of a 2-D x-y grid
   (:class:`eval.c2c_stream.Grid`) and into the halo files of the neighbouring cells within ``halo`` of it.
3. spacing: per cell, the finest level's k − 1 nearest others of the cell's own points among cell + halo (the
   in-memory search, :func:`classify.features.geometric.level_neighbours`); each point's nearest non-zero distance
   to a file; then their exact median (:func:`fusion.convert_stream.order_statistic`, a radix selection) — the
   spacing :func:`classify.features.geometric.spacing_from_neighbours` gives on the whole cloud.
4. features and prediction: per cell, :func:`classify.features.compute_features` on cell + halo with the whole
   cloud's box and spacing (:class:`classify.features.WholeCloud`: the Morton order of the points, the voxels and
   ground columns of the coarse levels and the spacing are the whole cloud's), then the model (and its smoothing)
   on those rows; the cell's own rows are kept (classification, probability, needs_splats) in a result file.
5. output: one pass over the source in its order, each chunk with its points' results appended to the PLY (the
   rows and header of :func:`core.io.ply.write_ply`), and the seeded sample of points the classes figure draws.

Exactness. A point's features depend on its neighbourhoods only, and the cell's points are sorted by their
original index before the (stable) Morton sort, so they meet in the whole cloud's relative order (same sums in the
same order). A loaded point's finest neighbourhood is exact when its k − 1-th distance is within the room the
loaded region leaves around it (``halo`` + its distance to the edges its cell shares, or ``halo`` − its distance
to the cell for a halo point); a coarse level's centroid when every voxel column within max(its k − 1-th
distance, a voxel) of it lies wholly in the loaded region (then its voxel, its neighbours and its 3 × 3 ground
columns are complete). With ``smooth_passes`` P the probabilities of a cell's point read those of its neighbours P
steps away: those must be exact too. A cell with any point it cannot prove is done again from the source with
twice the halo (counted as ``regrown``), until it can (at the latest when the halo spans the cloud). What is not
exact: where a point has several distinct neighbours at exactly its k-th distance (regular grids), the search may
pick another of them than the whole-cloud search (the in-memory grid and k-d tree searches differ the same way);
a column of non-finite features is refused per cell (more than 1 % of a cell's points) instead of per cloud.
The random forest sums its trees' probabilities in the order its threads finish, in memory as here.

Memory: ``memory_limit_mb`` sets the cell size, the chunk size and the photos kept in memory (:func:`plan_memory`).
Disk (``work_dir``): cells and halos (:func:`temp_bytes`), removed after.
Units: metres; positions float64 in the source's local frame.
"""

from __future__ import annotations

import math
import resource
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from os import PathLike
from pathlib import Path
from typing import ClassVar

import numpy as np

from classify.classes import ClassSet
from classify.features import FeatureOptions, FeatureTable, ViewData, WholeCloud, compute_features
from classify.features.geometric import level_neighbours, voxel_downsample
from classify.model import ClassifierModel, Prediction
from core.constraints import Constrained, Constraints, Interval, NoneOr
from core.errors import ConfigError, DataError
from core.io.atomic import atomic_path
from core.io.origin import remove_origin, write_origin
from core.io.point_stream import PointSource, rechunk
from core.pointcloud import PointCloud
from eval.c2c_stream import CellFiles, Grid, chunk_results, memory_work_mb

BASE_MB = 640.0
"""Memory taken before any point (MiB): the interpreter, numpy/numba/scipy/scikit-learn, the model, compiled kernels."""
MIN_WORK_MB = 64.0
"""The least memory beyond :data:`BASE_MB` the streamed classification works in (MiB)."""
_LOADED_BYTES = 2048
"""Bytes a loaded point (cell or halo) takes while its features are computed: the sorted copies, three levels'
neighbour lists and eigen results, the feature columns and table, the probabilities (bench/bench_classify_stream.py,
1 M points, shipped model: 770 MiB peak under a 1 024 MiB limit with 88 k points loaded)."""
_CHUNK_BYTES = 256
"""Bytes a point of an output chunk takes: the PointCloud, its visibility, the PLY rows."""
_RECORD_BYTES = 51
"""Bytes of a point's record in the cell files (position, index, visibility count, colour, normal), its image ids
apart (8 bytes each)."""
_HALO_VOXELS = 5.0
"""The halo in voxels of the coarsest level: its k-NN (~2.3 voxels for 16 on a surface), a voxel of alignment
and the ground columns; cells that cannot prove a point are redone with twice the halo."""
_RESULT = np.dtype([("cls", "u1"), ("prob", "<f4"), ("needs", "u1")])


@dataclass(frozen=True)
class ClassifyPlan:
    """Sizes derived from a memory limit (MiB): points a cell holds with its halo, points a chunk, photos cached."""

    memory_limit_mb: float
    points_per_cell: int
    chunk_size: int
    cache_bytes: int


def plan_memory(memory_limit_mb: float) -> ClassifyPlan:
    """Cell, chunk and photo-cache sizes for a peak resident memory of about ``memory_limit_mb`` (MiB).

    Of what is left above :data:`BASE_MB`, 50 % goes to a cell with its halo, 15 % to an output chunk, 20 % to the
    cached photos and depth maps; the rest is slack for denser cells. Raises :class:`ConfigError` naming the value
    when less than :data:`MIN_WORK_MB` would be left."""
    work = memory_work_mb(
        memory_limit_mb,
        BASE_MB,
        MIN_WORK_MB,
        "the streamed classification",
        "the interpreter, libraries and model",
        "a cell and a chunk",
    )
    work_bytes = work * 2**20
    cell = max(1000, int(0.5 * work_bytes / _LOADED_BYTES))
    chunk = max(1000, int(0.15 * work_bytes / _CHUNK_BYTES))
    return ClassifyPlan(float(memory_limit_mb), cell, chunk, int(0.2 * work_bytes))


def temp_bytes(points: int, vis_bytes: int) -> int:
    """Temporary bytes (disk) of a streamed classification of ``points`` points whose ``fused.ply.vis`` has
    ``vis_bytes`` bytes (4 a count, 4 an image id; 8 an id in the cell files): each point's record and ids in its
    cell and in at most 3 halos (cells are at least 2 halos wide: a cell with its halo covers at most 4 cells'
    area), its spacing (8) and its result (6)."""
    return 4 * (_RECORD_BYTES * points + 2 * vis_bytes) + 14 * points


def photo_cache_size(views: ViewData, plan: ClassifyPlan) -> int:
    """How many photos (and as many depth maps) fit the plan's cache: its bytes over an (H, W, 3) uint8 photo and
    an (H, W) float32 depth map of the largest camera; at least 1."""
    largest = max((c.width * c.height for c in views.cameras.cameras.values()), default=1)
    return max(1, plan.cache_bytes // (7 * largest))


@dataclass(frozen=True)
class ClassifyStreamOptions(Constrained):
    """How :func:`classify_stream` works: ``memory_limit_mb`` (MiB) sets the sizes (:func:`plan_memory`) unless
    ``points_per_cell`` / ``chunk_size`` are given; ``halo`` (metres) defaults to :data:`_HALO_VOXELS` coarsest
    voxels; ``work_dir`` holds the temporary cell files (a temporary folder inside it)."""

    memory_limit_mb: float
    points_per_cell: int | None = None
    chunk_size: int | None = None
    halo: float | None = None
    work_dir: Path | None = None

    constraints: ClassVar[Constraints] = {
        "points_per_cell": NoneOr(Interval(int, 1, None)),
        "chunk_size": NoneOr(Interval(int, 1, None)),
    }

    def plan(self) -> ClassifyPlan:
        plan = plan_memory(self.memory_limit_mb)
        return replace(plan, points_per_cell=self.points_per_cell or plan.points_per_cell,
                       chunk_size=self.chunk_size or plan.chunk_size)  # fmt: skip


@dataclass
class StreamedClassification:
    """What :func:`classify_stream` did: ``points``; ``spacing`` (metres, the whole cloud's); ``per_code``: class code
    → points; ``needs_splats``: points that need splats; the feature names; the ``grid`` and ``halo`` (metres);
    ``regrown``: times a cell was redone from the source with twice its halo; ``max_loaded``: the most points a
    cell held with its halo; ``sample``: (positions (S, 3) float64, codes (S,) uint8) of the points the classes
    figure draws; ``peak_rss_mb``: the process's peak resident memory (MiB, ``ru_maxrss``, whatever it held before
    included)."""

    points: int
    spacing: float
    per_code: dict[int, int]
    needs_splats: int
    feature_names: tuple[str, ...]
    grid: Grid
    halo: float
    regrown: int
    max_loaded: int
    sample: tuple[np.ndarray, np.ndarray]
    peak_rss_mb: float = 0.0
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def cells(self) -> int:
        return self.grid.nx * self.grid.ny


# -- the work: what every cell needs ----------------------------------------------------------------------------


@dataclass
class _Job:
    """Everything the cells share: the source, grid, options, model, views and the whole cloud's values."""

    source: PointSource
    grid: Grid
    halo: float
    options: FeatureOptions
    model: ClassifierModel | None
    views: ViewData | None
    classes: ClassSet
    threshold: float
    count: int
    lo: np.ndarray
    hi: np.ndarray
    origin: np.ndarray
    chunk_size: int
    spacing: float = math.nan
    regrown: int = 0
    max_loaded: int = 0

    @property
    def k(self) -> int:
        return self.options.geometric.k

    @property
    def smooth_passes(self) -> int:
        return int(self.model.info.get("smooth_passes", 0)) if self.model is not None else 0  # type: ignore[call-overload]


@dataclass
class _Loaded:
    """A cell's points with its halo, in the whole cloud's order: the cloud, their indices (N,) int64, which are
    the cell's own (N,) bool, and the room (N,) float64 metres the loaded region leaves around each (inf: all)."""

    cloud: PointCloud
    index: np.ndarray
    own: np.ndarray
    room: np.ndarray
    halo: float
    key: int


def _room(xy: np.ndarray, grid: Grid, key: int | np.ndarray, halo: float) -> np.ndarray:
    """(N,) metres: the radius of the largest x-y disc around each point (N, 2) inside the region whose points are
    loaded with cell ``key`` (one, or (N,) int64, one a point): its rectangle, open to infinity on the grid's outer
    sides, grown by ``halo``. Negative outside the region."""
    ix, iy = np.divmod(np.asarray(key, dtype=np.int64), grid.ny)
    c = grid.cell
    x_lo = np.where(ix > 0, grid.x0 + ix * c, -np.inf)
    x_hi = np.where(ix < grid.nx - 1, grid.x0 + (ix + 1) * c, np.inf)
    y_lo = np.where(iy > 0, grid.y0 + iy * c, -np.inf)
    y_hi = np.where(iy < grid.ny - 1, grid.y0 + (iy + 1) * c, np.inf)
    x, y = xy[:, 0], xy[:, 1]
    dx = np.maximum(np.maximum(x_lo - x, x - x_hi), 0.0)
    dy = np.maximum(np.maximum(y_lo - y, y - y_hi), 0.0)
    outside = np.hypot(dx, dy)
    inside = np.minimum(np.minimum(x - x_lo, x_hi - x), np.minimum(y - y_lo, y_hi - y))
    return np.where(outside > 0, halo - outside, halo + inside)


def _margin(job: _Job) -> float:
    """Rounding margin (metres) kept by every proof."""
    return 1e-9 * (float(np.abs(job.lo).max() + np.abs(job.hi).max()) + job.halo + job.grid.cell)


# -- passes 1 and 2: scan, bucket ---------------------------------------------------------------------------------


def _scan(source: PointSource) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, tuple[bool, bool, bool]]:
    """Pass 1: count, bounding box (3,) float64 metres (lo, hi), origin, and the attributes (colours, normals,
    visibility) every chunk must carry alike; non-finite coordinates and an empty cloud raise DataError."""
    count, lo, hi, origin, schema = 0, np.full(3, np.inf), np.full(3, -np.inf), None, None
    for chunk in source.chunks():
        this = (chunk.colors is not None, chunk.normals is not None, chunk.visibility is not None)
        if schema is None:
            schema, origin = this, chunk.origin.copy()
        elif this != schema or not np.array_equal(chunk.origin, origin):
            raise DataError(f"chunk at point {count} carries other attributes or origin than the first", source.path)
        if not np.isfinite(chunk.positions).all():
            raise DataError(f"points of the chunk at point {count} have NaN or infinite coordinates", source.path)
        if len(chunk):
            lo, hi = np.minimum(lo, chunk.positions.min(axis=0)), np.maximum(hi, chunk.positions.max(axis=0))
        count += len(chunk)
    if count < 3 or origin is None or schema is None:
        raise DataError(f"features need at least 3 points, got {count}", source.path)
    return count, lo, hi, origin, schema


def _record_dtype(schema: tuple[bool, bool, bool]) -> np.dtype:
    """A point's record in the cell files: position (metres), index, colour and normal when the cloud has them,
    and how many image ids of its visibility follow in the ids file."""
    fields = [("p", "<f8", 3), ("i", "<i8"), ("nvis", "<i4")]
    fields += [("rgb", "u1", 3)] if schema[0] else []
    fields += [("n", "<f4", 3)] if schema[1] else []
    return np.dtype(fields)


class _Cells(CellFiles):
    """The cell files of :class:`eval.c2c_stream.CellFiles` with whole records: ``core_K`` / ``halo_K`` hold
    :func:`_record_dtype` records, ``vcore_K`` / ``vhalo_K`` their visibility ids (int64, in record order)."""

    def __init__(self, folder: Path, grid: Grid, halo: float, schema: tuple[bool, bool, bool]) -> None:
        super().__init__(folder, grid, halo)
        self.schema, self.dtype = schema, _record_dtype(schema)

    def add_cloud(self, chunk: PointCloud) -> None:
        """Append a chunk: each point to its cell, and to the halo of each neighbour cell within ``halo``."""
        p, g = chunk.positions, self.grid
        rec = np.empty(len(p), self.dtype)
        rec["p"], rec["i"] = p, np.arange(self.count, self.count + len(p))
        counts = np.array([len(v) for v in chunk.visibility], np.int64) if chunk.visibility is not None else None
        rec["nvis"] = counts if counts is not None else 0
        if self.schema[0]:
            rec["rgb"] = chunk.colors
        if self.schema[1]:
            rec["n"] = chunk.normals
        self.count += len(p)
        ids = np.concatenate(chunk.visibility) if counts is not None and counts.sum() else np.zeros(0, np.int64)
        ix, iy = g.cell_of(p[:, :2])
        self._write("core", ix * g.ny + iy, rec, counts, ids)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                jx, jy = ix + dx, iy + dy
                inside = (jx >= 0) & (jx < g.nx) & (jy >= 0) & (jy < g.ny) & ((dx != 0) | (dy != 0))
                keys = np.where(inside, jx * g.ny + jy, 0)
                near = inside & (_room(p[:, :2], g, keys, self.halo) >= 0.0)
                if near.any():
                    self._write("halo", keys[near], rec[near], None if counts is None else counts[near],
                                _ids_of(ids, counts, near))  # fmt: skip

    def _write(self, kind: str, keys: np.ndarray, rec: np.ndarray, counts: np.ndarray | None, ids: np.ndarray) -> None:
        self._append(kind, keys, rec)
        if counts is not None and len(ids):
            self._append("v" + kind, np.repeat(keys, counts), ids.astype(np.int64))

    def load(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        """The records (N,) of cell ``key`` and its halo and their visibility ids, sorted by index."""
        parts, ids = [], []
        for kind in ("core", "halo"):
            path = self.folder / f"{kind}_{key}.bin"
            parts.append(np.fromfile(path, self.dtype) if path.is_file() else np.empty(0, self.dtype))
            vpath = self.folder / f"v{kind}_{key}.bin"
            ids.append(np.fromfile(vpath, np.int64) if vpath.is_file() else np.zeros(0, np.int64))
        rec, flat = np.concatenate(parts), np.concatenate(ids)
        order = np.argsort(rec["i"], kind="stable")
        lens = rec["nvis"][order].astype(np.int64)
        begin = (np.cumsum(rec["nvis"].astype(np.int64)) - rec["nvis"])[order]
        take = np.repeat(begin - (np.cumsum(lens) - lens), lens) + np.arange(int(lens.sum()))
        return rec[order], flat[take]

    def remove(self, key: int) -> None:
        for kind in ("core", "halo", "vcore", "vhalo"):
            (self.folder / f"{kind}_{key}.bin").unlink(missing_ok=True)


def _ids_of(ids: np.ndarray, counts: np.ndarray | None, rows: np.ndarray) -> np.ndarray:
    """The visibility ids (flattened, in row order) of the selected rows (N,) bool."""
    if counts is None or not len(ids):
        return np.zeros(0, np.int64)
    return ids[np.repeat(rows, counts)]


def _cloud_of(rec: np.ndarray, ids: np.ndarray, job: _Job, schema: tuple[bool, bool, bool]) -> PointCloud:
    """The PointCloud of records sorted by index and their visibility ids."""
    vis = np.split(ids, np.cumsum(rec["nvis"])[:-1]) if schema[2] else None
    return PointCloud(
        np.ascontiguousarray(rec["p"]), job.origin.copy(), np.ascontiguousarray(rec["rgb"]) if schema[0] else None,
        np.ascontiguousarray(rec["n"]) if schema[1] else None, visibility=vis,
    )  # fmt: skip


def _load(cells: _Cells, key: int, job: _Job) -> _Loaded:
    """Cell ``key`` with its halo from the cell files."""
    rec, ids = cells.load(key)
    cloud = _cloud_of(rec, ids, job, cells.schema)
    own = np.zeros(len(rec), bool)
    ix, iy = job.grid.cell_of(cloud.positions[:, :2])
    own[ix * job.grid.ny + iy == key] = True
    return _Loaded(cloud, rec["i"].copy(), own, _room(cloud.positions[:, :2], job.grid, key, job.halo), job.halo, key)


def _gather(job: _Job, key: int, halo: float) -> _Loaded:
    """Cell ``key`` with a halo of ``halo`` metres, read from the source (a cell redone with a larger halo)."""
    g, parts, start = job.grid, [], 0
    for _, chunk in rechunk(job.source, job.chunk_size):
        p = chunk.positions
        near = np.flatnonzero(_room(p[:, :2], g, key, halo) >= 0.0)
        if len(near):
            parts.append((chunk.subset(near), start + near))
        start += len(chunk)
    cloud = PointCloud(
        np.concatenate([c.positions for c, _ in parts]), job.origin.copy(),
        np.concatenate([c.colors for c, _ in parts]) if parts[0][0].colors is not None else None,
        np.concatenate([c.normals for c, _ in parts]) if parts[0][0].normals is not None else None,
        visibility=[v for c, _ in parts for v in c.visibility] if parts[0][0].visibility is not None else None,
    )  # fmt: skip
    index = np.concatenate([i for _, i in parts])
    ix, iy = g.cell_of(cloud.positions[:, :2])
    room = _room(cloud.positions[:, :2], g, key, halo)
    if len(index) == job.count:  # the whole cloud: every neighbourhood is exact
        room = np.full(len(index), np.inf)
    return _Loaded(cloud, index, ix * g.ny + iy == key, room, halo, key)


def _cells_with_points(cells: _Cells) -> Iterator[int]:
    g = cells.grid
    return (key for key in range(g.nx * g.ny) if (cells.folder / f"core_{key}.bin").is_file())


def _until_proven(cells: _Cells, key: int, job: _Job, work, what: str):  # noqa: ANN001, ANN202
    """``work(loaded)`` → (the cell's own rows proven (M,) bool, result) on cell ``key``, again from the source with
    twice the halo until every own row is proven; the result of the first attempt that proves them all."""
    loaded, halo = _load(cells, key, job), job.halo
    while True:
        job.max_loaded = max(job.max_loaded, len(loaded.index))
        ok, result = work(loaded)
        if ok.all():
            return result
        if np.isinf(loaded.room).all():
            raise DataError(f"the {what} of cell {key} could not be proven exact with the whole cloud loaded")
        halo *= 2.0
        job.regrown += 1
        loaded = _gather(job, key, halo)


# -- passes 3 and 4: spacing, features and prediction --------------------------------------------------------------


def _spacing_work(job: _Job, loaded: _Loaded) -> tuple[np.ndarray, np.ndarray]:
    """The cell's own rows proven, and their nearest non-zero distance among their k − 1 nearest others (metres;
    nan when all are duplicates), as :func:`classify.features.geometric.spacing_from_neighbours` reads them."""
    pts, own = loaded.cloud.positions, loaded.own
    if len(pts) < job.k and not np.isinf(loaded.room).all():
        return np.zeros(int(own.sum()), bool), np.empty(0)
    dist, _ = level_neighbours(pts, job.k, job.options.geometric)
    dist = dist[own]
    ok = dist[:, -1] <= loaded.room[own] - _margin(job)
    first = np.count_nonzero(dist <= 0.0, axis=1)
    has = first < dist.shape[1]
    nearest = np.full(len(dist), np.nan)
    nearest[has] = dist[np.flatnonzero(has), first[has]]
    return ok, nearest


def _spacing_pass(cells: _Cells, job: _Job, work: Path, in_memory: int) -> float:
    """Pass 3: the whole cloud's median point spacing (metres), exactly, from per-cell files of nearest distances."""
    from fusion.convert_stream import order_statistic

    files = []
    for key in _cells_with_points(cells):
        nearest = _until_proven(cells, key, job, lambda loaded: _spacing_work(job, loaded), "spacing")
        path = work / f"spacing_{key}.bin"
        nearest[np.isfinite(nearest)].tofile(path)
        files.append(path)

    def values() -> Iterator[np.ndarray]:
        return (np.fromfile(p, np.float64) for p in files)

    n = sum(p.stat().st_size // 8 for p in files)
    if n == 0:
        raise DataError("all points coincide: the point spacing is zero", job.source.path)
    if n <= in_memory:
        spacing = float(np.median(np.concatenate(list(values()))))
    else:
        ranks = [n // 2] if n % 2 else [n // 2 - 1, n // 2]
        spacing = float(np.mean(np.array([order_statistic(values, r, in_memory) for r in ranks])))
    for p in files:
        p.unlink()
    return spacing


def _columns_inside(centres: np.ndarray, radius: np.ndarray, voxel: float, job: _Job, loaded: _Loaded) -> np.ndarray:
    """(M,) bool: every voxel column (side ``voxel`` metres, from the cloud's lowest corner) within ``radius`` (M,)
    metres of each centre (M, 3) lies wholly in the loaded region (the 4 corners of their union; the region is
    convex)."""
    m = _margin(job)
    lo = job.lo[:2]
    first = np.floor((centres[:, :2] - radius[:, None] - lo) / voxel)
    last = np.floor((centres[:, :2] + radius[:, None] - lo) / voxel) + 1.0
    a, b = lo + first * voxel - m, lo + last * voxel + m
    ok = np.ones(len(centres), bool)
    for cx, cy in ((a[:, 0], a[:, 1]), (a[:, 0], b[:, 1]), (b[:, 0], a[:, 1]), (b[:, 0], b[:, 1])):
        ok &= _room(np.column_stack([cx, cy]), job.grid, loaded.key, loaded.halo) >= 0.0
    return ok


def _proven(job: _Job, loaded: _Loaded, table: FeatureTable) -> np.ndarray:
    """(N,) bool: the loaded rows whose features are the whole cloud's (module docstring: every level's
    neighbourhood, voxel and ground columns inside the loaded region)."""
    pts, n = loaded.cloud.positions, len(loaded.index)
    if np.isinf(loaded.room).all():
        return np.ones(n, bool)
    nb = table.neighbours
    if nb is None or nb.shape[1] < job.k - 1:
        return np.zeros(n, bool)
    m = _margin(job)
    ok = np.linalg.norm(pts[nb[:, -1]] - pts, axis=1) <= loaded.room - m
    for factor in job.options.geometric.voxel_factors:
        if factor <= 1.0:
            continue
        voxel = factor * job.spacing
        level, per_point = voxel_downsample(pts, voxel, origin=job.lo)
        if len(level) <= job.k:
            return np.zeros(n, bool)
        dist, _ = level_neighbours(level, job.k, job.options.geometric)
        ok &= _columns_inside(level, np.maximum(dist[:, -1], voxel) + m, voxel, job, loaded)[per_point]
    return ok


def _feature_work(job: _Job, loaded: _Loaded) -> tuple[np.ndarray, np.ndarray | None]:
    """The cell's own rows proven (their features and, with smoothing, their neighbours' up to ``smooth_passes``
    steps), and when all are, their results (:data:`_RESULT`, index order)."""
    from classify.run import predict_table

    own = loaded.own
    if len(loaded.index) <= job.k and not np.isinf(loaded.room).all():
        return np.zeros(int(own.sum()), bool), None
    whole = WholeCloud(job.lo, job.hi, job.spacing)
    table = compute_features(loaded.cloud, job.options, job.views, whole)
    exact = _proven(job, loaded, table)
    for _ in range(job.smooth_passes):
        exact = exact & exact[table.neighbours].all(axis=1)  # type: ignore[index]
    ok = exact[own]
    if not ok.all():
        return ok, None
    pred: Prediction = predict_table(job.model, table, job.classes, job.threshold)
    res = np.empty(int(own.sum()), _RESULT)
    res["cls"] = pred.classification[own].astype(np.uint8)
    res["prob"] = pred.probability[own].astype(np.float32)
    res["needs"] = pred.needs_splats[own].astype(np.uint8)
    return ok, res


def _feature_pass(cells: _Cells, job: _Job, work: Path) -> None:
    """Pass 4: a result file ``res_K.bin`` per cell (its own points in source order); cell files removed."""
    for key in list(_cells_with_points(cells)):
        res = _until_proven(cells, key, job, lambda loaded: _feature_work(job, loaded), "features")
        res.tofile(work / f"res_{key}.bin")
        cells.remove(key)


# -- pass 5: output -------------------------------------------------------------------------------------------------


def _output_pass(job: _Job, work: Path, ply_path: Path) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Pass 5: ``ply_path`` (atomically) as :func:`classify.run.write_classified` writes it; returns the points
    per class code and then the points that need splats (257,) int64, and the classes figure's sample (positions (S, 3)
    float64, codes (S,) uint8)."""
    from classify.figures import plotted_points
    from core.io.ply import ply_vertex_header, ply_vertex_rows

    picked = plotted_points(job.count)
    per_code, cursor = np.zeros(257, np.int64), {}  # the last: points that need splats
    sample_p, sample_c = [], []
    with atomic_path(ply_path) as tmp, open(tmp, "wb") as f:
        for start, chunk in rechunk(job.source, job.chunk_size):
            res = chunk_results(chunk.positions, job.grid, work, cursor, _RESULT)
            fields = dict(chunk.fields)
            fields["classification"], fields["probability"] = res["cls"], res["prob"]
            fields["needs_splats"] = res["needs"]
            rows = ply_vertex_rows(PointCloud(chunk.positions, chunk.origin, chunk.colors, chunk.normals, fields))
            if start == 0:
                f.write(ply_vertex_header(rows.dtype, job.count))
            f.write(rows.tobytes())
            per_code[:256] += np.bincount(res["cls"], minlength=256)
            per_code[256] += int(np.count_nonzero(res["needs"]))
            rows_here = (
                np.arange(len(chunk))
                if picked is None
                else picked[(picked >= start) & (picked < start + len(chunk))] - start
            )
            sample_p.append(chunk.positions[rows_here])
            sample_c.append(res["cls"][rows_here])
    write_origin(ply_path, job.origin) if np.any(job.origin != 0) else remove_origin(ply_path)
    return per_code, (np.concatenate(sample_p), np.concatenate(sample_c))


def classify_stream(
    source: PointSource,
    model: ClassifierModel | None,
    views: ViewData | None,
    classes: ClassSet,
    ply_path: str | PathLike[str],
    stream: ClassifyStreamOptions,
    threshold: float | None = None,
) -> StreamedClassification:
    """Classify a streamed dense cloud with bounded memory and write ``ply_path`` (classify/points.ply).

    source: the cloud (float64 local positions + origin, colours, normals, visibility as the model's features
    need them), at least 3 points. model: as :func:`classify.run.classify_cloud` (None: the fallback rules); views:
    the dense workspace's photos and depth maps (None when no feature needs them); threshold: None = the model's.
    stream: memory limit, sizes, halo, work folder. Returns a :class:`StreamedClassification`.
    Raises :class:`ConfigError` (memory limit; a model whose finest scale is not the full cloud, whose spacing
    is a random sample's), :class:`DataError` naming the source's file."""
    from classify.run import feature_options_for

    t0, seconds = time.perf_counter(), {}
    plan = stream.plan()
    options = feature_options_for(model)
    if options.geometric.voxel_factors[0] > 1.0:
        raise ConfigError(
            "the streamed classification needs the finest geometric scale to be the full cloud (voxel_factors[0] "
            f"<= 1, the default), got {options.geometric.voxel_factors}: classify in memory (no memory limit)"
        )
    count, lo, hi, origin, schema = _scan(source)
    seconds["scan"] = time.perf_counter() - t0
    grid, halo = _choose_grid(source, count, lo, hi, options, plan, stream.halo)
    t = threshold if threshold is not None or model is None else float(model.info.get("threshold", 0.5))  # type: ignore[arg-type]
    job = _Job(source, grid, halo, options, model, views, classes, t if t is not None else 0.5, count, lo, hi,
               origin, plan.chunk_size)  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="hybridsplat_classify_", dir=stream.work_dir) as tmp:
        work = Path(tmp)
        cells = _Cells(work / "cells", grid, halo, schema)
        for _, piece in rechunk(source, plan.chunk_size):
            cells.add_cloud(piece)
        seconds["bucket"] = time.perf_counter() - t0 - sum(seconds.values())
        job.spacing = _spacing_pass(cells, job, work, plan.points_per_cell)
        seconds["spacing"] = time.perf_counter() - t0 - sum(seconds.values())
        _feature_pass(cells, job, work)
        seconds["features"] = time.perf_counter() - t0 - sum(seconds.values())
        per_code, sample = _output_pass(job, work, Path(ply_path))
        seconds["output"] = time.perf_counter() - t0 - sum(seconds.values())
    codes = {c.code: int(per_code[c.code]) for c in classes.classes}
    needs = int(per_code[256])
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return StreamedClassification(count, job.spacing, codes, needs, options.selected(), grid, halo, job.regrown,
                                  job.max_loaded, sample, peak, seconds)  # fmt: skip


def _choose_grid(
    source: PointSource, count: int, lo: np.ndarray, hi: np.ndarray, options: FeatureOptions, plan: ClassifyPlan,
    halo: float | None,
) -> tuple[Grid, float]:  # fmt: skip
    """The x-y grid (about ``points_per_cell`` points a cell with its halo) and the halo (metres): given, or
    :data:`_HALO_VOXELS` voxels of the coarsest level at the spacing of the first chunk's points."""
    from classify.features.geometric import point_spacing

    if halo is None:
        first = next(iter(rechunk(source, 200_000)))[1].positions
        guess = point_spacing(first, sample=20_000) if len(first) >= 2 else 1.0
        halo = _HALO_VOXELS * max(1.0, *options.geometric.voxel_factors) * guess
    if not (halo > 0 and math.isfinite(halo)):
        raise ConfigError(f"halo must be a positive finite distance in metres, got {halo}")
    width, height = max(float(hi[0] - lo[0]), 1e-9), max(float(hi[1] - lo[1]), 1e-9)
    cells = max(1, math.ceil(count / plan.points_per_cell))
    size = max(math.sqrt(width * height / cells), 1e-9 * max(width, height))
    # The halo grows a cell by 2 halos a side: the points it holds with its halo scale with (size + 2 halo)². Cells
    # at least 2 halos wide keep the halos' copies on disk within 3 a point (:func:`temp_bytes`).
    size = max(size - 2.0 * halo, 2.0 * halo, 1e-9)
    grid = Grid(float(lo[0]), float(lo[1]), size, max(1, math.ceil(width / size)), max(1, math.ceil(height / size)))
    return grid, halo
