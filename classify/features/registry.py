"""The feature registry: every per-point feature has a name, a unit, a group and a meaning.

Features are selected by name (``FeatureOptions.names``, the configuration's ``classify.features``); the model
stores the names it was trained on and refuses data whose names differ. Geometric features exist once per
scale; their names carry the scale index (``linearity_s0``, ``linearity_s1``...). The table below is the
documentation users see (``hybridsplat classify features`` prints it).

Groups, in registry order (``FeatureOptions()`` selects the first three; ``ALL_GROUPS_EXTENDED`` all seven):

================ ===================== ===================================================================
group            module                what it measures
================ ===================== ===================================================================
geometric        geometric.py          shape of the k-NN neighbourhood at three scales (eigenvalues, height)
radiometric      radiometric.py        the point's colour and its spread over the finest neighbourhood
multiview        multiview.py          photos and depth maps of the frustum / fusing views at the point
fusion           fusion_evidence.py    disagreement of the fusing depth maps; offset from the neighbours' plane
view_dependent   view_dependent.py     luminance against viewing direction across the fusing views
image_boundaries image_boundaries.py   photo edges (Sobel, Canny distance) at the point's projections
image_texture    image_texture.py      grey-level spread and corner strength in the MVS window at the projections
================ ===================== ===================================================================

Units: ``1`` dimensionless (lengths divided by the cloud's median point spacing among them, as the meaning says),
``px`` photo pixels.
The newer groups (fusion, view_dependent, image_boundaries, image_texture) need the views, like multiview; each has a
documented neutral value for a point without the evidence (no fusing view, fewer than 2 or 3 views, no normal).
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
    FUSION = "fusion"
    VIEW_DEPENDENT = "view_dependent"
    IMAGE_BOUNDARIES = "image_boundaries"
    IMAGE_TEXTURE = "image_texture"


@dataclass(frozen=True)
class FeatureSpec:
    """One feature: ``name`` (as stored in models), ``unit``, ``group`` and ``meaning`` (one sentence)."""

    name: str
    unit: str
    group: FeatureGroup
    meaning: str


_G, _R, _M = FeatureGroup.GEOMETRIC, FeatureGroup.RADIOMETRIC, FeatureGroup.MULTIVIEW
_F, _V, _B = FeatureGroup.FUSION, FeatureGroup.VIEW_DEPENDENT, FeatureGroup.IMAGE_BOUNDARIES
_T = FeatureGroup.IMAGE_TEXTURE

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

FUSION: tuple[FeatureSpec, ...] = (
    FeatureSpec(
        "fusion_backproj_dist",
        "1",
        _F,
        "mean distance in spacings from the point to each fusing view's depth-map point on its ray, capped at 50 "
        "(50: no valid depth)",
    ),
    FeatureSpec(
        "fusion_reproj_px",
        "px",
        _F,
        "RMS pixel offset in each other fusing view of those depth-map points (linearised), capped at 50 (50: no "
        "pair of views)",
    ),
    FeatureSpec(
        "fusion_plane_offset",
        "1",
        _F,
        "signed distance in spacings along the mean viewing ray to the PCA plane of the k - 1 nearest other points, "
        "+ when the point is in front of it, clipped to +-50 (0: no fusing view)",
    ),
)

VIEW_DEPENDENT: tuple[FeatureSpec, ...] = (
    FeatureSpec("lum_cv_views", "1", _V, "std / mean (mean >= 0.02) of the luminance over the fusing views (0: < 2)"),
    FeatureSpec("lum_peak_views", "1", _V, "max - median luminance over the fusing views: a highlight (0: < 2 views)"),
    FeatureSpec(
        "lum_lobe_corr",
        "1",
        _V,
        "correlation of the other views' luminance with the cosine of their ray to the brightest view's ray "
        "(0: < 3 others)",
    ),
    FeatureSpec(
        "specular_up_corr",
        "1",
        _V,
        "correlation of the luminance with the up (+z) part of the view ray mirrored about the MVS normal "
        "(0: no normal or < 3 views)",
    ),
)

IMAGE_BOUNDARIES: tuple[FeatureSpec, ...] = (
    FeatureSpec(
        "edge_strength_views",
        "1/px",
        _B,
        "mean Sobel gradient magnitude (grey / 255 per px) at the point's projections in the fusing views (0: none)",
    ),
    FeatureSpec(
        "edge_distance_px",
        "px",
        _B,
        "mean distance from the projections to the nearest Canny edge pixel, capped at 32 (32: no fusing view)",
    ),
    FeatureSpec(
        "edge_distance_spacing",
        "1",
        _B,
        "that distance per view in metres at the point's depth (px z / f) / spacing, averaged, capped at 32 (32: none)",
    ),
)

IMAGE_TEXTURE: tuple[FeatureSpec, ...] = (
    FeatureSpec(
        "texture_std_views",
        "1",
        _T,
        "mean grey std (0-1) in the MVS window (7 x 7 px) at the point's projections in the fusing views (0: none)",
    ),
    FeatureSpec(
        "texture_corner_views",
        "1/px",
        _T,
        "mean sqrt of the smaller structure-tensor eigenvalue in that window (grey / 255 per px; 0: none)",
    ),
    FeatureSpec(
        "texture_log_spread",
        "1",
        _T,
        "std over the fusing views of ln(window grey std + 0.004): unlike texture between views (0: < 2 views)",
    ),
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
    for spec in RADIOMETRIC + MULTIVIEW + FUSION + VIEW_DEPENDENT + IMAGE_BOUNDARIES + IMAGE_TEXTURE:
        out[spec.name] = spec
    return out


def resolve_names(selected: tuple[str, ...] | None, n_scales: int, groups: tuple[FeatureGroup, ...]) -> tuple[str, ...]:
    """The feature names to compute: ``selected`` validated, or every feature of ``groups`` (registry order).

    A selected name may be a full name (``planarity_s1``), a geometric base name (``planarity``: every scale) or a
    group name (``radiometric``). Unknown names raise :class:`ConfigError` listing the known ones.
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
            raise ConfigError(f"unknown feature {name!r}; known: {', '.join(specs)} (or a base name / group)")
        picked += [n for n in new if n not in picked]
    order = list(specs)
    return tuple(sorted(picked, key=order.index))
