"""Trained splats + Gaussians converted from MVS points → one Gaussian set, with provenance kept.

Steps of :func:`merge_gaussians`:

1. MVS Gaussians whose ``classification`` is one of ``non_collaborative_classes`` are dropped: MVS is unreliable
   on those surfaces (mirrors, glass, shiny metal, textureless, thin) and the trained splats replace them.
2. With ``dedupe_mvs``, MVS Gaussians closer than ``duplicate_tolerance`` to an MVS Gaussian of lower index are
   dropped, so no two kept MVS Gaussians lie within the tolerance (the fused MVS cloud repeats points where
   several depth maps agree).
3. Across sources, the Gaussians of the non-preferred source (``prefer``, default MVS, whose geometry is
   metric) lying within ``duplicate_tolerance`` of a Gaussian of the preferred source are dropped. Splats among
   themselves are never deduplicated: trained splats legitimately stack at one place with different scales.
4. The result is expressed in the MVS set's origin (float64, georeferenced scenes keep their offset) at the
   higher SH degree of the two (MVS Gaussians get zero higher-order coefficients), with two uint8 fields:
   ``source`` (:class:`fusion.convert.Source`: 1 = MVS, 2 = splat) and ``classification`` (the MVS class;
   splats keep their own ``classification`` field when they have one, else ``splat_class``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from enum import Enum

import numpy as np

from core.errors import ConfigError, DataError
from core.gaussians import GaussianSet
from fusion.convert_options import Source

CLASS_FIELD = "classification"


class MergeWarning(UserWarning):
    """Merging could not do what its options ask (e.g. drop classes from an unclassified MVS set)."""


class Prefer(str, Enum):
    """Which source wins when an MVS Gaussian and a splat lie within the duplicate tolerance."""

    MVS = "mvs"
    SPLAT = "splat"


@dataclass(frozen=True)
class MergeOptions:
    """Options of :func:`merge_gaussians`. ``duplicate_tolerance`` in metres (0: only coincident centres)."""

    non_collaborative_classes: tuple[int, ...] = ()
    duplicate_tolerance: float = 1e-3
    prefer: Prefer = Prefer.MVS
    dedupe_mvs: bool = True
    splat_class: int = 0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.duplicate_tolerance) and self.duplicate_tolerance >= 0):
            raise ConfigError(f"duplicate_tolerance must be a finite distance >= 0 m, got {self.duplicate_tolerance}")
        if not 0 <= self.splat_class <= 255:
            raise ConfigError(f"splat_class must be a class code in 0..255, got {self.splat_class}")
        bad = [c for c in self.non_collaborative_classes if not 0 <= int(c) <= 255]
        if bad:
            raise ConfigError(f"non-collaborative class codes must lie in 0..255, got {bad}")
        object.__setattr__(self, "prefer", Prefer(self.prefer))


@dataclass
class MergeStats:
    """Counts of what :func:`merge_gaussians` kept and dropped."""

    mvs_input: int
    splat_input: int
    dropped_non_collaborative: int
    dropped_mvs_duplicates: int
    dropped_cross_duplicates: int  # of the non-preferred source
    mvs_kept: int
    splats_kept: int

    @property
    def total(self) -> int:
        return self.mvs_kept + self.splats_kept


@dataclass
class MergeResult:
    gaussians: GaussianSet
    stats: MergeStats


def merge_gaussians(
    splats: GaussianSet | None, mvs: GaussianSet | None, options: MergeOptions | None = None
) -> MergeResult:
    """Merge trained splats and MVS Gaussians into one set (see the module docstring for the rules).

    Either input may be None or empty (a scene without non-collaborative regions has no splats). The MVS set's
    ``classification`` field (integer codes 0..255) drives step 1; without it no MVS Gaussian is dropped by class.
    """
    options = options or MergeOptions()
    if splats is None and mvs is None:
        raise DataError("merge needs at least one Gaussian set (got neither splats nor MVS Gaussians)")
    origin = (mvs if mvs is not None else splats).origin  # type: ignore[union-attr]
    if options.non_collaborative_classes and mvs is not None and len(mvs) and CLASS_FIELD not in mvs.fields:
        warnings.warn(
            f"the {len(mvs)} MVS Gaussians have no {CLASS_FIELD!r} field: no non-collaborative class can be dropped "
            "(convert the classified cloud, or export MVS Gaussians with extra fields)",
            MergeWarning,
            stacklevel=2,
        )
    mvs = _with_provenance(mvs, Source.MVS, 0, origin)
    splats = _with_provenance(splats, Source.SPLAT, options.splat_class, origin)
    n_mvs, n_splat = len(mvs), len(splats)

    classes = np.asarray(sorted({int(c) for c in options.non_collaborative_classes}), dtype=np.int64)
    keep = ~np.isin(mvs.fields[CLASS_FIELD].astype(np.int64), classes)
    dropped_class = int(n_mvs - keep.sum())
    mvs = subset(mvs, keep)

    dropped_dupes = 0
    tol = float(options.duplicate_tolerance)
    if options.dedupe_mvs and len(mvs) > 1:
        keep = first_within_tolerance(mvs.means, tol)
        dropped_dupes = int(len(mvs) - keep.sum())
        mvs = subset(mvs, keep)

    dropped_cross = 0
    if len(mvs) and len(splats):
        winner, loser = (mvs, splats) if options.prefer is Prefer.MVS else (splats, mvs)
        near = near_any(loser.means, winner.means, tol)
        dropped_cross = int(near.sum())
        loser = subset(loser, ~near)
        mvs, splats = (winner, loser) if options.prefer is Prefer.MVS else (loser, winner)

    parts = [s for s in (mvs, splats) if len(s)]
    merged = GaussianSet.concatenate(parts) if parts else empty_like(mvs)
    stats = MergeStats(n_mvs, n_splat, dropped_class, dropped_dupes, dropped_cross, len(mvs), len(splats))
    return MergeResult(merged, stats)


def first_within_tolerance(points: np.ndarray, tolerance: float) -> np.ndarray:
    """Boolean keep-mask (N,): drops every point within ``tolerance`` (metres, inclusive) of a lower-index point.

    Afterwards no two kept points are within the tolerance of each other. ``points``: (N, 3) float64.
    """
    from scipy.spatial import cKDTree

    keep = np.ones(len(points), dtype=bool)
    if len(points) < 2:
        return keep
    pairs = cKDTree(points).query_pairs(r=tolerance, output_type="ndarray")  # i < j, distance <= r
    if len(pairs):
        keep[pairs[:, 1]] = False
    return keep


def near_any(query: np.ndarray, reference: np.ndarray, tolerance: float) -> np.ndarray:
    """Boolean mask (len(query),): True where a reference point lies within ``tolerance`` metres (inclusive)."""
    if len(query) == 0 or len(reference) == 0:
        return np.zeros(len(query), dtype=bool)
    from scipy.spatial import cKDTree

    # cKDTree's bound is strict and compared squared: widen it (≥ 1e-150 so its square stays > 0), then filter.
    bound = max(float(np.nextafter(tolerance, np.inf)) * (1 + 1e-12), 1e-150)
    d, _ = cKDTree(reference).query(query, k=1, distance_upper_bound=bound, workers=-1)
    return d <= tolerance


def subset(gs: GaussianSet, keep: np.ndarray) -> GaussianSet:
    """``gs.subset(keep)`` that also works when nothing is kept.

    Work-around: ``core.gaussians.GaussianSet`` cannot hold 0 Gaussians with SH rest of width 0 (``reshape(0, -1,
    3)`` is ambiguous), so empty results are built from a 1-Gaussian set and sliced to length 0 field by field.
    """
    keep = np.asarray(keep)
    if np.count_nonzero(keep) if keep.dtype == bool else len(keep):
        return gs.subset(keep)
    return empty_like(gs)


def empty_like(gs: GaussianSet | None, fields: tuple[str, ...] = ()) -> GaussianSet:
    """A Gaussian set with 0 Gaussians, the SH degree, origin and field names (and dtypes) of ``gs``."""
    degree = gs.sh_degree if gs is not None else 0
    k = (degree + 1) ** 2 - 1
    one = GaussianSet(
        np.zeros((1, 3)),
        np.zeros((1, 3)),
        np.array([[1.0, 0, 0, 0]]),
        np.zeros(1),
        np.zeros((1, 3)),
        np.zeros((1, k, 3)),
        gs.origin.copy() if gs is not None else np.zeros(3),
        {name: np.zeros(1, dtype=v.dtype) for name, v in (gs.fields.items() if gs is not None else ())}
        | {name: np.zeros(1, np.uint8) for name in fields},
    )
    for attr in ("means", "log_scales", "quats", "logit_opacities", "sh_dc", "sh_rest"):
        setattr(one, attr, getattr(one, attr)[:0])
    one.fields = {name: v[:0] for name, v in one.fields.items()}
    return one


def _with_provenance(gs: GaussianSet | None, source: Source, default_class: int, origin: np.ndarray) -> GaussianSet:
    """The set in ``origin`` with exactly two uint8 fields: ``source`` and ``classification``."""
    gs = empty_like(gs) if gs is None or len(gs) == 0 else gs.with_origin(origin)
    gs.origin = np.asarray(origin, np.float64).copy()
    n = len(gs)
    cls = gs.fields.get(CLASS_FIELD)
    if cls is None:
        cls = np.full(n, default_class)
    cls = np.asarray(cls)
    if n and (not np.isfinite(cls.astype(np.float64)).all() or cls.min() < 0 or cls.max() > 255):
        raise DataError(f"{source.name.lower()} Gaussians have classification codes outside 0..255")
    gs.fields = {"source": np.full(n, source, dtype=np.uint8), CLASS_FIELD: cls.astype(np.uint8)}
    return gs


def merge_hybrid(
    mvs: GaussianSet,
    splats: GaussianSet | None,
    needs_splats: np.ndarray,
    *,
    keep_needs_splats: bool = False,
    options: MergeOptions | None = None,
) -> MergeResult:
    """The hybrid product: frozen MVS Gaussians + cleaned trained splats, with the per-Gaussian ``source`` field.

    ``mvs`` holds one Gaussian per MVS point, in the order of ``needs_splats`` (N,) bool; the points that needed
    splats are left out (their noisy, incomplete geometry is what the splats replace) unless
    ``keep_needs_splats``. Defaults differ from :func:`merge_gaussians`' on purpose: MVS Gaussians are not
    deduplicated and only exactly coincident splats are dropped, so that outside the regions the merged set renders
    exactly like the MVS context the splats were trained next to.
    """
    needs = np.asarray(needs_splats, bool).reshape(-1)
    if len(needs) != len(mvs):
        raise DataError(f"needs_splats has {len(needs)} entries for {len(mvs)} MVS Gaussians")
    kept = mvs if keep_needs_splats else subset(mvs, ~needs)
    return merge_gaussians(splats, kept, options or MergeOptions(duplicate_tolerance=0.0, dedupe_mvs=False))
