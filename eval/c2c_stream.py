"""Out-of-core C2C for clouds larger than memory (issue 34): bucket both clouds on disk, then one cell at a time.

:func:`eval.c2c.compare_clouds` holds both clouds and a kd-tree over the reference in memory: 100 million points are
2.4 GB of float64 positions alone. :func:`streamed_c2c` instead reads each cloud as a stream of chunks (a LAS/LAZ
file through laspy's chunk iterator, or any re-iterable source), writes every point into the file of its grid
cell (a 2-D grid over x, y, sized so that a cell holds about ``points_per_cell`` points) and also into the files of
the neighbouring cells whose rectangle lies within ``halo`` of it (their halo). A cell's queries then need only
its own file and its halo: every point within ``halo`` of a query point in the cell's rectangle is there (the 3-D
distance is at least the x-y distance). Memory is bounded by a chunk and a cell, not by the clouds.

What it gives up against the in-memory C2C, and why: distances are searched up to ``halo`` only (farther points get
``halo``, as ``compare_clouds`` does with ``max_dist``; ``halo`` ≥ τ keeps precision and completeness exact), the
reverse distances too (their statistics count a clamped distance as an outlier), and statistics per class are not
kept. No library does this: scipy's and open3d's trees are in memory, PDAL's ``filters.neighborclassifier`` is not
a distance, and CloudCompare's octree C2C is a desktop tool.

The eval stage's path (``run --memory-limit``, :mod:`eval.geometry_stream`) goes further, with the same cells:
:func:`exact_nearest` searches the points with no neighbour within the halo in the whole other cloud, chunk by chunk,
so that every distance both ways (and the index of the nearest reference point) equals the in-memory search's, and
:func:`streamed_distance_stats` gives :func:`eval.c2c.distance_stats` of a memory-mapped array by chunks, its
percentiles exact (:func:`order_statistics`, a radix selection), its mean / std / rmse within a few ulps.
:func:`plan_c2c_memory` turns a limit in MiB into the cell and chunk sizes.

Units: metres, positions in one local float64 frame chosen by the caller (:func:`las_chunks` takes the origin).
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from core.errors import ConfigError, DataError
from eval.c2c import DistanceStats, ThresholdScores

ChunkSource = Callable[[], Iterable[np.ndarray]]
"""A re-iterable source of (n, 3) float64 positions (metres, local frame): called once per pass over the cloud."""

DEFAULT_POINTS_PER_CELL = 2_000_000
DEFAULT_CHUNK = 2_000_000
_CORE = np.dtype([("p", "<f8", 3), ("i", "<i8")])  # a point of the cell's own and its index in its cloud
_HALO = np.dtype([("p", "<f8", 3), ("i", "<i8")])  # a neighbour's point within the halo and its index


@dataclass(frozen=True)
class Grid:
    """A 2-D grid over x, y: cell (ix, iy) covers [x0 + ix·cell, x0 + (ix+1)·cell) × [y0 + iy·cell, …)."""

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int

    def cell_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cell indices of (n, 2) points, clipped to the grid (points beyond it belong to the border cells)."""
        ix = np.clip(np.floor((xy[:, 0] - self.x0) / self.cell), 0, self.nx - 1).astype(np.int64)
        iy = np.clip(np.floor((xy[:, 1] - self.y0) / self.cell), 0, self.ny - 1).astype(np.int64)
        return ix, iy


def memory_work_mb(
    limit_mb: float, base_mb: float, min_work_mb: float, what: str, base_for: str, work_for: str
) -> float:
    """The MiB a streamed step may use above ``base_mb`` under ``limit_mb``; a :class:`ConfigError` naming the value
    when it is not a finite number or leaves less than ``min_work_mb`` (``what``: the step; ``base_for`` and
    ``work_for``: what the two parts hold, for the message)."""
    if not (isinstance(limit_mb, int | float) and math.isfinite(limit_mb)):
        raise ConfigError(f"memory_limit_mb must be a finite number of MiB, got {limit_mb!r}")
    work = limit_mb - base_mb
    if work < min_work_mb:
        raise ConfigError(
            f"memory_limit_mb = {limit_mb:g} is too small for {what}: it needs at least {base_mb + min_work_mb:g} MiB "
            f"({base_mb:g} for {base_for}, {min_work_mb:g} for {work_for})"
        )
    return work


def chunk_results(positions: np.ndarray, grid: Grid, work: Path, cursor: dict[int, int], dtype: np.dtype) -> np.ndarray:
    """The per-point result records (``dtype``) of a chunk's (n, 3) positions, in chunk order, read from the cell
    files ``work/res_{cell}.bin`` that a cell pass wrote in source order: each cell's next records (``cursor``: the
    records of each cell read so far, updated). A :class:`DataError` when a cell has fewer records left than the
    chunk has points in it (the source gave other points on this pass)."""
    ix, iy = grid.cell_of(positions[:, :2])
    keys = ix * grid.ny + iy
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    out = np.empty(len(positions), dtype)
    starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], len(keys)], strict=True):
        key = int(sorted_keys[a])
        at = cursor.get(key, 0)
        rec = np.fromfile(work / f"res_{key}.bin", dtype, count=b - a, offset=at * dtype.itemsize)
        if len(rec) != b - a:
            raise DataError(f"the source gave other points on this pass than before (cell {key})")
        out[order[a:b]] = rec
        cursor[key] = at + (b - a)
    return out


def grid_for(lo: np.ndarray, hi: np.ndarray, count: int, halo: float, points_per_cell: int) -> Grid:
    """A grid over the x-y box [lo, hi] with about ``points_per_cell`` of ``count`` points a cell (uniform density
    assumed), and cells at least 4 halos wide so that halos stay a small share of a cell."""
    width, height = max(float(hi[0] - lo[0]), 1e-9), max(float(hi[1] - lo[1]), 1e-9)
    cells = max(1, math.ceil(count / points_per_cell))
    size = max(math.sqrt(width * height / cells), 4.0 * halo, 1e-9)
    return Grid(float(lo[0]), float(lo[1]), size, max(1, math.ceil(width / size)), max(1, math.ceil(height / size)))


class CellFiles:
    """Append-only files of one cloud's points per cell: ``core_K.bin`` (position and index) and ``halo_K.bin``
    (positions and indices of the neighbours' points within the halo of cell K), float64 / int64, in ``folder``."""

    def __init__(self, folder: Path, grid: Grid, halo: float) -> None:
        self.folder, self.grid, self.halo = folder, grid, halo
        folder.mkdir(parents=True, exist_ok=True)
        self.count = 0

    def _append(self, kind: str, keys: np.ndarray, records: np.ndarray) -> None:
        order = np.argsort(keys, kind="stable")
        keys, records = keys[order], records[order]
        starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
        for start, stop in zip(starts, np.r_[starts[1:], len(keys)], strict=True):
            with open(self.folder / f"{kind}_{keys[start]}.bin", "ab") as f:
                f.write(records[start:stop].tobytes())

    def add(self, positions: np.ndarray) -> None:
        """Append a chunk: each point to its cell's core, and to the halo of each neighbour within ``halo``."""
        p = np.ascontiguousarray(positions, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or not np.isfinite(p).all():
            raise DataError(f"a chunk of positions must be finite with shape (n, 3), got {p.shape}")
        g = self.grid
        ix, iy = g.cell_of(p[:, :2])
        core = np.empty(len(p), _CORE)
        core["p"], core["i"] = p, np.arange(self.count, self.count + len(p))
        self._append("core", ix * g.ny + iy, core)
        self.count += len(p)
        # distance from each point to the border it shares with the neighbour on each side (metres, >= 0)
        left = p[:, 0] - (g.x0 + ix * g.cell)
        right = g.x0 + (ix + 1) * g.cell - p[:, 0]
        below = p[:, 1] - (g.y0 + iy * g.cell)
        above = g.y0 + (iy + 1) * g.cell - p[:, 1]
        for dx in (-1, 0, 1):
            gap_x = {-1: left, 0: 0.0, 1: right}[dx]
            for dy in (-1, 0, 1):
                if dx == dy == 0:
                    continue
                gap_y = {-1: below, 0: 0.0, 1: above}[dy]
                jx, jy = ix + dx, iy + dy
                near = (np.square(gap_x) + np.square(gap_y) <= self.halo**2) & (jx >= 0) & (jx < g.nx)
                near &= (jy >= 0) & (jy < g.ny)
                if near.any():
                    halo = np.empty(int(near.sum()), _HALO)
                    halo["p"], halo["i"] = p[near], core["i"][near]
                    self._append("halo", jx[near] * g.ny + jy[near], halo)

    def core(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n, 3), indices (n,)) of the points of cell ``key``."""
        path = self.folder / f"core_{key}.bin"
        rec = np.fromfile(path, _CORE) if path.is_file() else np.empty(0, _CORE)
        return rec["p"], rec["i"]

    def near(self, key: int) -> np.ndarray:
        """(n, 3) positions of cell ``key``'s own points and of its halo."""
        return self.near_indexed(key)[0]

    def near_indexed(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n, 3), indices (n,) in the cloud's order) of cell ``key``'s own points and of its halo."""
        halo_path = self.folder / f"halo_{key}.bin"
        halo = np.fromfile(halo_path, _HALO) if halo_path.is_file() else np.empty(0, _HALO)
        points, index = self.core(key)
        return np.concatenate([points, halo["p"]]), np.concatenate([index, halo["i"]])


def las_chunks(path: str | PathLike[str], origin: np.ndarray, chunk: int = DEFAULT_CHUNK) -> ChunkSource:
    """A chunk source over a LAS/LAZ file: float64 positions relative to ``origin`` (world metres), ``chunk`` points
    at a time, the large offset cancelled before the small part is added (as :func:`core.io.las.read_las` does)."""
    import laspy

    path = Path(path)
    origin = np.asarray(origin, dtype=np.float64)

    def chunks() -> Iterator[np.ndarray]:
        with laspy.open(path) as reader:
            scales = np.asarray(reader.header.scales, dtype=np.float64)
            offsets = np.asarray(reader.header.offsets, dtype=np.float64)
            for points in reader.chunk_iterator(chunk):
                ints = np.stack([np.asarray(points.X), np.asarray(points.Y), np.asarray(points.Z)], axis=1)
                yield ints.astype(np.float64) * scales + (offsets - origin)

    return chunks


def array_chunks(positions: np.ndarray, chunk: int = DEFAULT_CHUNK) -> ChunkSource:
    """A chunk source over an in-memory (n, 3) array (tests, small clouds)."""
    return lambda: (positions[i : i + chunk] for i in range(0, len(positions), chunk))


@dataclass(frozen=True)
class StreamedC2C:
    """C2C of a streamed comparison: statistics of the compared → reference distances (metres; distances at
    ``halo`` are outliers), of the reverse ones, scores at τ, the grid used, and where the distances are
    (float32, in the compared cloud's order, in a file ``distances_path`` when one was asked for)."""

    stats: DistanceStats
    reverse: DistanceStats
    scores: ThresholdScores | None
    grid: Grid
    distances_path: Path | None


def _bounds(sources: Iterable[ChunkSource]) -> tuple[np.ndarray, np.ndarray, int, int]:
    lo, hi, counts = np.full(3, np.inf), np.full(3, -np.inf), []
    for source in sources:
        n = 0
        for c in source():
            if np.ndim(c) != 2 or np.shape(c)[1] != 3 or not np.isfinite(c).all():
                raise DataError(f"a chunk of positions must be finite with shape (n, 3), got {np.shape(c)}")
            if len(c):
                lo, hi = np.minimum(lo, c.min(axis=0)), np.maximum(hi, c.max(axis=0))
            n += len(c)
        counts.append(n)
    return lo, hi, counts[0], counts[1]


def _distances(queries: CellFiles, targets: CellFiles, out: np.memmap, halo: float, workers: int) -> None:
    """For every point of ``queries``, the distance to the nearest point of ``targets`` up to ``halo``."""
    g = queries.grid
    for key in range(g.nx * g.ny):
        points, index = queries.core(key)
        if not len(points):
            continue
        near = targets.near(key)
        if not len(near):
            out[index] = halo
            continue
        d, _ = cKDTree(near, balanced_tree=False, compact_nodes=False).query(
            points, k=1, distance_upper_bound=halo, workers=workers
        )
        out[index] = np.minimum(d, halo)


def _stats(distances: np.ndarray, halo: float, chunk: int = 10_000_000) -> DistanceStats:
    """:class:`DistanceStats` of float32 distances with those at ``halo`` as outliers; float64 sums by chunks."""
    n = len(distances)
    count = 0
    total = total_sq = 0.0
    lo, hi = math.inf, 0.0
    for start in range(0, n, chunk):
        d = np.asarray(distances[start : start + chunk], dtype=np.float64)
        d = d[d < halo]
        count += len(d)
        total += float(d.sum())
        total_sq += float(np.square(d).sum())
        if len(d):
            lo, hi = min(lo, float(d.min())), max(hi, float(d.max()))
    outliers = n - count
    if count == 0:
        return DistanceStats(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, halo, outliers, outliers / max(n, 1))
    kept = np.asarray(distances)
    kept = kept[kept < np.float32(halo)]
    p50, p90, p95, p99 = (float(v) for v in np.percentile(kept, [50, 90, 95, 99]))
    mean = total / count
    return DistanceStats(
        count=count,
        mean=mean,
        std=math.sqrt(max(total_sq / count - mean * mean, 0.0)),
        median=p50,
        rmse=math.sqrt(total_sq / count),
        p90=p90,
        p95=p95,
        p99=p99,
        min=lo,
        max=hi,
        max_dist=halo,
        outlier_count=outliers,
        outlier_share=outliers / n,
    )


def streamed_c2c(
    compared: ChunkSource,
    reference: ChunkSource,
    halo: float,
    tau: float | None = None,
    *,
    work_dir: str | PathLike[str] | None = None,
    points_per_cell: int = DEFAULT_POINTS_PER_CELL,
    distances_path: str | PathLike[str] | None = None,
    workers: int = -1,
) -> StreamedC2C:
    """C2C of ``compared`` against ``reference`` (chunk sources in one local frame) with bounded memory.

    halo: the search radius (metres): distances beyond it are reported as ``halo`` (outliers), both ways; must be
    ≥ ``tau`` so that the scores at τ are exact. work_dir: where the cell files go (a temporary folder by default;
    about 32 bytes a point per cloud, plus the halos). distances_path: keep the compared → reference distances there
    (float32, the compared cloud's order); otherwise a temporary file. Two passes over each source (bounds, then
    cells), then one kd-tree per cell and direction.
    """
    if not (halo > 0 and math.isfinite(halo)):
        raise ConfigError(f"halo must be a positive finite distance in metres, got {halo}")
    if tau is not None and not (0 < tau <= halo):
        raise ConfigError(f"tau must lie in (0, halo = {halo}] m so that the scores are exact, got {tau}")
    if points_per_cell < 1:
        raise ConfigError(f"points_per_cell must be >= 1, got {points_per_cell}")
    lo, hi, n_cmp, n_ref = _bounds((compared, reference))
    if n_cmp == 0 or n_ref == 0:
        raise DataError(f"C2C needs points in both clouds (compared {n_cmp}, reference {n_ref})")
    grid = grid_for(lo, hi, max(n_cmp, n_ref), halo, points_per_cell)
    with tempfile.TemporaryDirectory(prefix="hybridsplat_c2c_", dir=work_dir) as tmp:
        cells = {}
        for name, source in (("compared", compared), ("reference", reference)):
            cells[name] = CellFiles(Path(tmp) / name, grid, halo)
            for chunk in source():
                cells[name].add(chunk)
        forward_path = Path(distances_path) if distances_path else Path(tmp) / "forward.f32"
        forward = np.lib.format.open_memmap(forward_path, mode="w+", dtype=np.float32, shape=(n_cmp,))
        _distances(cells["compared"], cells["reference"], forward, halo, workers)
        backward = np.lib.format.open_memmap(Path(tmp) / "reverse.f32", mode="w+", dtype=np.float32, shape=(n_ref,))
        _distances(cells["reference"], cells["compared"], backward, halo, workers)
        stats, reverse = _stats(forward, halo), _stats(backward, halo)
        scores = None
        if tau is not None:
            precision = float(np.count_nonzero(forward < np.float32(tau))) / n_cmp
            recall = float(np.count_nonzero(backward < np.float32(tau))) / n_ref
            f = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
            scores = ThresholdScores(float(tau), precision, recall, f)
        forward.flush()
        del forward, backward
    return StreamedC2C(stats, reverse, scores, grid, Path(distances_path) if distances_path else None)


# -- exact distances both ways (the eval stage's streamed path) ---------------------------------------------------

_FAR = np.dtype([("p", "<f8", 3), ("i", "<i8")])  # a query point with no target within the halo, and its index
_SURE = 1.0 - 1e-9  # a distance found below halo·_SURE is exact; at or above it the whole other cloud is searched


@dataclass(frozen=True)
class ExactNearest:
    """Nearest-neighbour distances both ways of a streamed comparison, exact (not bounded by the halo), in
    memory-mapped ``.npy`` files under the caller's work folder (valid while it exists).

    forward: (n_compared,) float64 metres, compared → reference, in the compared cloud's order.
    nearest: (n_compared,) int64 index (reference order) of that nearest reference point (ties: either one).
    reverse: (n_reference,) float64 metres, reference → compared, in the reference's order; ``inf`` for points with
        no compared point within the halo when ``exact_reverse`` was off.
    far: how many points of each direction were farther than the halo and searched in the whole other cloud.
    """

    forward: np.ndarray
    nearest: np.ndarray
    reverse: np.ndarray
    grid: Grid
    far: tuple[int, int]


def _exact_cells(queries: CellFiles, targets: CellFiles, dist: np.ndarray, index: np.ndarray | None,
                 far_path: Path, workers: int) -> int:  # fmt: skip
    """Distances (and target indices) of every query point whose nearest target lies within the halo; the others
    are appended to ``far_path`` (position, index) for :func:`_exact_far`. Returns how many went there."""
    g, bound, far = queries.grid, queries.halo, 0
    with open(far_path, "wb") as out:
        for key in range(g.nx * g.ny):
            points, mine = queries.core(key)
            if not len(points):
                continue
            near, theirs = targets.near_indexed(key)
            if len(near):
                tree = cKDTree(near, balanced_tree=False, compact_nodes=False)
                d, j = tree.query(points, k=1, distance_upper_bound=bound, workers=workers)
            else:
                d, j = np.full(len(points), np.inf), np.zeros(len(points), np.int64)
            sure = d < bound * _SURE
            dist[mine[sure]] = d[sure]
            if index is not None:
                index[mine[sure]] = theirs[j[sure]]
            rec = np.empty(int((~sure).sum()), _FAR)
            rec["p"], rec["i"] = points[~sure], mine[~sure]
            out.write(rec.tobytes())
            far += len(rec)
    return far


def _exact_far(far_path: Path, targets: ChunkSource, dist: np.ndarray, index: np.ndarray | None, block: int,
               workers: int) -> None:  # fmt: skip
    """The nearest target of each point in ``far_path``, over the whole target cloud: per block of far points,
    one pass over the targets' chunks with a kd-tree per chunk (memory: a block and a chunk)."""
    total = far_path.stat().st_size // _FAR.itemsize
    for start in range(0, total, block):
        rec = np.fromfile(far_path, _FAR, count=min(block, total - start), offset=start * _FAR.itemsize)
        best, arg, offset = np.full(len(rec), np.inf), np.zeros(len(rec), np.int64), 0
        for chunk in targets():
            if len(chunk):
                d, j = cKDTree(chunk, balanced_tree=False, compact_nodes=False).query(rec["p"], k=1, workers=workers)
                better = d < best  # the first chunk's neighbour wins a tie, as a tree over the whole cloud may not
                best[better], arg[better] = d[better], j[better] + offset
            offset += len(chunk)
        dist[rec["i"]] = best
        if index is not None:
            index[rec["i"]] = arg


def exact_nearest(
    compared: ChunkSource,
    reference: ChunkSource,
    halo: float,
    work_dir: str | PathLike[str],
    *,
    points_per_cell: int = DEFAULT_POINTS_PER_CELL,
    block: int = DEFAULT_CHUNK,
    exact_reverse: bool = True,
    workers: int = -1,
) -> ExactNearest:
    """Exact C2C distances both ways with bounded memory: the cell pass of :func:`streamed_c2c` (neighbours up to
    ``halo`` metres), then, for the points with none that near, a search of the whole other cloud chunk by chunk
    (:func:`_exact_far`; ``exact_reverse`` off leaves the reverse ones at ``inf``, enough for scores at τ ≤ halo).

    The distances equal :func:`eval.c2c.nearest_distances` bit for bit when the sources yield the positions of the
    in-memory arrays (the distance of one pair of points does not depend on the tree that finds it). Files (cells,
    distances: 32 bytes a point and its halo copies, + 16 / 8 bytes a compared / reference point) go in
    ``work_dir``, which must outlive the result's arrays; ``block``: far points searched at a time.
    """
    if not (halo > 0 and math.isfinite(halo)):
        raise ConfigError(f"halo must be a positive finite distance in metres, got {halo}")
    if points_per_cell < 1 or block < 1:
        raise ConfigError(f"points_per_cell and block must be >= 1, got {points_per_cell}, {block}")
    lo, hi, n_cmp, n_ref = _bounds((compared, reference))
    if n_cmp == 0 or n_ref == 0:
        raise DataError(f"C2C needs points in both clouds (compared {n_cmp}, reference {n_ref})")
    grid = grid_for(lo, hi, max(n_cmp, n_ref), halo, points_per_cell)
    work = Path(work_dir)
    cells = {}
    for name, source in (("compared", compared), ("reference", reference)):
        cells[name] = CellFiles(work / name, grid, halo)
        for chunk in source():
            cells[name].add(chunk)
    forward = np.lib.format.open_memmap(work / "forward.npy", mode="w+", dtype=np.float64, shape=(n_cmp,))
    nearest = np.lib.format.open_memmap(work / "nearest.npy", mode="w+", dtype=np.int64, shape=(n_cmp,))
    reverse = np.lib.format.open_memmap(work / "reverse.npy", mode="w+", dtype=np.float64, shape=(n_ref,))
    far_fwd = _exact_cells(cells["compared"], cells["reference"], forward, nearest, work / "far_fwd.bin", workers)
    far_rev = _exact_cells(cells["reference"], cells["compared"], reverse, None, work / "far_rev.bin", workers)
    for name in ("compared", "reference"):  # the cell files are no longer needed
        for path in (work / name).iterdir():
            path.unlink()
        (work / name).rmdir()
    _exact_far(work / "far_fwd.bin", reference, forward, nearest, block, workers)
    if exact_reverse:
        _exact_far(work / "far_rev.bin", compared, reverse, None, block, workers)
    else:
        total = (work / "far_rev.bin").stat().st_size // _FAR.itemsize
        for start in range(0, total, block):
            rec = np.fromfile(work / "far_rev.bin", _FAR, count=min(block, total - start), offset=start * _FAR.itemsize)
            reverse[rec["i"]] = np.inf
    return ExactNearest(forward, nearest, reverse, grid, (far_fwd, far_rev))


_PERCENTILES = (50, 90, 95, 99)  # as eval.c2c.distance_stats reports them


def order_statistics(values: np.ndarray, ranks: Iterable[int], upper: float | None = None,
                     chunk: int = DEFAULT_CHUNK) -> dict[int, float]:  # fmt: skip
    """The exact ``k``-th smallest (0-based) of the values below ``upper`` (every one when None) of ``values``, a
    (n,) float64 array ≥ 0 such as a memory map, read ``chunk`` at a time: radix selection on the IEEE-754 bit
    patterns (ordered as the values for non-negative floats), 16 bits a pass, four passes; memory: a chunk and a
    65 536-bin histogram a rank."""
    wanted = sorted(set(int(r) for r in ranks))
    prefix, left = dict.fromkeys(wanted, 0), {r: r for r in wanted}
    for shift in (48, 32, 16, 0):
        hist = {r: np.zeros(1 << 16, np.int64) for r in wanted}
        for start in range(0, len(values), chunk):
            v = np.asarray(values[start : start + chunk], dtype=np.float64)
            bits = (v[v < upper] if upper is not None else v).view(np.uint64)
            digit = ((bits >> np.uint64(shift)) & np.uint64(0xFFFF)).astype(np.int64)
            high = bits >> np.uint64(shift + 16) if shift < 48 else None
            for r in wanted:
                hist[r] += np.bincount(
                    digit if high is None else digit[high == np.uint64(prefix[r])], minlength=1 << 16
                )
        for r in wanted:
            cum = np.cumsum(hist[r])
            b = int(np.searchsorted(cum, left[r], side="right"))
            left[r] -= int(cum[b - 1]) if b else 0
            prefix[r] = (prefix[r] << 16) | b
    return {r: float(np.array([prefix[r]], np.uint64).view(np.float64)[0]) for r in wanted}


def percentiles_linear(
    count: int, qs: Iterable[float], value_at: Callable[[Iterable[int]], dict[int, float]]
) -> list[float]:
    """``np.percentile(x, qs)`` (method ``linear``) of ``count`` values from their order statistics ``value_at``
    (ranks → values), with numpy's own arithmetic (virtual index (n − 1)·q/100, its two-sided interpolation) so that
    the figures equal numpy's bit for bit (tests/test_eval_stream.py holds them to it)."""
    positions = []
    for q in qs:
        virtual = (count - 1) * np.true_divide(q, 100)
        prev = min(int(np.floor(virtual)), count - 1)
        positions.append((prev, min(prev + 1, count - 1), virtual - prev))
    values = value_at([r for p in positions for r in p[:2]])
    out = []
    for prev, nxt, gamma in positions:
        a, b = values[prev], values[nxt]
        diff = b - a
        out.append(float(b - diff * (1 - gamma)) if gamma >= 0.5 else float(a + diff * gamma))
    return out


def streamed_distance_stats(distances: np.ndarray, max_dist: float | None = None,
                            chunk: int = DEFAULT_CHUNK) -> DistanceStats:  # fmt: skip
    """:func:`eval.c2c.distance_stats` of (n,) float64 distances (metres; a memory map) read ``chunk`` at a time.

    Counts, outliers, min, max and the percentiles are exact (:func:`order_statistics`); mean, std and rmse are
    float64 sums by chunks, in another order than numpy's pairwise sums: they differ from the in-memory figures by
    a few ulps (relative 1e-12 is far above it)."""
    n = len(distances)
    count, total, lo, hi = 0, 0.0, math.inf, -math.inf
    for start in range(0, n, chunk):
        d = np.asarray(distances[start : start + chunk], dtype=np.float64)
        if not np.isfinite(d).all():
            raise DataError("distances contain NaN or infinite values")
        d = d[d < max_dist] if max_dist is not None else d
        count, total = count + len(d), total + float(d.sum())
        if len(d):
            lo, hi = min(lo, float(d.min())), max(hi, float(d.max()))
    outliers = n - count
    share = outliers / n if n else 0.0
    if count == 0:
        return DistanceStats(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, max_dist, outliers, share)
    mean, spread, squares = total / count, 0.0, 0.0
    for start in range(0, n, chunk):
        d = np.asarray(distances[start : start + chunk], dtype=np.float64)
        d = d[d < max_dist] if max_dist is not None else d
        spread, squares = spread + float(np.square(d - mean).sum()), squares + float(np.square(d).sum())
    p50, p90, p95, p99 = percentiles_linear(
        count, _PERCENTILES, lambda ranks: order_statistics(distances, ranks, max_dist, chunk)
    )
    return DistanceStats(
        count=count,
        mean=mean,
        std=math.sqrt(max(spread / count, 0.0)),
        median=p50,
        rmse=math.sqrt(squares / count),
        p90=p90,
        p95=p95,
        p99=p99,
        min=lo,
        max=hi,
        max_dist=max_dist,
        outlier_count=outliers,
        outlier_share=share,
    )


# -- memory plan ------------------------------------------------------------------------------------------------

BASE_MB = 512.0
"""Memory (MiB) the eval stage holds besides the streamed C2C: interpreter, numpy/scipy/laspy, the product measured
(its cloud and Gaussians, in memory for the renders and the distance clouds) on a small project."""
MIN_WORK_MB = 64.0
"""The least memory beyond :data:`BASE_MB` the streamed C2C works in (MiB)."""
_CELL_POINT_BYTES = 200  # a point of a cell: record 32, positions for the tree 24 + tree ~40, results 16, halo share
_CHUNK_POINT_BYTES = 160  # a point of a read chunk: positions 24, LAS record ~40, colours, normals, fields, copies


@dataclass(frozen=True)
class C2CPlan:
    """Sizes of the streamed C2C for a memory limit: ``points_per_cell`` (of both clouds together, about) and
    ``chunk`` (points read at a time, and far points searched at a time)."""

    memory_limit_mb: float
    points_per_cell: int
    chunk: int


def plan_c2c_memory(memory_limit_mb: float) -> C2CPlan:
    """Cell and chunk sizes for a peak resident memory of about ``memory_limit_mb`` (MiB) in the eval stage: of
    what is left above :data:`BASE_MB`, 50 % to a cell (both clouds' points there), 25 % to a chunk. Raises
    :class:`ConfigError` naming the value when less than :data:`MIN_WORK_MB` would be left."""
    work = memory_work_mb(
        memory_limit_mb,
        BASE_MB,
        MIN_WORK_MB,
        "the streamed C2C of the eval stage",
        "the interpreter, libraries and the product",
        "a cell and a chunk",
    )
    work_bytes = work * 2**20
    cell = max(1000, int(0.5 * work_bytes / _CELL_POINT_BYTES) // 2)  # the two clouds share a cell
    chunk = max(1000, int(0.25 * work_bytes / _CHUNK_POINT_BYTES))
    return C2CPlan(float(memory_limit_mb), cell, chunk)
