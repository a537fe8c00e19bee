"""The feature registry: every per-point feature has a name, a unit, a group and a meaning.

Features are selected by name (``FeatureOptions.names``, the configuration's ``classify.features``); the model
stores the names it was trained on and refuses data whose names differ. Geometric features exist once per
scale; their names carry the scale index (``linearity_s0``, ``linearity_s1``...). The table below is the
documentation users see (``hybridsplat classify features`` prints it).

Groups, in registry order (``FeatureOptions()`` selects all three):

================ ===================== ===================================================================
group            module                what it measures
================ ===================== ===================================================================
geometric        geometric.py          shape of the k-NN neighbourhood at three scales (eigenvalues, height)
radiometric      radiometric.py        the point's colour and its spread over the finest neighbourhood
multiview        multiview.py          photos and depth maps of the frustum / fusing views at the point
================ ===================== ===================================================================

Units: ``1`` dimensionless (lengths divided by the cloud's median point spacing among them, as the meaning says),
``px`` photo pixels.

Four view-based groups were removed in 0.4 (:data:`REMOVED_GROUPS`, issue 54): a name of one of them, or of one of
their features, is a :class:`ConfigError` naming the group (:func:`refuse_removed`), and a model trained with one
does not load.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from core.errors import ConfigError


class FeatureGroup(str, Enum):
    """Where a feature comes from; the ablation study switches groups on and off."""

    GEOMETRIC = "geometric"
    RADIOMETRIC = "radiometric"
    MULTIVIEW = "multiview"


REMOVED_GROUPS: dict[str, tuple[str, ...]] = {
    "fusion": ("fusion_backproj_dist", "fusion_reproj_px", "fusion_plane_offset"),
    "view_dependent": ("lum_cv_views", "lum_peak_views", "lum_lobe_corr", "specular_up_corr"),
    "image_boundaries": ("edge_strength_views", "edge_distance_px", "edge_distance_spacing"),
    "image_texture": ("texture_std_views", "texture_corner_views", "texture_log_spread"),
}
"""The feature groups removed in 0.4 (issue 54) and the names of their features."""

REMOVED_WHY = (
    "removed in 0.4: the out-of-fold evaluation found it not improving the model, and the classifier's mistakes "
    "cost the product too little for a feature to matter; see docs/migration.md"
)


def removed_groups(names: tuple[str, ...] | list[str]) -> list[str]:
    """The removed groups (:data:`REMOVED_GROUPS`) that ``names`` (group or feature names) name, in registry order."""
    given = set(names)
    return [g for g, features in REMOVED_GROUPS.items() if g in given or given.intersection(features)]


def refuse_removed(names: tuple[str, ...] | list[str], what: str = "feature group") -> None:
    """A :class:`ConfigError` naming the removed groups that ``names`` (group or feature names) name, if any."""
    gone = removed_groups(names)
    if gone:
        raise ConfigError(f"{what} {', '.join(gone)}: {REMOVED_WHY}")


def feature_group(value: str) -> FeatureGroup:
    """The group named ``value``; a :class:`ConfigError` naming it when it was removed or is unknown."""
    refuse_removed([value])
    try:
        return FeatureGroup(value)
    except ValueError:
        known = ", ".join(g.value for g in FeatureGroup)
        raise ConfigError(f"unknown feature group {value!r}; known: {known}") from None


@dataclass(frozen=True)
class FeatureSpec:
    """One feature: ``name`` (as stored in models), ``unit``, ``group`` and ``meaning`` (one sentence)."""

    name: str
    unit: str
    group: FeatureGroup
    meaning: str


_G, _R, _M = FeatureGroup.GEOMETRIC, FeatureGroup.RADIOMETRIC, FeatureGroup.MULTIVIEW

# Geometric features per scale; e1 >= e2 >= e3 are the covariance eigenvalues divided by their sum.
GEOMETRIC_BASE: tuple[FeatureSpec, ...] = (
    FeatureSpec("linearity", "1", _G, "(e1 - e2) / e1: 1 on a line, 0 on a plane or in a blob"),
    FeatureSpec("planarity", "1", _G, "(e2 - e3) / e1: 1 on a plane"),
    FeatureSpec("scattering", "1", _G, "e3 / e1: 1 for an isotropic blob (noise, volume)"),
    FeatureSpec("omnivariance", "1", _G, "(e1 e2 e3)^(1/3)"),
    FeatureSpec("anisotropy", "1", _G, "(e1 - e3) / e1"),
    FeatureSpec("eigenentropy", "nat", _G, "-sum e_i ln e_i"),
    FeatureSpec("change_of_curvature", "1", _G, "e3 (the smallest normalised eigenvalue, surface variation)"),
    FeatureSpec("verticality", "1", _G, "1 - |n_z| of the local plane normal: 0 horizontal, 1 vertical"),
    FeatureSpec("density", "1", _G, "k / (pi d_k^2) * v^2: neighbours per cell area of the scale's cell size v"),
    FeatureSpec("roughness", "1", _G, "sqrt(lambda3) / d_k: RMS distance of the neighbours to their plane / radius"),
    FeatureSpec("normal_deviation", "1", _G, "1 - |n_mvs . n_pca|: MVS normal against the local plane (0 if none)"),
)

# Geometric features of the coarser scales only (s >= 1, whose level is the voxel-downsampled cloud).
COARSE_BASE: tuple[FeatureSpec, ...] = (
    FeatureSpec(
        "height",
        "1",
        _G,
        "(z - lowest z of the level in the 3 x 3 columns of cell v around) / v: height above the local ground in "
        "cells (up = +z)",
    ),
)

RADIOMETRIC: tuple[FeatureSpec, ...] = (
    FeatureSpec("red", "1", _R, "red channel / 255"),
    FeatureSpec("green", "1", _R, "green channel / 255"),
    FeatureSpec("blue", "1", _R, "blue channel / 255"),
    FeatureSpec("hue", "1", _R, "HSV hue / 360 (0 for grey)"),
    FeatureSpec("saturation", "1", _R, "HSV saturation"),
    FeatureSpec("value", "1", _R, "HSV value (max channel / 255)"),
    FeatureSpec("color_variance", "1", _R, "std of the RGB colour (/255, channels averaged) over the finest k-NN"),
)

MULTIVIEW: tuple[FeatureSpec, ...] = (
    FeatureSpec("n_views", "count", _M, "images that fused the point (fused.ply.vis)"),
    FeatureSpec("view_ratio", "1", _M, "n_views / images whose frustum contains the point"),
    FeatureSpec("triangulation_spread_deg", "deg", _M, "2 x the largest angle of a fusing view's ray to the mean ray"),
    FeatureSpec("color_std_views", "1", _M, "std over fusing views of the photo colour at the point's projection"),
    FeatureSpec("ncc_views", "1", _M, "mean NCC of each fusing view's 3x3 grey patch with the views' mean patch"),
    FeatureSpec("depth_agree", "1", _M, "share of frustum views whose depth map agrees with the point (rel. 1 %)"),
    FeatureSpec("depth_freespace", "1", _M, "share of frustum views whose depth map sees past the point"),
    FeatureSpec("depth_invalid", "1", _M, "share of frustum views whose depth map is empty at the point"),
    FeatureSpec("depth_residual", "1", _M, "mean |d_map - z| / z over the fusing views, clipped at 1 (1: none)"),
)


def geometric_name(base: str, scale: int) -> str:
    """Name of a geometric feature at scale index ``scale`` (``linearity_s0``)."""
    return f"{base}_s{scale}"


def feature_specs(n_scales: int) -> dict[str, FeatureSpec]:
    """Every known feature for ``n_scales`` geometric scales, by name, in a stable order."""
    out: dict[str, FeatureSpec] = {}
    for s in range(n_scales):
        for spec in GEOMETRIC_BASE + (COARSE_BASE if s >= 1 else ()):
            name = geometric_name(spec.name, s)
            out[name] = FeatureSpec(name, spec.unit, spec.group, f"{spec.meaning} (scale {s})")
    for spec in RADIOMETRIC + MULTIVIEW:
        out[spec.name] = spec
    return out


def resolve_names(selected: tuple[str, ...] | None, n_scales: int, groups: tuple[FeatureGroup, ...]) -> tuple[str, ...]:
    """The feature names to compute: ``selected`` validated, or every feature of ``groups`` (registry order).

    A selected name may be a full name (``planarity_s1``), a geometric base name (``planarity``: every scale) or a
    group name (``radiometric``). Unknown names raise :class:`ConfigError` listing the known ones; names of a removed
    group (:data:`REMOVED_GROUPS`) one naming the group.
    """
    specs = feature_specs(n_scales)
    if selected is None:
        return tuple(n for n, s in specs.items() if s.group in groups)
    picked: list[str] = []
    bases = {s.name for s in GEOMETRIC_BASE + COARSE_BASE}
    for name in selected:
        if name in specs:
            new = [name]
        elif name in bases:
            new = [n for n in (geometric_name(name, s) for s in range(n_scales)) if n in specs]
        elif name in {g.value for g in FeatureGroup}:
            new = [n for n, s in specs.items() if s.group.value == name]
        else:
            refuse_removed([name])
            raise ConfigError(f"unknown feature {name!r}; known: {', '.join(specs)} (or a base name / group)")
        picked += [n for n in new if n not in picked]
    order = list(specs)
    return tuple(sorted(picked, key=order.index))
