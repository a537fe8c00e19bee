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
_HALO = np.dtype([("p", "<f8", 3)])


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


def grid_for(lo: np.ndarray, hi: np.ndarray, count: int, halo: float, points_per_cell: int) -> Grid:
    """A grid over the x-y box [lo, hi] with about ``points_per_cell`` of ``count`` points a cell (uniform density
    assumed), and cells at least 4 halos wide so that halos stay a small share of a cell."""
    width, height = max(float(hi[0] - lo[0]), 1e-9), max(float(hi[1] - lo[1]), 1e-9)
    cells = max(1, math.ceil(count / points_per_cell))
    size = max(math.sqrt(width * height / cells), 4.0 * halo, 1e-9)
    return Grid(float(lo[0]), float(lo[1]), size, max(1, math.ceil(width / size)), max(1, math.ceil(height / size)))


class CellFiles:
    """Append-only files of one cloud's points per cell: ``core_K.bin`` (position and index) and ``halo_K.bin``
    (positions of the neighbours' points within the halo of cell K), float64, in ``folder``."""

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
                    halo["p"] = p[near]
                    self._append("halo", jx[near] * g.ny + jy[near], halo)

    def core(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n, 3), indices (n,)) of the points of cell ``key``."""
        path = self.folder / f"core_{key}.bin"
        rec = np.fromfile(path, _CORE) if path.is_file() else np.empty(0, _CORE)
        return rec["p"], rec["i"]

    def near(self, key: int) -> np.ndarray:
        """(n, 3) positions of cell ``key``'s own points and of its halo."""
        halo_path = self.folder / f"halo_{key}.bin"
        halo = np.fromfile(halo_path, _HALO)["p"] if halo_path.is_file() else np.empty((0, 3))
        return np.concatenate([self.core(key)[0], halo])


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
