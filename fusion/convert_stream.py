"""Out-of-core MVS-point → Gaussian conversion and chunked Gaussian exports with bounded memory (issue 34).

:func:`convert_stream` gives the Gaussians of :func:`fusion.convert.convert_points` (both modes, same options) for
clouds larger than memory, and writes them chunk by chunk as a 3DGS PLY (the layout of
:func:`core.io.gaussian_ply.write_gaussian_ply`) and/or a LAS/LAZ point export of their centres (what
:func:`fusion.export.export_points` writes for them: colour, ``classification``, ``source``, ``opacity``, ``scale`` and
the cloud's fields; :class:`core.io.las.LasChunkWriter`). The input is a
:class:`core.io.point_stream.PointSource`: a re-iterable stream of :class:`core.pointcloud.PointCloud` chunks in one
local frame (``cloud_source`` over an in-memory cloud, ``las_source`` over a LAS/LAZ file, ``ply_source`` over a
binary PLY such as COLMAP's ``fused.ply`` with its ``fused.ply.vis``). This module is the conversion algorithm: its
passes, cells, fallback search, global values and output.

Passes (the source must give the same points in the same order every time):

1. scan: count, x-y bounds, attributes (every chunk must carry the same ones), finite coordinates, and a halo from
   the k-th neighbour distances of the first chunk's first points (3 × their 99th percentile, unless given).
2. bucket: every point into the file of its cell of a 2-D x-y grid (:class:`eval.c2c_stream.CellFiles`, ``Grid``:
   about ``points_per_cell`` points a cell, cells ≥ 4 halos wide) and into the halo files of the neighbouring cells
   within ``halo`` of it.
3. neighbours: per cell, the k nearest neighbours (:func:`core.knn.knn_grid`, the in-memory search) of the cell's
   own points among its points and its halo: the nearest distances (summed), and in ``adaptive`` mode the spacing
   (median non-duplicate distance) and, when some points lack a normal, the PCA normal's quaternion, to a result
   file per cell (then the cell's files go). The search is always :func:`core.knn.knn_grid` whatever
   ``neighbor_backend`` says (both backends give identical distances).
   Exactness: every point within ``halo`` of the cell's rectangle is in its halo, so the k found for a point q are
   exact when the k-th distance is ≤ ``halo`` + the distance from q to the nearest cell edge shared with another
   cell (the ball around q then lies in the cell grown by the halo; a small rounding margin is kept). Points that
   fail (isolated points, too few points in cell + halo) are kept aside, and
4. fallback (only if any failed): one more pass over the source searches them exactly against every chunk
   (``scipy.spatial.cKDTree`` per chunk, k + 1 neighbours, the point itself excluded by its index) and their results
   are patched into the result files. The count is reported (``fallback_points``); the pass costs one more read
   of the source and a k-d tree per chunk, so a halo far too small is slow, never wrong.
5. global values: ``paper`` the mean nearest distance d (float64 sums per cell, then ``math.fsum``); ``adaptive`` the
   exact median of the clamped spacings (an in-memory partition when they fit the budget, else a radix selection
   over the bit patterns of the positive float64 values, 16 bits a pass over the result files).
6. output: one pass over the source in its order; each chunk takes its points' results from the cells' result files
   (a cell's points come in source order, so one cursor per cell suffices), becomes Gaussians by the kernels of
   :mod:`fusion.convert` (the same float operations) and is appended to the PLY (header written first: the count
   is known) and the LAS/LAZ (laspy's chunk writer). Both are written to temporary names and renamed on success.

What differs from the in-memory conversion: Gaussians and rows come out in the source's order with identical
values, except (a) ``paper``'s d, a mean summed in another order (relative difference ~1e-16, so log-scales and
logits may differ in the last float32 bit), and (b) where a point has several distinct neighbours at exactly its
k-th distance (regular grids), the tie may pick another of them, which changes a PCA normal (the in-memory grid and
k-d tree searches differ the same way); distances, spacings and opacities are unaffected.

Memory: ``memory_limit_mb`` sets ``points_per_cell`` and ``chunk_size`` (:func:`plan_memory`); x-y density is assumed
roughly uniform, as in :mod:`eval.c2c_stream` (the largest cell is reported). Disk (``work_dir``): 32 bytes a point
for the cells plus their halos, then (``adaptive``) 24 bytes a point of results. Units: metres; positions float64
in the source's local frame, ``origin`` (world = origin + local) carried to the PLY sidecar and the LAS offsets.
"""

from __future__ import annotations

import contextlib
import math
import resource
import tempfile
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

import numba
import numpy as np
from scipy.spatial import cKDTree

from core.errors import ConfigError, DataError, FormatError
from core.gaussians import GaussianSet
from core.io.atomic import atomic_path
from core.io.gaussian_ply import gaussian_ply_rows
from core.io.origin import remove_origin, write_origin
from core.io.point_stream import PointSource, rechunk
from core.knn import knn_grid, median_nonzero, run_threads
from core.pointcloud import PointCloud
from eval.c2c_stream import CellFiles, Grid, chunk_results, grid_for, memory_work_mb
from fusion.convert import (
    ConvertStats,
    clamp_kernel,
    pca_normals,
    quats_from_given_normals,
    quats_z_to,
    sh_dc_from_colors,
    surfel_attributes,
)
from fusion.convert_options import DEFAULT_MODE, ConversionWarning, ConvertMode, ConvertOptions, Source

DEFAULT_MEMORY_LIMIT_MB = 4096.0
BASE_MB = 512.0
"""Memory taken before any point: the interpreter, numpy/numba/scipy/laspy, compiled kernels, a PCA batch (MB)."""
MIN_WORK_MB = 64.0
"""The least memory beyond :data:`BASE_MB` the streamed conversion works in (MB)."""
_CHUNK_BYTES = 640
"""Bytes a point of a chunk takes at most: decoded LAS records, the PointCloud, Gaussians, PLY rows, LAS records."""
_RESULT = np.dtype([("spacing", "<f8"), ("quat", "<f4", 4)])  # per point: raw spacing (metres), PCA quaternion
_PLY_SCALAR = "float"  # every 3DGS PLY property is float32, as write_gaussian_ply writes it


def _cell_bytes(k: int) -> int:
    """Bytes a point of a cell (own or halo) takes during the neighbour search: records, positions, the search's
    sorted copy and column table, (N, k) distances and indices, results."""
    return 256 + 16 * k


@dataclass(frozen=True)
class StreamPlan:
    """Sizes derived from a memory limit: points per grid cell and per chunk."""

    memory_limit_mb: float
    points_per_cell: int
    chunk_size: int


def plan_memory(memory_limit_mb: float, k_neighbors: int = 8) -> StreamPlan:
    """Cell and chunk sizes for a peak resident memory of about ``memory_limit_mb`` (MiB).

    Of what is left above :data:`BASE_MB`, 55 % goes to a cell (own points + halo), 25 % to a chunk, the rest is
    slack for denser-than-average cells. Raises :class:`ConfigError` naming the value when less than
    :data:`MIN_WORK_MB` would be left.
    """
    work = memory_work_mb(
        memory_limit_mb,
        BASE_MB,
        MIN_WORK_MB,
        "the streamed conversion",
        "the interpreter and libraries",
        "a cell and a chunk",
    )
    work_bytes = work * 2**20
    cell = max(1000, int(0.55 * work_bytes / _cell_bytes(k_neighbors)))
    chunk = max(1000, int(0.25 * work_bytes / _CHUNK_BYTES))
    return StreamPlan(float(memory_limit_mb), cell, chunk)


@dataclass
class StreamedConversion:
    """What :func:`convert_stream` did. ``stats`` as :func:`fusion.convert.convert_points` reports them
    (``mean_nn_spacing`` summed in another order). ``peak_rss_mb``: the process's peak resident memory (MiB,
    ``ru_maxrss``) at the end, which includes whatever the process held before the call."""

    stats: ConvertStats
    num_points: int
    origin: np.ndarray
    grid: Grid
    halo: float
    plan: StreamPlan
    max_cell_points: int
    fallback_points: int
    ply_path: Path | None
    las_path: Path | None
    las_points: int = 0
    dropped_opacity: int = 0
    peak_rss_mb: float = 0.0
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def cells(self) -> int:
        return self.grid.nx * self.grid.ny


# -- pass 1: scan ----------------------------------------------------------------------------------------------


@dataclass
class _Scan:
    count: int = 0
    lo: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))
    hi: np.ndarray = field(default_factory=lambda: np.full(3, -np.inf))
    origin: np.ndarray | None = None
    schema: tuple | None = None
    missing_normals: bool = False  # some point lacks a usable normal: PCA of the neighbours
    halo_hint: float = math.nan


def _schema(chunk: PointCloud) -> tuple:
    fields = tuple((k, np.dtype(v.dtype).str) for k, v in chunk.fields.items())
    return (chunk.colors is not None, chunk.normals is not None, chunk.visibility is not None, fields)


def _scan(source: PointSource, k: int) -> _Scan:
    """Pass 1: count, bounds, one schema and origin for all chunks, finite coordinates, the halo hint."""
    scan = _Scan()
    for chunk in source.chunks():
        if not isinstance(chunk, PointCloud):
            raise DataError(f"a chunk must be a PointCloud, got {type(chunk).__name__}", source.path)
        if scan.schema is None:
            scan.schema, scan.origin = _schema(chunk), chunk.origin.copy()
            scan.halo_hint = _halo_hint(chunk.positions, k)
        elif _schema(chunk) != scan.schema:
            raise DataError(
                f"chunk at point {scan.count} carries other attributes than the first: {_schema(chunk)} vs "
                f"{scan.schema}",
                source.path,
            )
        elif not np.array_equal(chunk.origin, scan.origin):
            raise DataError(f"chunk at point {scan.count} has origin {chunk.origin} ≠ {scan.origin}", source.path)
        bad = ~np.isfinite(chunk.positions).all(axis=1)
        if bad.any():
            first = scan.count + int(np.flatnonzero(bad)[0])
            raise DataError(
                f"{int(bad.sum())} points of a chunk have NaN or infinite coordinates (first: point {first})",
                source.path,
            )
        if len(chunk):
            scan.lo = np.minimum(scan.lo, chunk.positions.min(axis=0))
            scan.hi = np.maximum(scan.hi, chunk.positions.max(axis=0))
            scan.missing_normals |= bool(quats_from_given_normals(_positions_normals(chunk))[1].any())
        scan.count += len(chunk)
    if scan.count == 0:
        raise DataError("cannot convert an empty point cloud to Gaussians (0 points)", source.path)
    return scan


def _positions_normals(chunk: PointCloud) -> PointCloud:
    return PointCloud(chunk.positions, chunk.origin, normals=chunk.normals)


def _halo_hint(positions: np.ndarray, k: int, sample: int = 200_000) -> float:
    """3 × the 99th percentile of the k-th neighbour distance among the first ``sample`` points (metres); nan when
    there are too few. Only a hint: a halo too small costs fallback searches, never exactness."""
    p = np.ascontiguousarray(positions[:sample], dtype=np.float64)
    if k < 1 or len(p) <= k:
        return math.nan
    dist, _ = knn_grid(p, k)
    return 3.0 * float(np.percentile(dist[:, -1], 99))


# -- passes 2–4: cells, neighbours, fallback ----------------------------------------------------------------------


def _choose_grid(scan: _Scan, k: int, halo: float | None, points_per_cell: int) -> tuple[Grid, float]:
    width = max(float(scan.hi[0] - scan.lo[0]), float(scan.hi[1] - scan.lo[1]), 1e-9)
    area = max(float(scan.hi[0] - scan.lo[0]), 1e-9) * max(float(scan.hi[1] - scan.lo[1]), 1e-9)
    cap = max(math.sqrt(area / max(1, math.ceil(scan.count / points_per_cell))) / 4.0, 1e-9)
    if halo is None:
        halo = min(scan.halo_hint, cap) if math.isfinite(scan.halo_hint) and scan.halo_hint > 0 else cap
        halo = max(halo, 1e-9 * width)
    elif not (halo > 0 and math.isfinite(halo)):
        raise ConfigError(f"halo must be a positive finite distance in metres, got {halo}")
    return grid_for(scan.lo, scan.hi, scan.count, halo, points_per_cell), float(halo)


def _interior_gap(p: np.ndarray, g: Grid, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
    """Distance (metres) from each point to the nearest edge of its cell that another cell shares (inf if none)."""
    inf = np.inf
    left = np.where(ix > 0, p[:, 0] - (g.x0 + ix * g.cell), inf)
    right = np.where(ix < g.nx - 1, g.x0 + (ix + 1) * g.cell - p[:, 0], inf)
    below = np.where(iy > 0, p[:, 1] - (g.y0 + iy * g.cell), inf)
    above = np.where(iy < g.ny - 1, g.y0 + (iy + 1) * g.cell - p[:, 1], inf)
    return np.maximum(np.minimum(np.minimum(left, right), np.minimum(below, above)), 0.0)


@dataclass
class _Failed:
    """Points whose neighbours the cell could not prove exact: cell key, row in the cell, position, index."""

    keys: list[np.ndarray] = field(default_factory=list)
    rows: list[np.ndarray] = field(default_factory=list)
    positions: list[np.ndarray] = field(default_factory=list)
    index: list[np.ndarray] = field(default_factory=list)

    def add(self, key: int, rows: np.ndarray, positions: np.ndarray, index: np.ndarray) -> None:
        if len(rows):
            self.keys.append(np.full(len(rows), key, np.int64))
            self.rows.append(rows)
            self.positions.append(positions[rows])
            self.index.append(index[rows])

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if not self.keys:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64)
        return (np.concatenate(self.keys), np.concatenate(self.rows), np.concatenate(self.positions),
                np.concatenate(self.index))  # fmt: skip


def _cell_neighbours(cells: CellFiles, key: int, k: int, pca: bool, failed: _Failed) -> tuple[np.ndarray, int, float]:
    """Pass 3 for one cell: its result records (core order), the number of points in cell + halo, and the sum of
    the nearest distances of the points whose neighbours are proven exact (the others go to ``failed``)."""
    points, index = cells.core(key)
    near = np.ascontiguousarray(cells.near(key))
    n, m = len(points), len(near)
    res = np.zeros(n, _RESULT)
    res["quat"] = (1.0, 0.0, 0.0, 0.0)
    kk = min(k, m - 1)
    if kk < 1:
        failed.add(key, np.arange(n), points, index)
        return res, m, 0.0
    dist, nbr = knn_grid(near, kk)
    dist, nbr = dist[:n], nbr[:n]
    res["spacing"] = median_nonzero(dist)
    g = cells.grid
    ix, iy = g.cell_of(points[:, :2])
    margin = 1e-9 * (cells.halo + g.cell + abs(g.x0) + abs(g.y0) + g.cell * (g.nx + g.ny))
    ok = dist[:, -1] <= cells.halo + _interior_gap(points, g, ix, iy) - margin
    if kk < k:
        ok[:] = False
    if pca and k >= 2:
        rows = np.flatnonzero(ok)
        if len(rows):
            res["quat"][rows] = quats_z_to(pca_normals(near, rows, nbr[rows]))
    failed.add(key, np.flatnonzero(~ok), points, index)
    return res, m, float(np.sum(dist[ok, 0]))


def _neighbour_pass(cells: CellFiles, work: Path, k: int, pca: bool, keep: bool) -> tuple[_Failed, int, list[float]]:
    """Pass 3 over every cell: result files ``res_K.bin`` (when ``keep``: adaptive mode); the cell's own and halo
    files are removed once used. Returns the failed points, the largest cell + halo, the nearest-distance sums."""
    failed, biggest, sums = _Failed(), 0, []
    g = cells.grid
    for key in range(g.nx * g.ny):
        if not (cells.folder / f"core_{key}.bin").is_file():
            continue
        res, m, nearest = _cell_neighbours(cells, key, k, pca, failed)
        biggest, sums = max(biggest, m), [*sums, nearest]
        if keep:
            res.tofile(work / f"res_{key}.bin")
        (cells.folder / f"core_{key}.bin").unlink()
        (cells.folder / f"halo_{key}.bin").unlink(missing_ok=True)
    return failed, biggest, sums


def _fallback(
    source: PointSource, failed: _Failed, work: Path, k: int, pca: bool, chunk_size: int, keep: bool
) -> tuple[int, float]:
    """Pass 4: exact k nearest of the failed points against every chunk; their results patched in (when ``keep``).
    Returns their number and the sum of their nearest distances."""
    keys, rows, q, qi = failed.arrays()
    f = len(q)
    if f == 0:
        return 0, 0.0
    best_d = np.full((f, k), np.inf)
    best_p = np.zeros((f, k, 3))
    for start, chunk in rechunk(source, chunk_size):
        m = min(k + 1, len(chunk))
        d, i = cKDTree(chunk.positions).query(q, k=m)
        d, i = d.reshape(f, m), np.minimum(i.reshape(f, m), len(chunk) - 1)  # i = len: no neighbour (d = inf)
        d = np.where(start + i == qi[:, None], np.inf, d)  # the point itself
        all_d = np.concatenate([best_d, d], axis=1)
        all_p = np.concatenate([best_p, chunk.positions[i]], axis=1)
        order = np.argsort(all_d, axis=1, kind="stable")[:, :k]
        best_d = np.take_along_axis(all_d, order, axis=1)
        best_p = np.take_along_axis(all_p, order[:, :, None], axis=1)
    if keep:
        res = np.zeros(f, _RESULT)
        res["spacing"], res["quat"] = median_nonzero(best_d), (1.0, 0.0, 0.0, 0.0)
        if pca and k >= 2:
            local = np.concatenate([q, best_p.reshape(-1, 3)])
            res["quat"] = quats_z_to(pca_normals(local, np.arange(f), f + np.arange(f * k).reshape(f, k)))
        for key in np.unique(keys):
            path = work / f"res_{key}.bin"
            cell = np.fromfile(path, _RESULT)
            sel = keys == key
            cell[rows[sel]] = res[sel]
            cell.tofile(path)
    return f, float(np.sum(best_d[:, 0]))


# -- pass 5: global values ------------------------------------------------------------------------------------


def _result_files(work: Path, grid: Grid) -> list[Path]:
    return [p for key in range(grid.nx * grid.ny) if (p := work / f"res_{key}.bin").is_file()]


def _clamped_spacings(files: list[Path], lo: float, hi: float) -> Callable[[], Iterator[np.ndarray]]:
    return lambda: (np.clip(np.fromfile(p, _RESULT)["spacing"], lo, hi) for p in files)


def order_statistic(values: Callable[[], Iterable[np.ndarray]], rank: int, in_memory: int) -> float:
    """The ``rank``-th smallest (0-based) of non-negative finite float64 values given as a re-iterable stream of
    arrays, exactly, holding at most about ``in_memory`` values: a radix selection on their bit patterns (which
    sort as the values do), 16 bits a pass, until the candidates fit; then a partition."""
    prefix, shift = 0, 64
    while True:
        shift -= 16
        hist = np.zeros(1 << 16, np.int64)
        for v in values():
            key = np.ascontiguousarray(v, dtype=np.float64).view(np.uint64)
            if shift < 48:
                key = key[(key >> np.uint64(shift + 16)) == np.uint64(prefix)]
            hist += np.bincount(((key >> np.uint64(shift)) & np.uint64(0xFFFF)).astype(np.int64), minlength=1 << 16)
        cum = np.cumsum(hist)
        digit = int(np.searchsorted(cum, rank, side="right"))
        rank -= int(cum[digit - 1]) if digit else 0
        prefix = (prefix << 16) | digit
        if hist[digit] <= in_memory or shift == 0:
            break
    pick = []
    for v in values():
        key = np.ascontiguousarray(v, dtype=np.float64).view(np.uint64)
        pick.append(key[(key >> np.uint64(shift)) == np.uint64(prefix)])
    return float(np.partition(np.concatenate(pick), rank)[rank].view(np.float64))


def _median(values: Callable[[], Iterable[np.ndarray]], n: int, in_memory: int) -> float:
    """``np.median`` of the streamed values, exactly (the mean of the two middle ones when n is even)."""
    if n <= in_memory:
        return float(np.median(np.concatenate(list(values()))))
    ranks = [n // 2] if n % 2 else [n // 2 - 1, n // 2]
    return float(np.mean(np.array([order_statistic(values, r, in_memory) for r in ranks])))


# -- pass 6: output ---------------------------------------------------------------------------------------------


@dataclass
class _Globals:
    """What every chunk's Gaussians need besides their own points: the mode, options, k and the global values."""

    mode: ConvertMode
    options: ConvertOptions
    k: int
    d: float = math.nan  # paper: the clamped global spacing (metres)
    median: float = math.nan  # adaptive: median clamped spacing (metres)
    nearest_sum: float = 0.0  # sum of every point's nearest-other distance (metres)
    clamped_spacing: int = 0
    clamped_opacity: int = 0
    estimated_normals: int = 0


def _adaptive_chunk(chunk: PointCloud, res: np.ndarray | None, glob: _Globals) -> tuple[np.ndarray, ...]:
    """Log-scales, quaternions and unclamped logits of a chunk, as :func:`fusion.convert._adaptive` computes them
    (``res`` None: a single point, no neighbour)."""
    o, n, nth = glob.options, len(chunk), numba.get_num_threads()
    if res is None:
        res = np.zeros(n, _RESULT)
        res["quat"], res["spacing"] = (1.0, 0.0, 0.0, 0.0), o.fallback_spacing
    quats, missing = quats_from_given_normals(chunk)
    if missing.any():
        quats[missing] = res["quat"][missing]
        glob.estimated_normals += int(missing.sum()) if glob.k >= 2 else 0
    raw = np.ascontiguousarray(res["spacing"])
    spacing = np.empty(n, dtype=np.float64)
    bad = np.zeros(nth, dtype=np.int64)
    run_threads(clamp_kernel, (raw, o.min_spacing, o.max_spacing, spacing, bad), nth)
    glob.clamped_spacing += int(bad.sum())
    log_scales, logits = surfel_attributes(chunk, spacing, o, glob.median)
    return log_scales, quats, logits


def _chunk_gaussians(chunk: PointCloud, res: np.ndarray | None, glob: _Globals) -> GaussianSet:
    """The Gaussians of one chunk (``res``: its points' result records, adaptive only)."""
    n = len(chunk)
    if glob.mode is ConvertMode.PAPER:
        log_scales = np.full((n, 3), np.log(glob.d), dtype=np.float32)
        quats = np.zeros((n, 4), dtype=np.float32)
        quats[:, 0] = 1.0
        logits = np.full(n, np.log(1.0 / glob.d), dtype=np.float64)
    else:
        log_scales, quats, logits = _adaptive_chunk(chunk, res, glob)
    lo, hi = glob.options.opacity_logit_min, glob.options.opacity_logit_max
    glob.clamped_opacity += int(np.count_nonzero((logits < lo) | (logits > hi)))
    colors = chunk.colors if chunk.colors is not None else np.full((n, 3), 128, dtype=np.uint8)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConversionWarning)
        sh_dc = sh_dc_from_colors(colors, n, ConvertStats(glob.mode, n, math.nan, math.nan))
    fields = dict(chunk.fields)
    fields["source"] = np.full(n, Source.MVS, dtype=np.uint8)
    return GaussianSet(
        means=chunk.positions,
        log_scales=log_scales,
        quats=quats,
        logit_opacities=np.clip(logits, lo, hi),
        sh_dc=sh_dc,
        origin=chunk.origin.copy(),
        fields=fields,
    )


def ply_header(count: int, names: list[str]) -> bytes:
    """The header :func:`core.io.gaussian_ply.write_gaussian_ply` writes (through plyfile) for ``count`` vertices
    with float32 properties ``names``, binary little-endian."""
    props = "".join(f"property {_PLY_SCALAR} {name}\n" for name in names)
    return f"ply\nformat binary_little_endian 1.0\nelement vertex {count}\n{props}end_header\n".encode("ascii")


@dataclass(frozen=True)
class StreamOptions:
    """How :func:`convert_stream` works: ``memory_limit_mb`` (MiB) sets the cell and chunk sizes
    (:func:`plan_memory`) unless ``points_per_cell`` / ``chunk_size`` are given; ``halo`` (metres) defaults to the
    scan's hint; ``work_dir`` holds the temporary cell files (a temporary folder inside it; system default when
    None); ``median_in_memory``: the most spacings the median takes in memory (default: ``points_per_cell``)."""

    memory_limit_mb: float = DEFAULT_MEMORY_LIMIT_MB
    points_per_cell: int | None = None
    chunk_size: int | None = None
    halo: float | None = None
    work_dir: Path | None = None
    median_in_memory: int | None = None

    def plan(self, k: int) -> StreamPlan:
        plan = plan_memory(self.memory_limit_mb, k)
        for name in ("points_per_cell", "chunk_size", "median_in_memory"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, int) and value >= 1):
                raise ConfigError(f"{name} must be a positive integer, got {value!r}")
        return StreamPlan(
            plan.memory_limit_mb, self.points_per_cell or plan.points_per_cell, self.chunk_size or plan.chunk_size
        )


@dataclass(frozen=True)
class _Outputs:
    ply_path: Path | None
    las_path: Path | None
    extra_fields: bool
    min_opacity: float
    crs: str | None


def _output_pass(source: PointSource, n: int, grid: Grid, work: Path, glob: _Globals, out: _Outputs, chunk: int):
    """Pass 6: Gaussians chunk by chunk to the PLY and the LAS/LAZ (temporary names, renamed when both are complete:
    on an error neither is left behind); returns (LAS points written, points dropped below ``min_opacity``)."""
    from core.io.las import LasChunkWriter
    from fusion.export import gaussians_to_points

    ply_file, las, dropped, cursor = None, None, 0, {}
    with contextlib.ExitStack() as stack:
        if out.ply_path is not None:
            ply_file = stack.enter_context(open(stack.enter_context(atomic_path(out.ply_path)), "wb"))
        if out.las_path is not None:
            las = LasChunkWriter(stack.enter_context(atomic_path(out.las_path)), crs=out.crs, target=out.las_path)
            stack.callback(las.close)
        for start, piece in rechunk(source, chunk):
            adaptive = glob.mode is ConvertMode.ADAPTIVE and glob.k
            res = chunk_results(piece.positions, grid, work, cursor, _RESULT) if adaptive else None
            gs = _chunk_gaussians(piece, res, glob)
            if ply_file is not None:
                names, rows = gaussian_ply_rows(gs, out.extra_fields)  # core.io.gaussian_ply's layout
                if start == 0:
                    ply_file.write(ply_header(n, names))
                ply_file.write(rows.tobytes())
            if las is not None:
                keep = gs.opacities >= np.float32(out.min_opacity)
                dropped += int(len(gs) - keep.sum())
                las.write(gaussians_to_points(gs.subset(keep)))
        if las is not None and las.count == 0:
            raise DataError(
                f"nothing to export: all {n} Gaussians are below opacity {out.min_opacity:.4g}", out.las_path
            )
    return (las.count if las is not None else 0), dropped


def convert_stream(
    source: PointSource,
    mode: ConvertMode | str = DEFAULT_MODE,
    options: ConvertOptions | None = None,
    stream: StreamOptions | None = None,
    *,
    ply_path: str | PathLike[str] | None = None,
    las_path: str | PathLike[str] | None = None,
    extra_fields: bool = False,
    min_opacity: float = 1.0 / 255.0,
    crs: str | None = None,
) -> StreamedConversion:
    """Convert a streamed MVS cloud to Gaussians with bounded memory and write them chunk by chunk.

    source: the cloud (float64 local positions + origin; uint8 colours, grey with a warning when absent; optional
        normals, visibility or ``confidence`` field, other fields carried over), N ≥ 1 points.
    mode, options: as :func:`fusion.convert.convert_points` (same Gaussians; see the module docstring).
    stream: memory limit, cell and chunk sizes, halo, work folder (:class:`StreamOptions`).
    ply_path: a 3DGS PLY as :func:`core.io.gaussian_ply.write_gaussian_ply` writes (``extra_fields`` as there),
        with the origin sidecar when the origin is not zero.
    las_path: ``.las``/``.laz``: the Gaussians' centres as :func:`fusion.export.export_points` exports them
        (Gaussians with α < ``min_opacity`` dropped, as its default options do; ``crs`` written as WKT).

    Returns a :class:`StreamedConversion` (statistics, grid, halo, fallback count, peak memory, seconds per pass).
    Raises :class:`ConfigError` (mode, options, memory limit), :class:`DataError` / :class:`InputFileError` naming
    the source's file (empty, NaN coordinates, inconsistent chunks, unreadable).
    """
    t0 = time.perf_counter()
    options, stream = options or ConvertOptions(), stream or StreamOptions()
    try:
        mode = ConvertMode(mode)
    except ValueError as err:
        raise ConfigError(f"conversion mode must be one of {[m.value for m in ConvertMode]}, got {mode!r}") from err
    out = _outputs(ply_path, las_path, extra_fields, min_opacity, crs)
    k_want = 1 if mode is ConvertMode.PAPER else options.k_neighbors
    plan = stream.plan(k_want)
    seconds: dict[str, float] = {}
    scan = _scan(source, k_want)
    seconds["scan"] = time.perf_counter() - t0
    n = scan.count
    k = min(k_want, n - 1)
    grid, halo = _choose_grid(scan, max(k, 1), stream.halo, plan.points_per_cell)
    glob = _Globals(mode, options, k)
    stats = ConvertStats(mode=mode, num_points=n, mean_nn_spacing=math.nan, median_spacing=math.nan)
    with tempfile.TemporaryDirectory(prefix="hybridsplat_convert_", dir=stream.work_dir) as tmp:
        work = Path(tmp)
        biggest, fallback = _neighbours(source, scan, grid, halo, work, glob, plan, seconds)
        _global_values(work, grid, glob, stats, stream.median_in_memory or plan.points_per_cell)
        seconds["global"] = time.perf_counter() - t0 - sum(seconds.values())
        las_count, dropped = _output_pass(source, n, grid, work, glob, out, plan.chunk_size)
        seconds["output"] = time.perf_counter() - t0 - sum(seconds.values())
    if out.ply_path is not None:
        write_origin(out.ply_path, scan.origin) if np.any(scan.origin != 0) else remove_origin(out.ply_path)
    stats.clamped_spacing, stats.clamped_opacity = glob.clamped_spacing, glob.clamped_opacity
    stats.estimated_normals = glob.estimated_normals
    stats.missing_colors = not scan.schema[0]  # type: ignore[index]
    stats.seconds_neighbors = seconds.get("neighbours", 0.0) + seconds.get("fallback", 0.0)
    stats.seconds_total = time.perf_counter() - t0
    _warn_like_convert(stats, glob)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return StreamedConversion(
        stats, n, scan.origin, grid, halo, plan, biggest, fallback, out.ply_path, out.las_path, las_count, dropped,
        peak, seconds,
    )  # fmt: skip


def _outputs(ply_path, las_path, extra_fields: bool, min_opacity: float, crs: str | None) -> _Outputs:  # noqa: ANN001
    ply = Path(ply_path) if ply_path is not None else None
    las = Path(las_path) if las_path is not None else None
    if ply is not None and ply.suffix.lower() != ".ply":
        raise FormatError(f"the Gaussian output needs a .ply suffix, got {ply.suffix!r}", ply)
    if las is not None and las.suffix.lower() not in (".las", ".laz"):
        raise FormatError(f"the point export needs a .las or .laz suffix, got {las.suffix!r}", las)
    if not 0.0 <= min_opacity < 1.0:
        raise ConfigError(f"min_opacity must lie in [0, 1), got {min_opacity}")
    return _Outputs(ply, las, extra_fields, min_opacity, crs)


def _neighbours(
    source: PointSource, scan: _Scan, grid: Grid, halo: float, work: Path, glob: _Globals, plan: StreamPlan,
    seconds: dict[str, float],
) -> tuple[int, int]:  # fmt: skip
    """Passes 2–4: bucket, per-cell neighbours, fallback; returns (largest cell + halo, fallback points)."""
    if glob.k < 1:
        return scan.count, 0
    t = time.perf_counter()
    cells = CellFiles(work / "cells", grid, halo)
    for _, piece in rechunk(source, plan.chunk_size):
        cells.add(piece.positions)
    seconds["bucket"] = time.perf_counter() - t
    t = time.perf_counter()
    pca = glob.mode is ConvertMode.ADAPTIVE and scan.missing_normals
    keep = glob.mode is ConvertMode.ADAPTIVE
    failed, biggest, sums = _neighbour_pass(cells, work, glob.k, pca, keep)
    seconds["neighbours"] = time.perf_counter() - t
    t = time.perf_counter()
    fallback, rest = _fallback(source, failed, work, glob.k, pca, plan.chunk_size, keep)
    glob.nearest_sum = math.fsum([*sums, rest])
    seconds["fallback"] = time.perf_counter() - t
    return biggest, fallback


def _global_values(work: Path, grid: Grid, glob: _Globals, stats: ConvertStats, in_memory: int) -> None:
    """Pass 5: paper's clamped d, or adaptive's median clamped spacing; the mean nearest distance for the stats."""
    o, n = glob.options, stats.num_points
    files = _result_files(work, grid)
    if glob.k >= 1:
        stats.mean_nn_spacing = glob.nearest_sum / n
    if glob.mode is ConvertMode.PAPER:
        d = stats.mean_nn_spacing if glob.k >= 1 else o.fallback_spacing
        glob.d = float(np.clip(d, o.min_spacing, o.max_spacing))
        glob.clamped_spacing = n if glob.d != d else 0
        stats.median_spacing = glob.d
        return
    if glob.k >= 1:
        glob.median = _median(_clamped_spacings(files, o.min_spacing, o.max_spacing), n, in_memory)
    else:
        glob.median = float(np.clip(o.fallback_spacing, o.min_spacing, o.max_spacing))
    stats.median_spacing = glob.median


def _warn_like_convert(stats: ConvertStats, glob: _Globals) -> None:
    """The warnings :func:`fusion.convert.convert_points` gives, with the same counts."""
    o, n = glob.options, stats.num_points
    msgs = []
    if stats.missing_colors:
        msgs.append(f"the cloud has no colours; {n} Gaussians get mid grey (128, 128, 128)")
    if glob.k < 1:
        msgs.append(f"a single point has no neighbour; spacing set to fallback_spacing = {o.fallback_spacing} m")
        stats.notes.append("single point: no neighbour, fallback_spacing used")
    if stats.clamped_spacing:
        msgs.append(
            f"spacing clamped to [{o.min_spacing}, {o.max_spacing}] m for {stats.clamped_spacing} of {n} points"
        )
    if stats.clamped_opacity:
        lo, hi = o.opacity_logit_min, o.opacity_logit_max
        msgs.append(f"opacity clamped to [{lo}, {hi}] (stored logit) for {stats.clamped_opacity} of {n} Gaussians")
    for msg in msgs:
        warnings.warn(msg, ConversionWarning, stacklevel=3)
