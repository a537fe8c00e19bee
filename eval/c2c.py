"""Cloud-to-cloud (C2C) distances as CloudCompare defines them, their statistics, and threshold scores.

For every point of the *compared* cloud, the distance (metres) to the nearest point of the *reference*
cloud. Both clouds are first expressed relative to ONE local origin in float64, so georeferenced data
(UTM, national grids) keeps millimetres. Nearest neighbours come from scipy's ``cKDTree`` queried in
chunks (bounded memory) on all cores, with the queries sorted along a Morton curve so that consecutive
queries walk the same tree branches (faster on surface-like clouds than unsorted queries; the timing:
docs/experiments/2026-11-27-domain-defaults.md).

Threshold scores follow Tanks and Temples / ETH3D: at a distance τ,
``precision = share of compared points with d(compared -> reference) < τ``,
``recall = completeness = share of reference points with d(reference -> compared) < τ``,
``F = 2 P R / (P + R)`` (0 when both are 0).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from core.errors import ConfigError, DataError
from core.pointcloud import PointCloud, choose_origin

DEFAULT_CHUNK = 1_000_000


@dataclass(frozen=True)
class DistanceStats:
    """Statistics of a set of distances (metres).

    Statistics cover the inliers (distance < ``max_dist``) when ``max_dist`` is set, every distance
    otherwise. ``std`` is the population standard deviation (ddof=0, as CloudCompare reports it).
    Percentiles use linear interpolation. An empty set gives zeros, never NaN.
    """

    count: int
    mean: float
    std: float
    median: float
    rmse: float
    p90: float
    p95: float
    p99: float
    min: float
    max: float
    max_dist: float | None = None
    outlier_count: int = 0
    outlier_share: float = 0.0

    def as_dict(self) -> dict[str, float | int | None]:
        """A JSON-ready mapping with the field names as keys."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class ThresholdScores:
    """Precision / recall (completeness) / F-score at a distance threshold ``tau`` (metres), shares in [0, 1]."""

    tau: float
    precision: float
    recall: float
    fscore: float

    @property
    def completeness(self) -> float:
        """Completeness is the recall: share of reference points within τ of the compared cloud."""
        return self.recall

    def as_dict(self) -> dict[str, float]:
        return {
            "tau": self.tau,
            "precision": self.precision,
            "recall": self.recall,
            "completeness": self.recall,
            "fscore": self.fscore,
        }


@dataclass(frozen=True)
class C2CResult:
    """Everything one C2C comparison measured.

    distances: (N,) float64 compared -> reference distances in metres (outliers beyond ``max_dist`` are
        clamped to ``max_dist``, as CloudCompare does when a maximum distance is set).
    stats: statistics of ``distances`` (inliers only when ``max_dist`` is set).
    reverse: statistics of reference -> compared distances (computed when ``tau`` is given), else None.
    scores: precision / recall / F-score at ``tau``, else None.
    per_class: statistics per value of the compared cloud's ``classification`` field (empty when absent).
    """

    distances: np.ndarray
    stats: DistanceStats
    reverse: DistanceStats | None = None
    scores: ThresholdScores | None = None
    per_class: Mapping[int, DistanceStats] = field(default_factory=dict)


def common_origin(*clouds: PointCloud) -> np.ndarray:
    """(3,) float64 world origin shared by ``clouds``: the first cloud's origin plus its rounded bbox centre.

    When the first cloud already sits near its origin (|local| < 1e4 m) its origin is returned unchanged.
    """
    if not clouds:
        raise DataError("common_origin needs at least one cloud")
    first = clouds[0]
    if len(first) == 0:
        return first.origin.copy()
    return first.origin + choose_origin(first.positions)


def morton_order(points: np.ndarray, bits: int = 21) -> np.ndarray:
    """(N,) int64 permutation sorting ``points`` (N, 3) along a 3-D Morton (Z-order) curve.

    Coordinates are quantised to ``bits`` bits per axis over the bounding box.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) == 0:
        return np.zeros(0, dtype=np.int64)
    lo = pts.min(axis=0)
    extent = float(max((pts.max(axis=0) - lo).max(), 1e-12))
    scale = ((1 << bits) - 1) / extent
    code = np.zeros(len(pts), dtype=np.uint64)
    for axis in range(3):
        q = ((pts[:, axis] - lo[axis]) * scale).astype(np.uint64)
        code |= _spread_bits(q) << np.uint64(axis)
    return np.argsort(code, kind="stable")


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """Insert two zero bits between each of the low 21 bits of ``v`` (uint64), for Morton codes."""
    v = v & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


def build_tree(reference: np.ndarray) -> cKDTree:
    """A kd-tree over (M, 3) float64 reference positions (sliding-midpoint build: faster, same answers)."""
    ref = np.ascontiguousarray(reference, dtype=np.float64)
    if ref.ndim != 2 or ref.shape[1] != 3:
        raise DataError(f"reference positions must have shape (M, 3), got {ref.shape}")
    if len(ref) == 0:
        raise DataError("the reference cloud is empty; C2C needs at least one reference point")
    return cKDTree(ref, balanced_tree=False, compact_nodes=False)


def nearest_distances(
    compared: np.ndarray,
    reference: np.ndarray | cKDTree,
    max_dist: float | None = None,
    chunk_size: int = DEFAULT_CHUNK,
    workers: int = -1,
    sort_queries: bool = True,
) -> np.ndarray:
    """Distance from each compared point to its nearest reference point.

    Parameters
    ----------
    compared: (N, 3) float64 positions, metres, in the same local frame as ``reference``.
    reference: (M, 3) float64 positions in that frame, or a tree from :func:`build_tree`.
    max_dist: if given, the search stops at this distance and farther points get ``max_dist`` (clamped).
    chunk_size: queries per chunk (memory stays O(chunk_size) beyond the inputs and the tree).
    workers: threads for the tree queries (-1: all cores).
    sort_queries: query in Morton order (faster on large clouds; the result is in the input order).

    Returns
    -------
    (N,) float64 distances in metres.
    """
    pts = np.asarray(compared, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise DataError(f"compared positions must have shape (N, 3), got {pts.shape}")
    if chunk_size <= 0:
        raise ConfigError(f"chunk_size must be positive, got {chunk_size}")
    if max_dist is not None and not (max_dist > 0 and np.isfinite(max_dist)):
        raise ConfigError(f"max_dist must be a positive finite distance in metres, got {max_dist}")
    tree = reference if isinstance(reference, cKDTree) else build_tree(reference)
    n = len(pts)
    out = np.empty(n, dtype=np.float64)
    order = morton_order(pts) if sort_queries and n > 4 * 65536 else None
    bound = np.inf if max_dist is None else float(max_dist)
    for start in range(0, n, chunk_size):
        sel = slice(start, min(start + chunk_size, n))
        idx = order[sel] if order is not None else sel
        d, _ = tree.query(pts[idx], k=1, distance_upper_bound=bound, workers=workers)
        if max_dist is not None:
            d = np.minimum(d, bound)  # cKDTree reports inf beyond the bound
        out[idx] = d
    return out


def distance_stats(distances: np.ndarray, max_dist: float | None = None) -> DistanceStats:
    """Statistics of (N,) distances in metres; with ``max_dist``, points beyond it (or at a clamped
    ``max_dist``) are outliers, counted and excluded from the other statistics."""
    d = np.asarray(distances, dtype=np.float64).reshape(-1)
    if not np.isfinite(d).all():
        raise DataError("distances contain NaN or infinite values")
    total = len(d)
    outliers = 0
    if max_dist is not None:
        keep = d < max_dist
        outliers = int(total - np.count_nonzero(keep))
        d = d[keep]
    share = outliers / total if total else 0.0
    if len(d) == 0:
        return DistanceStats(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, max_dist, outliers, share)
    mean = float(d.mean())
    p50, p90, p95, p99 = (float(v) for v in np.percentile(d, [50, 90, 95, 99]))
    return DistanceStats(
        count=len(d),
        mean=mean,
        std=float(np.sqrt(max(float(np.mean((d - mean) ** 2)), 0.0))),
        median=p50,
        rmse=float(np.sqrt(np.mean(d * d))),
        p90=p90,
        p95=p95,
        p99=p99,
        min=float(d.min()),
        max=float(d.max()),
        max_dist=max_dist,
        outlier_count=outliers,
        outlier_share=share,
    )


def per_class_stats(
    distances: np.ndarray, classes: np.ndarray, max_dist: float | None = None
) -> dict[int, DistanceStats]:
    """Statistics per class value: ``distances`` (N,) metres, ``classes`` (N,) integer labels."""
    d = np.asarray(distances, dtype=np.float64).reshape(-1)
    c = np.asarray(classes).reshape(-1)
    if len(c) != len(d):
        raise DataError(f"classification has {len(c)} entries but there are {len(d)} distances")
    return {int(k): distance_stats(d[c == k], max_dist) for k in np.unique(c)}


def threshold_scores(to_reference: np.ndarray, to_compared: np.ndarray, tau: float) -> ThresholdScores:
    """Precision / recall / F-score at ``tau`` metres (Tanks and Temples: a point counts when d < τ).

    to_reference: (N,) compared -> reference distances; to_compared: (M,) reference -> compared distances.
    """
    if not (tau > 0 and np.isfinite(tau)):
        raise ConfigError(f"tau must be a positive finite distance in metres, got {tau}")
    a = np.asarray(to_reference, dtype=np.float64)
    b = np.asarray(to_compared, dtype=np.float64)
    precision = float(np.count_nonzero(a < tau) / len(a)) if len(a) else 0.0
    recall = float(np.count_nonzero(b < tau) / len(b)) if len(b) else 0.0
    denom = precision + recall
    fscore = 2.0 * precision * recall / denom if denom > 0 else 0.0
    return ThresholdScores(float(tau), precision, recall, fscore)


def compare_clouds(
    compared: PointCloud,
    reference: PointCloud,
    max_dist: float | None = None,
    tau: float | None = None,
    class_field: str = "classification",
    chunk_size: int = DEFAULT_CHUNK,
    workers: int = -1,
) -> C2CResult:
    """C2C of ``compared`` against ``reference`` (both :class:`PointCloud`, any origins).

    Both clouds are moved to one float64 local origin first. With ``tau`` the reverse distances
    (reference -> compared) are computed too, giving completeness, precision, recall and F-score; the
    reverse search is unbounded so that recall and the completeness statistics are exact.
    """
    compared.validate("compared cloud")
    reference.validate("reference cloud")
    if len(compared) == 0:
        raise DataError("the compared cloud is empty; C2C needs at least one compared point")
    origin = common_origin(reference, compared)
    cmp_local = compared.with_origin(origin).positions
    ref_local = reference.with_origin(origin).positions
    # Searching up to max(max_dist, tau) keeps precision exact when tau > max_dist.
    bound = None if max_dist is None else (max_dist if tau is None else max(max_dist, tau))
    d = nearest_distances(cmp_local, ref_local, max_dist=bound, chunk_size=chunk_size, workers=workers)
    reverse = scores = None
    if tau is not None:
        back = nearest_distances(ref_local, cmp_local, chunk_size=chunk_size, workers=workers)
        reverse = distance_stats(back)
        scores = threshold_scores(d, back, tau)
    if max_dist is not None:
        d = np.minimum(d, max_dist)
    stats = distance_stats(d, max_dist)
    per_class: dict[int, DistanceStats] = {}
    if class_field in compared.fields:
        per_class = per_class_stats(d, compared.fields[class_field], max_dist)
    return C2CResult(distances=d, stats=stats, reverse=reverse, scores=scores, per_class=per_class)


def histogram(distances: np.ndarray, bins: int = 50, upper: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(bins + 1,) float64 edges and (bins,) int64 counts of distances over [0, upper] (default: P99.5)."""
    d = np.asarray(distances, dtype=np.float64)
    if upper is None:
        upper = float(np.percentile(d, 99.5)) if len(d) else 1.0
    upper = max(upper, 1e-9)
    counts, edges = np.histogram(np.clip(d, 0.0, upper), bins=bins, range=(0.0, upper))
    return edges, counts.astype(np.int64)
