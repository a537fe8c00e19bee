"""Multi-scale geometric features from the eigenvalues of local covariances.

Scales are a voxel pyramid (Hackel et al. 2016): scale ``s`` works on the cloud voxel-downsampled at
``voxel_factors[s] × spacing`` (a factor ≤ 1 keeps the full cloud), with ``k`` nearest neighbours on that level;
every point takes the features of its nearest level point. Because the voxel sizes are multiples of the median
point spacing, the neighbourhoods scale with the data: a tabletop at 1 mm spacing and a UAV block at 3 cm get
the same neighbourhoods in units of spacing, and a model trained on one applies to the other. The pyramid also
keeps the cost near that of the finest level (each coarser level has ~4× fewer points on surfaces).

Eigen decompositions come from a backend: ``numba`` (threaded closed-form kernel, default), ``numpy`` (the
obvious twin, batched LAPACK ``eigh``) or ``pgeof`` (C++ library). All return (λ, normal); the tests hold the
kernel and the library to the twin.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.spatial import cKDTree

from classify.features.reorder import morton_codes
from core.constraints import Choice, Constrained, Constraints, Interval, SequenceOf
from core.errors import ConfigError, DataError

EIGEN_BACKENDS = ("numba", "numpy", "pgeof")
NEIGHBOUR_SEARCHES = ("grid", "kdtree")


@dataclass(frozen=True)
class GeometricOptions(Constrained):
    """Options of the geometric features.

    voxel_factors: per scale, the voxel size in units of the median point spacing (≤ 1: the full cloud).
        Default (1, 4, 12): the finest neighbourhoods, ~4× and ~12× coarser ones.
    k: neighbours per point on every level (default 16: stable covariances, cheap).
    backend: eigen decomposition: ``numba`` (default, the threaded kernel of :mod:`classify.features.eigen_numba`),
        ``numpy`` (the twin) or ``pgeof`` (library; its middle eigenvalue deviates, see that module).
    spacing_sample: points sampled (seeded) to estimate the median spacing. seed: that sample's seed.
    chunk_size: points per chunk of the k-d tree queries and of the eigen work.
    workers: threads for the k-d tree queries (-1: all cores; the grid search uses numba's thread count).
    search: k-NN search: ``grid`` (default, :func:`core.knn.knn_grid`, exact, less CPU than the tree on survey
        clouds: docs/experiments/2026-11-27-domain-defaults.md) or ``kdtree`` (scipy's cKDTree queried in leaf
        order, the reference).
    """

    voxel_factors: tuple[float, ...] = (1.0, 4.0, 12.0)
    k: int = 16
    backend: str = "numba"
    spacing_sample: int = 100_000
    seed: int = 0
    chunk_size: int = 250_000
    workers: int = -1
    search: str = "grid"

    constraints: ClassVar[Constraints] = {
        "voxel_factors": SequenceOf(Interval(float, 0, None, closed="neither"), min_length=1),
        "k": Interval(int, 3, None),
        "backend": Choice(EIGEN_BACKENDS),
        "chunk_size": Interval(int, 1, None),
        "search": Choice(NEIGHBOUR_SEARCHES),
    }


@dataclass(frozen=True)
class Eigen:
    """Per point: eigenvalues (N, 3) float64 of the neighbourhood covariance, descending, metres²; normal (N, 3)
    float64 unit eigenvector of the smallest eigenvalue (sign arbitrary); radius (N,) float64 metres, the
    distance to the k-th neighbour."""

    values: np.ndarray
    normal: np.ndarray
    radius: np.ndarray


# -- spacing, pyramid, neighbours ----------------------------------------------------------------------------
def spatial_order(
    positions: np.ndarray, bits: int = 16, lo: np.ndarray | None = None, span: float | None = None
) -> np.ndarray:
    """A permutation (N,) int64 that sorts points (N, 3) float64 along a Morton (Z-order) curve of their bounding
    box (``bits`` per axis; or of the cube at ``lo`` (3,) metres of side ``span`` metres, see
    :func:`~classify.features.reorder.morton_codes`): neighbours in space become neighbours in memory, so the k-NN
    gathers of the features hit the cache (clouds are often stored in scan or random order). Ties keep the points'
    order (a stable sort)."""
    return np.argsort(morton_codes(positions, bits, lo, span), kind="stable")


def point_spacing(positions: np.ndarray, sample: int = 100_000, seed: int = 0, workers: int = -1) -> float:
    """Median distance (metres) from a point to its nearest other point, on a seeded sample of ``sample`` points.

    Duplicate points (distance 0) are ignored; a cloud of fewer than 2 distinct points raises :class:`DataError`.
    """
    pts = np.asarray(positions, dtype=np.float64)
    if len(pts) < 2:
        raise DataError(f"point spacing needs at least 2 points, got {len(pts)}")
    rng = np.random.default_rng(seed)
    query = pts if len(pts) <= sample else pts[rng.choice(len(pts), sample, replace=False)]
    d, _ = cKDTree(pts).query(query, k=min(4, len(pts)), workers=workers)
    d = np.asarray(d, dtype=np.float64).reshape(len(query), -1)
    # The nearest non-zero distance per sampled point (rows are sorted, duplicates give 0); median over points.
    nearest = np.where(d > 0, d, np.inf).min(axis=1)
    nearest = nearest[np.isfinite(nearest)]
    if len(nearest) == 0:
        raise DataError("all points coincide: the point spacing is zero")
    return float(np.median(nearest))


def voxel_downsample(
    positions: np.ndarray, voxel: float, origin: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (M, 3) float64 of the occupied voxels of size ``voxel`` metres and, per point, its voxel (N,) int64;
    voxels start at ``origin`` (3,) metres, default the points' minimum."""
    pts = np.asarray(positions, dtype=np.float64)
    lo = pts.min(axis=0) if origin is None else np.asarray(origin, dtype=np.float64)
    keys = np.floor((pts - lo) / voxel).astype(np.int64)
    span = keys.max(axis=0) + 1
    flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
    _, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    sums = np.zeros((len(counts), 3))
    for axis in range(3):
        sums[:, axis] = np.bincount(inverse, weights=pts[:, axis], minlength=len(counts))
    return sums / counts[:, None], inverse.astype(np.int64)


def knn(tree: cKDTree, query: np.ndarray, k: int, workers: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """Distances (N, k) float64 and indices (N, k) int64 of the k nearest tree points (self included)."""
    k = min(k, tree.n)
    d, i = tree.query(query, k=k, workers=workers)
    return np.asarray(d, dtype=np.float64).reshape(len(query), k), np.asarray(i, dtype=np.int64).reshape(len(query), k)


# -- eigen backends ----------------------------------------------------------------------------------------
def _with_self(neighbours: np.ndarray, with_self: bool, offset: int) -> np.ndarray:
    if not with_self:
        return neighbours
    own = np.arange(offset, offset + len(neighbours), dtype=np.int64)[:, None]
    return np.concatenate([own, np.asarray(neighbours, dtype=np.int64)], axis=1)


def eigen_numpy(
    points: np.ndarray, neighbours: np.ndarray, with_self: bool = False, offset: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """The twin: eigenvalues (N, 3) descending and smallest-eigenvector normals (N, 3) of the covariance
    (divided by k) of ``points[neighbours]`` (neighbours (N, k) int64), with numpy's batched ``eigh`` in float64.
    with_self: row i's own point ``offset + i`` belongs to its neighbourhood too, without being listed."""
    neighbours = _with_self(neighbours, with_self, offset)
    x = points[neighbours]
    x = x - x.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", x, x) / neighbours.shape[1]
    w, v = np.linalg.eigh(cov)
    return np.clip(w[:, ::-1], 0.0, None), v[:, :, 0]


def eigen_pgeof(
    points: np.ndarray, neighbours: np.ndarray, with_self: bool = False, offset: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """The library: the same quantities from ``pgeof.compute_features`` (float32 inside).

    pgeof returns length = √λ1, surface = √(√λ1·√λ2), volume = (√λ1·√λ2·√λ3)^(1/3) (checked against the twin in
    the tests); the eigenvalues are recovered from those three, the normal from its normal columns.
    """
    import pgeof

    neighbours = _with_self(neighbours, with_self, offset)
    n, k = neighbours.shape
    centred = (points - points.mean(axis=0)).astype(np.float32)
    nn = neighbours.astype(np.uint32).ravel()
    ptr = np.arange(0, n * k + 1, k, dtype=np.uint32)
    f = pgeof.compute_features(centred, nn, ptr, k_min=1).astype(np.float64)
    s0 = np.maximum(f[:, 7], 0.0)
    tiny = 1e-30
    s1 = np.where(s0 > tiny, f[:, 8] ** 2 / np.maximum(s0, tiny), 0.0)
    s2 = np.where(s0 * s1 > tiny, f[:, 9] ** 3 / np.maximum(s0 * s1, tiny), 0.0)
    s = np.stack([s0, np.minimum(s1, s0), np.minimum(s2, np.minimum(s1, s0))], axis=1)
    normal = f[:, 4:7]
    norm = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(norm > 0, normal / np.maximum(norm, tiny), np.array([0.0, 0.0, 1.0]))
    return s**2, normal


def eigen_backend(name: str) -> Callable[..., tuple[np.ndarray, np.ndarray]]:
    """The eigen function called ``name`` (``pgeof`` falls back to an ImportError message if not installed)."""
    if name == "numpy":
        return eigen_numpy
    if name == "numba":
        from classify.features.eigen_numba import eigen_numba

        return eigen_numba
    if name == "pgeof":
        try:
            import pgeof  # noqa: F401
        except ImportError as err:  # pragma: no cover - pgeof is a dependency
            raise ConfigError("the pgeof backend needs 'pip install pgeof'; or choose backend='numpy'") from err
        return eigen_pgeof
    raise ConfigError(f"eigen backend must be one of {EIGEN_BACKENDS}, got {name!r}")


def level_neighbours(points: np.ndarray, k: int, options: GeometricOptions) -> tuple[np.ndarray, np.ndarray]:
    """Each point's k − 1 nearest *other* points of ``points`` (N, 3) float64 (its neighbourhood of k is itself and
    these): distances (N, k − 1) float64 metres (ascending) and indices (N, k − 1) int64, with the search of
    ``options.search`` (both exact; ties between equidistant neighbours may pick different indices)."""
    from core.knn import drop_self, knn_grid

    n = len(points)
    k = max(2, min(k, n))
    if options.search == "grid" and n > k:
        return knn_grid(points, k - 1)
    # Queries in the tree's leaf order are spatially coherent: ~3-4x faster than input order (scipy walks fewer
    # nodes per query; the same trick as core.knn.knn_kdtree). Results are scattered back to input order.
    tree = cKDTree(points, leafsize=16, balanced_tree=False, compact_nodes=False)
    order = np.asarray(tree.indices)
    dist = np.empty((n, k - 1))
    idx = np.empty((n, k - 1), dtype=np.int64)
    for start in range(0, n, options.chunk_size):
        rows = order[start : start + options.chunk_size]
        d, i = knn(tree, points[rows], k, options.workers)
        dist[rows], idx[rows] = drop_self(d, i, rows)
    return dist, idx


def level_eigen(points: np.ndarray, options: GeometricOptions) -> tuple[Eigen, np.ndarray, np.ndarray]:
    """Eigen analysis of every point of one level with its k nearest neighbours (itself included), chunked.

    Returns the :class:`Eigen`, the indices (N, k − 1) int64 of the neighbours other than the point itself (the
    finest level's are reused for the colour variance) and their distances (N, k − 1) float64 metres, ascending."""
    fn = eigen_backend(options.backend)
    n = len(points)
    dist, neigh = level_neighbours(points, options.k, options)
    values = np.empty((n, 3))
    normal = np.empty((n, 3))
    for start in range(0, n, options.chunk_size):
        sl = slice(start, min(n, start + options.chunk_size))
        values[sl], normal[sl] = fn(points, neigh[sl], True, start)
    return Eigen(values, normal, dist[:, -1].copy()), neigh, dist


def spacing_from_neighbours(dist: np.ndarray) -> float:
    """The median point spacing (metres) from the distances (N, m) float64 to each point's nearest others, rows
    ascending: the median over points of the nearest non-zero distance (what :func:`point_spacing` estimates on
    a sample)."""
    d = dist
    first = np.count_nonzero(d <= 0.0, axis=1)  # duplicates come first in each ascending row
    ok = first < d.shape[1]
    if not ok.any():
        raise DataError("all points coincide: the point spacing is zero")
    return float(np.median(d[np.flatnonzero(ok), first[ok]]))


# -- features from eigenvalues -------------------------------------------------------------------------------
def eigen_features(eig: Eigen, cell: float, k: int) -> dict[str, np.ndarray]:
    """The per-scale features of :data:`classify.features.registry.GEOMETRIC_BASE` from an :class:`Eigen`, except
    ``normal_deviation`` (see :func:`normal_deviation`).

    cell: the scale's cell size in metres (normalises the density). Degenerate neighbourhoods (all eigenvalues
    0, e.g. duplicates) give 0 instead of NaN.
    """
    lam = eig.values
    total = lam.sum(axis=1)
    ok = total > 0
    e = np.where(ok[:, None], lam / np.where(ok, total, 1.0)[:, None], 0.0)
    e1 = np.where(e[:, 0] > 0, e[:, 0], 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ent = -np.sum(np.where(e > 0, e * np.log(np.where(e > 0, e, 1.0)), 0.0), axis=1)
    r = np.maximum(eig.radius, 1e-12)
    out = {
        "linearity": (e[:, 0] - e[:, 1]) / e1,
        "planarity": (e[:, 1] - e[:, 2]) / e1,
        "scattering": e[:, 2] / e1,
        "omnivariance": np.cbrt(e[:, 0] * e[:, 1] * e[:, 2]),
        "anisotropy": (e[:, 0] - e[:, 2]) / e1,
        "eigenentropy": ent,
        "change_of_curvature": e[:, 2],
        "verticality": 1.0 - np.abs(eig.normal[:, 2]),
        "density": np.minimum(k / (np.pi * r**2) * cell**2, 1e3),
        "roughness": np.sqrt(lam[:, 2]) / r,
    }
    for key, value in out.items():
        if key != "density":
            out[key] = np.where(ok, value, 0.0)
    return out


def ground_below(points: np.ndarray, cell: float, origin: np.ndarray | None = None) -> np.ndarray:
    """(M,) float64: the lowest z among ``points`` (M, 3) float64 metres in the 3 × 3 vertical columns of side
    ``cell`` metres around each point's own column ("up" = +z). Columns are floor((x, y) − origin) / cell), origin
    (3,) defaulting to the points' minimum: pass the full cloud's minimum when ``points`` are the centroids of its
    voxels of side ``cell`` (:func:`voxel_downsample`), so that a centroid's column is its voxel's, and that of
    every point in the voxel.

    Columns are keyed sparsely (sorted int64 keys and binary search, O(M log M)): a dense grid over a survey's
    extent at a fine cell size would not fit in memory."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) == 0:
        return np.zeros(0)
    o = pts.min(axis=0) if origin is None else np.asarray(origin, dtype=np.float64)
    ij = np.floor((pts[:, :2] - o[:2]) / cell).astype(np.int64) + 1
    ij -= ij.min(axis=0) - 1
    stride = int(ij[:, 1].max()) + 2
    key = ij[:, 0] * stride + ij[:, 1]
    cols, inverse = np.unique(key, return_inverse=True)
    inverse = inverse.reshape(-1)
    low = np.full(len(cols), np.inf)
    np.minimum.at(low, inverse, pts[:, 2])
    around = low.copy()
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di == 0 and dj == 0:
                continue
            other = cols + di * stride + dj
            pos = np.minimum(np.searchsorted(cols, other), len(cols) - 1)
            hit = cols[pos] == other
            around[hit] = np.minimum(around[hit], low[pos[hit]])
    return around[inverse]


def height_above_ground(points: np.ndarray, cell: float) -> np.ndarray:
    """(M,) float64: (z − :func:`ground_below`) / ``cell`` for points (M, 3) float64 metres: the height above the
    lowest point of the surrounding 3 × 3 columns, in cells (0 for the lowest)."""
    pts = np.asarray(points, dtype=np.float64)
    return (pts[:, 2] - ground_below(pts, cell)) / cell


def normal_deviation(mvs_normals: np.ndarray | None, plane_normals: np.ndarray) -> np.ndarray:
    """1 − |n_mvs · n_plane| per point (N,) float64; 0 where there is no MVS normal (None or zero vectors)."""
    if mvs_normals is None:
        return np.zeros(len(plane_normals))
    nm = np.asarray(mvs_normals, dtype=np.float64)
    norm = np.linalg.norm(nm, axis=1)
    dot = np.abs(np.sum(nm * plane_normals, axis=1)) / np.maximum(norm, 1e-12)
    return np.where(norm > 0, 1.0 - np.clip(dot, 0.0, 1.0), 0.0)


@dataclass(frozen=True)
class GeometricResult:
    """features: name (``linearity_s0``...) → (N,) float32; spacing: median point spacing (metres);
    neighbours: the finest level's k − 1 nearest others of each point (N, k − 1) int64 (the point itself is
    implied) when scale 0 is the full cloud, else None."""

    features: dict[str, np.ndarray]
    spacing: float
    neighbours: np.ndarray | None


def geometric_features(
    positions: np.ndarray,
    mvs_normals: np.ndarray | None = None,
    options: GeometricOptions = GeometricOptions(),
    spacing: float | None = None,
    origin: np.ndarray | None = None,
) -> GeometricResult:
    """Every geometric feature at every scale for points (N, 3) float64 metres (local frame).

    spacing: the median point spacing (metres); estimated from the points when None. origin: (3,) metres, where
    the coarse levels' voxels and ground columns start (default the points' minimum; a part of a cloud passes the
    whole cloud's, :mod:`classify.stream`).
    """
    pts = np.asarray(positions, dtype=np.float64)
    if len(pts) < 3:
        raise DataError(f"geometric features need at least 3 points, got {len(pts)}")
    if not np.isfinite(pts).all():
        raise DataError("positions contain NaN or infinite values")
    feats: dict[str, np.ndarray] = {}
    finest: np.ndarray | None = None
    # the voxels' and ground columns' origin (one (N, 3) reduction, 30 ms at 1 M)
    lowest = pts.min(axis=0) if origin is None else np.asarray(origin, dtype=np.float64)
    for s, factor in enumerate(options.voxel_factors):
        level, per_point = pts, None
        if factor > 1.0:
            if spacing is None:
                spacing = point_spacing(pts, options.spacing_sample, options.seed, options.workers)
            level, per_point = voxel_downsample(pts, factor * spacing, origin=lowest)
            if len(level) < 3:
                level, per_point = pts, None
        eig, neigh, dist = level_eigen(level, options)
        if spacing is None:  # a full-cloud level: its k-NN gives the spacing without another search
            spacing = (
                spacing_from_neighbours(dist) if dist.shape[1] > 1 else point_spacing(pts, workers=options.workers)
            )
        del dist
        cell = factor * spacing
        if s == 0 and per_point is None:
            finest = neigh
        values = eigen_features(eig, cell, min(options.k, len(level)))
        if s >= 1:
            # The point's own z above the ground of its level's columns (each point lies in its voxel's column).
            ground = ground_below(level, cell, origin=lowest)
            feats[f"height_s{s}"] = ((pts[:, 2] - (ground if per_point is None else ground[per_point])) / cell).astype(
                np.float32
            )
        values["normal_deviation"] = normal_deviation(
            mvs_normals, eig.normal if per_point is None else eig.normal[per_point]
        )
        for name, v in values.items():
            v = v.astype(np.float32)  # before the gather: a coarse level has fewer rows than the cloud
            if per_point is not None and name != "normal_deviation":
                v = v[per_point]
            feats[f"{name}_s{s}"] = v
    return GeometricResult(feats, float(spacing), finest)
