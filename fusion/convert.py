"""MVS points to 3D Gaussians: the reference paper's conversion (Eq. 1–4) and an adaptive surfel conversion.

Both modes return a :class:`core.gaussians.GaussianSet` in the cloud's local frame (``means`` are the cloud's
float64 local ``positions``, ``origin`` is copied), SH degree 0, with the cloud's scalar fields carried over and a
``source`` field (:class:`Source`, uint8) set to ``Source.MVS``.

``paper`` (Eq. 1–4 of the reference paper, reproduced exactly):
    f_dc = (RGB/255 − 0.5) / C0, f_rest = 0;
    d = mean over all points of the distance to the nearest other point (one global spacing, metres);
    stored opacity = log(1/d), clamped to [``opacity_logit_min``, ``opacity_logit_max``];
    stored log-scale = log(d) on all three axes; rotation = identity (1, 0, 0, 0).

``adaptive`` (per point i):
    s_i = median distance to the ``k_neighbors`` nearest other points, ignoring exact duplicates (distance 0),
    so one spacing per point that follows the local sampling density and is robust to a few outliers;
    σ_tangent = ``tangent_scale`` · s_i on the two in-surface axes, σ_normal = ``thickness_ratio`` · σ_tangent on the
    third axis, which is rotated onto the MVS normal (normals estimated by PCA of the same neighbours when the
    cloud has none), i.e. a flat surfel lying in the surface;
    α_i = ``max_opacity`` · c_views · c_density, where c_views = 1 − exp(−n_views / ``view_saturation``) from the
    fused visibility (or the ``confidence`` field in [0, 1] when there is no visibility; 1 when there is neither),
    and c_density = min(1, ``outlier_spacing_factor`` · median(s) / s_i) fades isolated points (likely MVS
    outliers) whose spacing is far above the typical one; stored opacity = logit(α_i), clamped as in ``paper``.

Every spacing is clamped to [``min_spacing``, ``max_spacing``] before a log is taken, so duplicate points (d = 0), a
single point (no neighbour: ``fallback_spacing``), collinear points and huge or tiny spacings all give finite values;
each clamp that changes values emits a :class:`ConversionWarning` with the count.

Neighbour search (``neighbor_backend``): ``"grid"`` (default), the exact column-grid search of :mod:`core.knn` (numba
kernels on ``numba.get_num_threads()`` Python threads, O(N) memory: a sorted copy of the points and a column table),
faster than the reference ``"kdtree"``: one ``scipy.spatial.cKDTree`` over all points queried in chunks of
``chunk_size`` points in the tree's leaf order (faster than input order; memory beyond the outputs O(chunk_size · k);
the timings: docs/experiments/2026-11-27-domain-defaults.md). Both give identical distances (tested). Each mode computes
only what it needs: ``paper`` the nearest distance of each point (for the global mean); ``adaptive`` with MVS normals
everywhere the per-point median spacing straight from the search (no (N, k) arrays), and the (N, k) neighbours only when
some points lack a normal (PCA of those points only); MVS normals become quaternions in one pass, and the spacing clamp,
scales, confidence, density fade and logits are two threaded numba passes around the median (no float64 temporaries).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.spatial import cKDTree

from core.errors import ConfigError, DataError
from core.gaussians import SH_C0, GaussianSet
from core.knn import drop_self, knn_grid, knn_grid_summary, median_nonzero, run_threads
from core.pointcloud import PointCloud
from fusion.convert_options import DEFAULT_MODE, ConversionWarning, ConvertMode, ConvertOptions, Source


@dataclass
class ConvertStats:
    """What a conversion did: the spacing used, how many values each clamp changed, and timings (seconds)."""

    mode: ConvertMode
    num_points: int
    mean_nn_spacing: float  # the paper's d before clamping (metres); nan when undefined (fewer than 2 points)
    median_spacing: float  # median per-point spacing (adaptive) or d (paper), after clamping, metres
    clamped_spacing: int = 0
    clamped_opacity: int = 0
    estimated_normals: int = 0
    missing_colors: bool = False
    seconds_neighbors: float = 0.0
    seconds_total: float = 0.0
    notes: list[str] = field(default_factory=list)


@dataclass
class ConvertResult:
    gaussians: GaussianSet
    stats: ConvertStats


def points_to_gaussians(
    cloud: PointCloud, mode: ConvertMode | str = DEFAULT_MODE, options: ConvertOptions | None = None
) -> GaussianSet:
    """Gaussians from an MVS point cloud (see the module docstring for both modes).

    Parameters
    ----------
    cloud: N ≥ 1 points, float64 local positions (metres) + origin; colours uint8 (grey 128 when absent, with a
        warning); optional unit normals (adaptive), visibility or ``confidence`` field (adaptive opacity).
    mode: ``"paper"`` or ``"adaptive"``.

    Returns
    -------
    GaussianSet with N Gaussians, SH degree 0, ``means`` = cloud positions (float64, local), same ``origin``.
    """
    return convert_points(cloud, mode, options).gaussians


def convert_points(
    cloud: PointCloud, mode: ConvertMode | str = DEFAULT_MODE, options: ConvertOptions | None = None
) -> ConvertResult:
    """As :func:`points_to_gaussians`, also returning :class:`ConvertStats`."""
    t0 = time.perf_counter()
    options = options or ConvertOptions()
    try:
        mode = ConvertMode(mode)
    except ValueError as err:
        raise ConfigError(f"conversion mode must be one of {[m.value for m in ConvertMode]}, got {mode!r}") from err
    n = len(cloud)
    if n == 0:
        raise DataError("cannot convert an empty point cloud to Gaussians (0 points)")
    cloud.validate("MVS cloud")

    stats = ConvertStats(mode=mode, num_points=n, mean_nn_spacing=float("nan"), median_spacing=float("nan"))
    sh_dc = sh_dc_from_colors(cloud.colors, n, stats)
    if mode is ConvertMode.PAPER:
        log_scales, quats, logits = _paper(cloud.positions, options, stats)
    else:
        log_scales, quats, logits = _adaptive(cloud, options, stats)

    lo, hi = options.opacity_logit_min, options.opacity_logit_max
    outside = (logits < lo) | (logits > hi)
    stats.clamped_opacity = int(np.count_nonzero(outside))
    if stats.clamped_opacity:
        _warn(f"opacity clamped to [{lo}, {hi}] (stored logit) for {stats.clamped_opacity} of {n} Gaussians")
    logits = np.clip(logits, lo, hi)

    fields = dict(cloud.fields)
    fields["source"] = np.full(n, Source.MVS, dtype=np.uint8)
    gaussians = GaussianSet(
        means=cloud.positions.copy(),
        log_scales=log_scales,
        quats=quats,
        logit_opacities=logits,
        sh_dc=sh_dc,
        origin=cloud.origin.copy(),
        fields=fields,
    )
    stats.seconds_total = time.perf_counter() - t0
    return ConvertResult(gaussians, stats)


# -- the two modes ------------------------------------------------------------------------------------


def _paper(positions: np.ndarray, options: ConvertOptions, stats: ConvertStats):
    n = len(positions)
    t = time.perf_counter()
    if n >= 2 and options.neighbor_backend == "grid":
        d = float(np.mean(knn_grid_summary(positions, 1)[0], dtype=np.float64))
        stats.mean_nn_spacing = d
    elif n >= 2:
        nn = knn_distances(positions, 1, options.chunk_size, options.workers, backend=options.neighbor_backend)[0][:, 0]
        d = float(np.mean(nn, dtype=np.float64))
        stats.mean_nn_spacing = d
    else:
        d = options.fallback_spacing
        stats.notes.append("single point: no neighbour, fallback_spacing used")
        _warn(f"a single point has no neighbour; spacing set to fallback_spacing = {d} m")
    stats.seconds_neighbors = time.perf_counter() - t
    d_clamped = float(np.clip(d, options.min_spacing, options.max_spacing))
    if d_clamped != d:
        stats.clamped_spacing = n
        _warn(
            f"global spacing d = {d:.6g} m clamped to {d_clamped:.6g} m (bounds [{options.min_spacing}, "
            f"{options.max_spacing}]) for all {n} Gaussians"
        )
    stats.median_spacing = d_clamped
    log_scales = np.full((n, 3), np.log(d_clamped), dtype=np.float32)
    quats = np.zeros((n, 4), dtype=np.float32)
    quats[:, 0] = 1.0
    logits = np.full(n, np.log(1.0 / d_clamped), dtype=np.float64)  # Eq. 3: log(1/d), clamped by the caller
    return log_scales, quats, logits


def _adaptive(cloud: PointCloud, options: ConvertOptions, stats: ConvertStats):
    positions = cloud.positions
    n = len(positions)
    k = min(options.k_neighbors, n - 1)
    quats, missing = quats_from_given_normals(cloud)
    t = time.perf_counter()
    if k >= 1 and options.neighbor_backend == "grid" and not missing.any():
        # no PCA needed: the per-point statistics come straight from the search, without (N, k) arrays
        idx = np.zeros((n, 0), dtype=np.int64)
        nearest, spacing = knn_grid_summary(positions, k)
        stats.mean_nn_spacing = float(np.mean(nearest, dtype=np.float64))
    elif k >= 1:
        dist, idx = knn_distances(
            positions, k, options.chunk_size, options.workers, return_index=True, backend=options.neighbor_backend
        )
        stats.mean_nn_spacing = float(np.mean(dist[:, 0], dtype=np.float64))
        spacing = _robust_spacing(dist)
        del dist
    else:
        idx = np.zeros((n, 0), dtype=np.int64)
        spacing = np.full(n, options.fallback_spacing, dtype=np.float64)
        _warn(f"a single point has no neighbour; spacing set to fallback_spacing = {options.fallback_spacing} m")
    stats.seconds_neighbors = time.perf_counter() - t

    # one clamp pass (also counting), the median, then one pass for scales and opacities: threaded numba
    # kernels instead of ~10 serial numpy passes with float64 temporaries (~1 s at 10 M points)
    nth = numba.get_num_threads()
    clamped = np.empty(n, dtype=np.float64)
    bad = np.zeros(nth, dtype=np.int64)
    run_threads(clamp_kernel, (spacing, options.min_spacing, options.max_spacing, clamped, bad), nth)
    spacing = clamped
    stats.clamped_spacing = int(bad.sum())
    if stats.clamped_spacing:
        _warn(
            f"per-point spacing clamped to [{options.min_spacing}, {options.max_spacing}] m for "
            f"{stats.clamped_spacing} of {n} points (duplicates or isolated points)"
        )
    stats.median_spacing = float(np.median(spacing))

    _fill_missing_normals(cloud.positions, quats, missing, idx, stats)

    log_scales, logits = surfel_attributes(cloud, spacing, options, stats.median_spacing)
    return log_scales, quats, logits


def surfel_attributes(
    cloud: PointCloud, spacing: np.ndarray, options: ConvertOptions, median_spacing: float
) -> tuple[np.ndarray, np.ndarray]:
    """Adaptive log-scales (N, 3) float32 and opacity logits (N,) float64 of ``cloud``'s points from their clamped
    ``spacing`` (metres) and the cloud's ``median_spacing`` (outliers are judged against it); the streamed
    conversion calls it per chunk."""
    n, nth = len(cloud), numba.get_num_threads()
    conf_kind, conf = confidence_source(cloud)
    log_scales = np.empty((n, 3), dtype=np.float32)
    logits = np.empty(n, dtype=np.float64)
    args = (spacing, conf_kind, conf, options.view_saturation, options.tangent_scale, options.thickness_ratio)
    args += (options.min_spacing, options.outlier_spacing_factor * median_spacing, options.max_opacity)
    run_threads(surfel_kernel, (*args, LOGIT_EPS, log_scales, logits), nth)
    return log_scales, logits


LOGIT_EPS = 1e-6
"""Opacities are clamped to [eps, 1 − eps] before the logit (as ``core.gaussians.logit(alpha, eps)``)."""

_CONF_ONES, _CONF_FIELD, _CONF_VIEWS = 0, 1, 2


def confidence_source(cloud: PointCloud) -> tuple[int, np.ndarray]:
    """What c_views comes from: (_CONF_VIEWS, view counts float64), (_CONF_FIELD, the raw ``confidence`` field) or
    (_CONF_ONES, an empty array); :func:`surfel_kernel` turns it into c_views."""
    if cloud.visibility is not None:
        return _CONF_VIEWS, np.fromiter((len(v) for v in cloud.visibility), dtype=np.float64, count=len(cloud))
    if "confidence" in cloud.fields:
        return _CONF_FIELD, np.ascontiguousarray(cloud.fields["confidence"])
    return _CONF_ONES, np.zeros(0)


@numba.njit(nogil=True, cache=True)
def clamp_kernel(s: np.ndarray, lo: float, hi: float, out: np.ndarray, bad: np.ndarray, th: int, nth: int) -> None:
    """out = clip(s, lo, hi) (NaN stays NaN, as np.clip); bad[th] = count of values not in [lo, hi] (NaN included)
    over the th-th of nth contiguous ranges."""
    n = len(s)
    count = 0
    for i in range(th * n // nth, (th + 1) * n // nth):
        v = s[i]
        if v >= lo and v <= hi:
            out[i] = v
            continue
        count += 1
        out[i] = hi if v > hi else (lo if v < lo else v)
    bad[th] = count


@numba.njit(nogil=True, cache=True)
def surfel_kernel(
    spacing, conf_kind, conf, view_saturation, tangent_scale, thickness_ratio, min_spacing, ref, max_opacity, eps,
    log_scales, logits, th, nth,
):  # fmt: skip
    """Adaptive log-scales (float32) and opacity logits (float64) of the th-th of nth contiguous ranges of points,
    the formulas of the module docstring (the same float64 operations, in the same order, as numpy would do)."""
    n = len(spacing)
    for i in range(th * n // nth, (th + 1) * n // nth):
        s = spacing[i]
        sigma_t = max(tangent_scale * s, min_spacing)
        sigma_n = max(thickness_ratio * sigma_t, min_spacing)
        lt = np.float32(np.log(sigma_t))
        log_scales[i, 0] = lt
        log_scales[i, 1] = lt
        log_scales[i, 2] = np.float32(np.log(sigma_n))
        if conf_kind == _CONF_VIEWS:
            c = 1.0 - np.exp(-conf[i] / view_saturation)
        elif conf_kind == _CONF_FIELD:
            c = np.float64(conf[i])
            c = 0.0 if np.isnan(c) else min(max(c, 0.0), 1.0)
        else:
            c = 1.0
        d = ref / s
        alpha = max_opacity * c * (1.0 if d > 1.0 else d)
        p = min(max(alpha, eps), 1.0 - eps)
        logits[i] = np.log(p) - np.log1p(-p)


# -- building blocks ------------------------------------------------------------------------------------


def knn_distances(
    positions: np.ndarray,
    k: int,
    chunk_size: int = 1_000_000,
    workers: int = -1,
    return_index: bool = False,
    backend: str = "grid",
) -> tuple[np.ndarray, np.ndarray | None]:
    """Distances (N, k) float64 (ascending, metres) from each point to its k nearest *other* points.

    ``positions``: (N, 3) float64, N > k. With ``return_index`` also the neighbour indices (N, k) int64, else None.
    Exact duplicates appear as distance 0. ``backend``: ``"grid"`` (:func:`core.knn.knn_grid`, exact, the faster)
    or ``"kdtree"`` (scipy ``cKDTree`` queried in leaf order in chunks of ``chunk_size``).
    """
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    n = len(positions)
    if n <= k:
        raise DataError(f"{k} nearest neighbours need more than {k} points, got {n}")
    if backend == "grid":
        dist, index = knn_grid(positions, k)
        return dist, (index if return_index else None)
    if backend != "kdtree":
        raise ConfigError(f"neighbour backend must be 'grid' or 'kdtree', got {backend!r}")
    # Unbalanced, non-compact trees build 2× faster and query as fast on MVS-like data.
    tree = cKDTree(positions, leafsize=16, balanced_tree=False, compact_nodes=False)
    order = tree.indices  # leaf order: spatially coherent queries run ~4× faster than input order
    dist = np.empty((n, k), dtype=np.float64)
    index = np.empty((n, k), dtype=np.int64) if return_index else None
    for start in range(0, n, chunk_size):
        rows = order[start : start + chunk_size]
        d, i = tree.query(positions[rows], k=k + 1, workers=workers)
        d, i = drop_self(d, i, rows)
        dist[rows] = d
        if index is not None:
            index[rows] = i
    return dist, index


def _robust_spacing(dist: np.ndarray) -> np.ndarray:
    """Median of each row's non-zero distances (rows are sorted ascending); 0 when every neighbour is a duplicate."""
    return median_nonzero(dist)


def quats_from_given_normals(cloud: PointCloud) -> tuple[np.ndarray, np.ndarray]:
    """Quaternions (N, 4) float32 turning +z onto the cloud's normals (as :func:`quats_z_to` of the normalised
    normals, in one pass without temporaries) and the (N,) bool mask of points whose normal is missing (absent,
    non-finite or shorter than 1e-6); their quaternions are left for :func:`_fill_missing_normals`."""
    n = len(cloud)
    quats = np.empty((n, 4), dtype=np.float32)
    missing = np.ones(n, dtype=bool)
    if cloud.normals is not None:
        run_threads(
            _normal_quats_kernel, (np.ascontiguousarray(cloud.normals), quats, missing), numba.get_num_threads()
        )
    return quats, missing


@numba.njit(nogil=True, cache=True)
def _normal_quats_kernel(normals: np.ndarray, quats: np.ndarray, missing: np.ndarray, th: int, nth: int) -> None:
    n = len(normals)
    for i in range(th * n // nth, (th + 1) * n // nth):  # the th-th of nth contiguous ranges
        nx, ny, nz = np.float64(normals[i, 0]), np.float64(normals[i, 1]), np.float64(normals[i, 2])
        norm = np.sqrt(nx * nx + ny * ny + nz * nz)
        if not (np.isfinite(norm) and norm > 1e-6):
            continue
        missing[i] = False
        nx, ny, nz = nx / norm, ny / norm, nz / norm
        qw, qx, qy = 1.0 + nz, -ny, nx
        qn = np.sqrt(qw * qw + qx * qx + qy * qy)
        if qn < 1e-9:  # n ≈ −z: a half turn about x
            qw, qx, qy, qn = 0.0, 1.0, 0.0, 1.0
        quats[i, 0] = qw / qn
        quats[i, 1] = qx / qn
        quats[i, 2] = qy / qn
        quats[i, 3] = 0.0


def _fill_missing_normals(
    positions: np.ndarray, quats: np.ndarray, missing: np.ndarray, idx: np.ndarray, stats: ConvertStats
) -> None:
    """Quaternions of the points without a normal: PCA of their neighbours (``idx`` (N, k), k ≥ 2), else +z."""
    rows = np.flatnonzero(missing)
    if not len(rows):
        return
    if idx.shape[1] >= 2:
        quats[rows] = quats_z_to(pca_normals(positions, rows, idx[rows]))
        stats.estimated_normals = len(rows)
    else:
        quats[rows] = (1.0, 0.0, 0.0, 0.0)  # +z


def pca_normals(positions: np.ndarray, rows: np.ndarray, neighbors: np.ndarray, chunk: int = 262_144) -> np.ndarray:
    """Unit normals (len(rows), 3): eigenvector of the smallest eigenvalue of each neighbourhood's covariance.

    ``neighbors``: (len(rows), k) indices into ``positions``; the point itself is included in the covariance.
    Degenerate neighbourhoods (collinear, coincident) still return a unit vector (some direction ⟂ to the line).
    """
    out = np.empty((len(rows), 3), dtype=np.float64)
    for s in range(0, len(rows), chunk):
        r = rows[s : s + chunk]
        pts = np.concatenate([positions[r][:, None, :], positions[neighbors[s : s + chunk]]], axis=1)
        centred = pts - pts.mean(axis=1, keepdims=True)
        cov = np.einsum("nki,nkj->nij", centred, centred)
        _, vecs = np.linalg.eigh(cov)
        out[s : s + chunk] = vecs[:, :, 0]
    return out


def quats_z_to(normals: np.ndarray) -> np.ndarray:
    """Unit quaternions (N, 4) float32 (w, x, y, z) rotating the local +z axis onto each unit normal (N, 3).

    Shortest-arc rotation q ∝ (1 + n_z, −n_y, n_x, 0); for n ≈ −z (where that vanishes) a half turn about x.
    """
    n = np.asarray(normals, dtype=np.float64)
    q = np.stack([1.0 + n[:, 2], -n[:, 1], n[:, 0], np.zeros(len(n))], axis=1)
    norm = np.linalg.norm(q, axis=1)
    flip = norm < 1e-9
    q[flip] = (0.0, 1.0, 0.0, 0.0)
    norm[flip] = 1.0
    return (q / norm[:, None]).astype(np.float32)


def sh_dc_from_colors(colors: np.ndarray | None, n: int, stats: ConvertStats) -> np.ndarray:
    """Eq. 1: f_dc = (RGB/255 − 0.5) / C0, (N, 3) float32; mid grey with a warning when the cloud has no colours."""
    if colors is None:
        stats.missing_colors = True
        _warn(f"the cloud has no colours; {n} Gaussians get mid grey (128, 128, 128)")
        colors = np.full((n, 3), 128, dtype=np.uint8)
    lut = ((np.arange(256, dtype=np.float64) / 255.0 - 0.5) / SH_C0).astype(np.float32)  # same values, no temporaries
    colors = np.ascontiguousarray(colors, dtype=np.uint8)
    out = np.empty(colors.shape, dtype=np.float32)
    run_threads(_lut_kernel, (lut, colors.reshape(-1), out.reshape(-1)), numba.get_num_threads())  # = lut[colors]
    return out


@numba.njit(nogil=True, cache=True)
def _lut_kernel(lut: np.ndarray, values: np.ndarray, out: np.ndarray, th: int, nth: int) -> None:
    """out[i] = lut[values[i]] over the th-th of nth contiguous ranges."""
    n = len(values)
    for i in range(th * n // nth, (th + 1) * n // nth):
        out[i] = lut[values[i]]


def _warn(message: str) -> None:
    warnings.warn(message, ConversionWarning, stacklevel=4)
