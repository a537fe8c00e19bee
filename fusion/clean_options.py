"""Options of splat cleaning and of the survey-point rule (:mod:`fusion.clean`), without its heavy imports.

Kept apart from :mod:`fusion.clean` (torch, scikit-learn) so that the pipeline's configuration and the command line
can name and check them without loading those; :mod:`fusion.clean` re-exports them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from core.constraints import Constrained, Constraints, Interval, NoneOr

POSITIVE_OR_INF = Interval(float, 0, math.inf, closed="right")
"""A threshold > 0; inf (as None) sets no limit."""


@dataclass(frozen=True)
class CleanOptions(Constrained):
    """Options of :func:`fusion.clean.clean_splats` and of the pipeline's ``clean`` stage; a check is off when its
    value is None.

    mask_dilation_px: the masks are dilated by this many pixels before the outside-every-mask test.
    min_opacity: α below which a splat goes. max_scale_scene / max_scale_spacing: largest σ as a share of the scene
    scale / in median splat spacings. cluster_eps_spacing: DBSCAN eps in median splat spacings; clusters smaller
    than ``min_cluster_size`` splats are floaters. The defaults are lenient on purpose: large flat splats on
    textureless, glass and mirror regions, and sparse splats, are legitimate there (chosen on data_synth
    ``tabletop``; docs/experiments/2026-11-27-pipeline-defaults.md).
    """

    mask_dilation_px: int = 2
    min_opacity: float | None = 0.02
    max_scale_scene: float | None = 0.2
    max_scale_spacing: float | None = None
    cluster_eps_spacing: float | None = 50.0
    min_cluster_size: int = 3

    constraints: ClassVar[Constraints] = {
        "mask_dilation_px": Interval(int, 0, None),
        "max_scale_scene": NoneOr(POSITIVE_OR_INF),
        "max_scale_spacing": NoneOr(POSITIVE_OR_INF),
        "cluster_eps_spacing": NoneOr(POSITIVE_OR_INF),
        "min_cluster_size": Interval(int, 1, None),
    }


@dataclass(frozen=True)
class SurveyPointOptions(Constrained):
    """Rule for the splats whose centres go into the survey point product (``merged_points.ply/.las``).

    A point product must not contain floaters, so a splat's centre is a point only when its geometry is
    trustworthy; the 3DGS PLY keeps every cleaned splat for rendering. Defaults chosen on data_synth ``tabletop``
    and ``tiny`` (``bench/bench_train.py geometry``; docs/experiments/2026-11-27-pipeline-defaults.md): the rim
    test is what rejects the virtual images MVS and splats place inside mirrors and glass.
    Lengths relative to ``spacing``, the trusted MVS point spacing (metres) passed to :func:`select_survey_points`.
    A check is off when its value is None.

    min_opacity: α at least this (a faint splat is a colour correction, not a surface).
    max_thickness_spacing: smallest σ at most this × spacing (thin along its normal: a surface element).
    max_extent_spacing: largest σ at most this × spacing (a large splat's centre says little about the surface).
    min_views: the centre lands inside the mask, in front of the trusted MVS surface, in at least this many views.
    min_mask_share: of the views where the centre lands in the image unoccluded by the trusted MVS surface, the
        share where it lands inside the mask (visual-hull consistency: a centre seen outside the region from other
        views floats in front of or beside the real surface).
    occlusion_tolerance: relative depth margin of the occlusion test (behind the trusted z-buffer by more than this
        share of its depth = occluded; the view is not counted).
    max_rim_spacing: the centre must come within this × spacing (metres at its depth) of a mask edge in some view
        where it lands inside the mask. A point of a surface lies on the silhouette rim of the views that graze it;
        what MVS or a splat places *inside* a mirror or glass object (virtual images of reflections, refractions)
        stays inside every visual hull but far from every rim. None turns the test off.
    max_behind_share: of the views where the centre lands inside the mask unoccluded, the share where it lies
        behind the trusted MVS surface filled across the hole (:func:`hole_filled_depth`) by more than
        ``behind_margin_spacing`` × spacing may be at most this. Splats that lie below a table or behind a wall
        whose MVS has a hole (what training puts there to explain the photos) are rejected; a convex object's
        virtual images are not (the hole's surroundings lie behind it: the rim test is for them). None: off.
    behind_margin_spacing: margin of the test above (in spacings).
    shape_checks: apply the opacity / thickness / extent tests (off for MVS points, whose Gaussians are converted,
        not trained).
    """

    min_opacity: float | None = 0.2
    max_thickness_spacing: float | None = 2.0
    max_extent_spacing: float | None = 10.0
    min_views: int = 3
    min_mask_share: float | None = 0.9
    occlusion_tolerance: float = 0.02
    max_rim_spacing: float | None = 0.5
    max_behind_share: float | None = None
    behind_margin_spacing: float = 2.0
    shape_checks: bool = True

    constraints: ClassVar[Constraints] = {
        "min_opacity": NoneOr(POSITIVE_OR_INF),
        "max_thickness_spacing": NoneOr(POSITIVE_OR_INF),
        "max_extent_spacing": NoneOr(POSITIVE_OR_INF),
        "min_views": Interval(int, 0, None),
        "min_mask_share": NoneOr(Interval(float, 0, 1)),
        "occlusion_tolerance": Interval(float, 0, math.inf),
        "max_rim_spacing": NoneOr(POSITIVE_OR_INF),
        "max_behind_share": NoneOr(Interval(float, 0, 1)),
        "behind_margin_spacing": Interval(float, 0, None),
    }


def surface_splat_options() -> SurveyPointOptions:
    """The rule for splats whose centres may shape a mesh (the ``surface`` field the merge stage writes): opaque
    (α ≥ 0.5), seen inside the mask from 3 views and outside it from almost none (visual hull), and not behind the
    trusted MVS surface filled across its holes (in at most half of the views). No thickness, extent or rim test:
    those keep a point product exact but drop the large flat splats of textureless surfaces, which are what a mesh
    needs there (``bench/bench_mesh.py --sections 3``; docs/experiments/2026-11-27-pipeline-defaults.md)."""
    return SurveyPointOptions(
        min_opacity=0.5, max_thickness_spacing=None, max_extent_spacing=None, min_views=3, min_mask_share=0.9,
        max_rim_spacing=None, max_behind_share=0.5,
    )  # fmt: skip
