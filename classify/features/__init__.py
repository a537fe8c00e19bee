"""Per-point features of a dense cloud: geometric (multi-scale), radiometric and multi-view.

``compute_features(cloud, options, views)`` returns a :class:`FeatureTable` (names + an (N, F) float32 matrix).
Every feature is documented in :mod:`classify.features.registry` and selectable by name.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from classify.features.geometric import GeometricOptions, geometric_features, point_spacing, spatial_order
from classify.features.multiview import MultiViewOptions, ViewData, multiview_features, views_from_workspace
from classify.features.radiometric import color_variance, rgb_hsv
from classify.features.registry import (
    FeatureGroup,
    FeatureSpec,
    feature_specs,
    resolve_names,
)
from classify.features.reorder import cube_of, gather_rows, renumber_neighbours, scatter_column
from core.errors import ConfigError, DataError
from core.pointcloud import PointCloud

__all__ = [
    "ALL_GROUPS",
    "VIEW_GROUPS",
    "FeatureGroup",
    "FeatureOptions",
    "FeatureSpec",
    "FeatureTable",
    "WholeCloud",
    "GeometricOptions",
    "MultiViewOptions",
    "ViewData",
    "compute_features",
    "feature_specs",
    "point_spacing",
    "views_from_workspace",
]

ALL_GROUPS = (FeatureGroup.GEOMETRIC, FeatureGroup.RADIOMETRIC, FeatureGroup.MULTIVIEW)
# The groups that need the photos, cameras and depth maps of the dense workspace (``views``).
VIEW_GROUPS = (FeatureGroup.MULTIVIEW,)


@dataclass(frozen=True)
class FeatureOptions:
    """Which features, and how.

    names: feature names (full names, geometric base names or group names; None = every feature of ``groups``).
    groups: the groups used when ``names`` is None (default: geometric, radiometric, multiview).
    geometric / multiview: their options.
    """

    names: tuple[str, ...] | None = None
    groups: tuple[FeatureGroup, ...] = ALL_GROUPS
    geometric: GeometricOptions = field(default_factory=GeometricOptions)
    multiview: MultiViewOptions = field(default_factory=MultiViewOptions)

    @property
    def n_scales(self) -> int:
        return len(self.geometric.voxel_factors)

    def selected(self) -> tuple[str, ...]:
        """The resolved, ordered feature names."""
        return resolve_names(self.names, self.n_scales, self.groups)


@dataclass(frozen=True)
class FeatureTable:
    """names: F feature names; values: (N, F) float32, finite; spacing: the cloud's median point spacing (m);
    neighbours: (N, k − 1) int64, each point's nearest other points (the finest geometric neighbourhood, rows of
    this table), or None when not computed (the prediction's smoothing uses them)."""

    names: tuple[str, ...]
    values: np.ndarray
    spacing: float
    neighbours: np.ndarray | None = None

    def column(self, name: str) -> np.ndarray:
        """The (N,) column of feature ``name``."""
        return self.values[:, self.names.index(name)]

    def select(self, names: tuple[str, ...]) -> FeatureTable:
        """The table restricted to ``names`` (in that order); a missing name raises :class:`DataError`."""
        missing = [n for n in names if n not in self.names]
        if missing:
            raise DataError(f"features not computed: {', '.join(missing)}")
        cols = [self.names.index(n) for n in names]
        return FeatureTable(tuple(names), self.values[:, cols], self.spacing, self.neighbours)


@dataclass(frozen=True)
class WholeCloud:
    """What :func:`compute_features` derives from the whole cloud, given when it computes a part of one (the x-y cells
    of :mod:`classify.stream`): lo, hi (3,) float64 metres, the cloud's bounding box (the Morton cube of the spatial
    order, the origin of the coarse levels' voxels and ground columns); spacing: its median point spacing (metres)."""

    lo: np.ndarray
    hi: np.ndarray
    spacing: float


def compute_features(
    cloud: PointCloud,
    options: FeatureOptions = FeatureOptions(),
    views: ViewData | None = None,
    whole: WholeCloud | None = None,
) -> FeatureTable:
    """The selected features of every point of ``cloud`` (local positions, colours, normals, visibility).

    whole: when ``cloud`` is a part of a larger cloud, that cloud's box and spacing (:class:`WholeCloud`): every
    point whose neighbourhoods lie inside the part then gets the features it has in the whole cloud, bit for bit
    (:mod:`classify.stream` proves which do); None: ``cloud`` is the whole cloud.

    Radiometric features need colours; the view-based group (:data:`VIEW_GROUPS`) needs ``views`` (and uses
    ``cloud.visibility``).
    A missing input for a selected feature raises :class:`ConfigError` naming it. Non-finite values are
    replaced by 0 (counted: a :class:`DataError` if more than 1 % of a column is non-finite, which means a bug).
    """
    names = options.selected()
    if not names:
        raise ConfigError("no features selected")
    if len(cloud) < 3:
        raise DataError(f"features need at least 3 points, got {len(cloud)}")
    cloud.validate("dense cloud")
    specs = feature_specs(options.n_scales)
    groups = {specs[n].group for n in names}
    if FeatureGroup.RADIOMETRIC in groups and cloud.colors is None:
        raise ConfigError("radiometric features need point colours; the cloud has none")
    need_views = [g.value for g in VIEW_GROUPS if g in groups]
    if need_views and views is None:
        raise ConfigError(
            f"multi-view features ({', '.join(need_views)}) need the photos and cameras (a dense workspace)"
        )
    # Geometric and radiometric features are computed on the points sorted along a space-filling curve (cache-
    # friendly neighbour gathers) and written back in the cloud's order; multi-view features in the cloud's order.
    lo, span = cube_of(whole.lo, whole.hi) if whole is not None else (None, None)
    order = spatial_order(cloud.positions, lo=lo, span=span)
    sorted_columns: dict[str, np.ndarray] = {}
    normals = gather_rows(cloud.normals, order) if cloud.normals is not None else None
    positions = gather_rows(cloud.positions, order)
    spacing, origin = (whole.spacing, whole.lo) if whole is not None else (None, None)
    geo = geometric_features(positions, normals, options.geometric, spacing, origin)
    spacing = geo.spacing
    if FeatureGroup.GEOMETRIC in groups:
        sorted_columns.update(geo.features)
    if FeatureGroup.RADIOMETRIC in groups:
        colors = gather_rows(cloud.colors, order)  # type: ignore[arg-type]
        sorted_columns.update(rgb_hsv(colors))
        sorted_columns["color_variance"] = color_variance(
            colors,
            neighbours=geo.neighbours,
            positions=positions,
            k=options.geometric.k,
            workers=options.geometric.workers,
            with_self=geo.neighbours is not None,
        )
    neighbours = None
    if geo.neighbours is not None:  # back to the cloud's order: row order[i] has neighbours order[neigh[i]]
        neighbours = renumber_neighbours(geo.neighbours, order)
    del geo
    columns = multiview_features(cloud.positions, cloud.visibility, views, options.multiview) if need_views else {}
    values = np.empty((len(cloud), len(names)), dtype=np.float32)
    for j, name in enumerate(names):
        in_order = name in sorted_columns
        col = np.asarray(sorted_columns[name] if in_order else columns[name], dtype=np.float32)
        bad = ~np.isfinite(col)
        n_bad = int(np.count_nonzero(bad))
        if n_bad > 0.01 * len(col):
            raise DataError(f"feature {name!r} is non-finite for {n_bad} of {len(col)} points")
        if n_bad:
            col = np.where(bad, np.float32(0.0), col)
        if in_order:
            scatter_column(values, order, j, col)
        else:
            values[:, j] = col
    return FeatureTable(names, values, spacing, neighbours)
