"""Options of the region masks (:mod:`classify.masks`, the pipeline's ``masks`` stage), without OpenCV or scipy.

Kept apart from :mod:`classify.masks` so that the pipeline's configuration and the command line can name and check
them without loading those; :mod:`classify.masks` re-exports them (the module docstring there says what each does).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import ClassVar

from core.constraints import Choice, Constrained, Constraints, Interval


class HoleArea(str, Enum):
    """Where MVS holes are looked for (see the module docstring)."""

    HULL_BELOW = "hull_below"
    HULL = "hull"
    BELOW = "below"
    ENCLOSED = "enclosed"


class ExplainedBy(str, Enum):
    """Which points explain pixels when looking for holes (see the module docstring)."""

    SEEN = "seen"
    ALL = "all"


HOLE_AREAS = tuple(a.value for a in HoleArea)


EXPLAINED_BY = tuple(e.value for e in ExplainedBy)


@dataclass(frozen=True)
class MaskOptions(Constrained):
    """footprint: a point's radius as a multiple of the point spacing (default 1.5: neighbouring footprints touch).
    hole_gsd: the radius, in ground sample distances at the point's depth, within which a point explains pixels
    when looking for holes (default 2.5, a little under the evaluation's τ = 3 GSD because disks of whole pixels
    cover slightly more than their radius; chosen on the tabletop and aerial presets with their true classes, see
    docs/experiments/2026-11-27-domain-defaults.md). 0: use ``hole_footprint``, the radius in point spacings (2.5),
    instead.
    grow_area: GrabCut iterations that grow the valid area by what looks like the reconstructed scene (default 3;
    0 = off; needs the photos, see ``SeenInView``); run on the photo reduced to ``grow_max_px`` pixels on its long
    side (default 640).
    max_radius_px: footprint cap (default 12 px). occlusion_tolerance: relative depth under which a point counts as
    in front (default 2 %). close_px / dilate_px: radii (pixels) of the closing and the dilation (defaults 3 / 2).
    dilate_spacings: the dilation radius in point spacings at the view's median depth, when larger than
    ``dilate_px`` (default 3: a margin tied to the sampling, not to the image size; 0 = ``dilate_px`` only).
    train_margin_spacings: the extra margin of the *training* masks, in point spacings at the view's median depth
    (default 5; 0 = none): recorded per photo as ``train_margin_px`` (:class:`PhotoMask`); the train and clean
    stages dilate the region mask by it (the region masks themselves, what the classification is scored on, stay
    as they are). Splats at a region's edge then see the photo on both sides of it; 5 spacings gave the best
    held-out image quality inside the masks for the same training time, and widening the region masks themselves
    instead would cover far more pixels that need no splats (see docs/experiments/2026-11-27-domain-defaults.md).
    holes: whether MVS holes are added (default True). hole_area: "hull_below" (default), "hull", "below" or
    "enclosed"; explained_by: "seen" (default) or "all"; colour_tolerance: mean absolute RGB difference (/255)
    under which a point's colour matches the photo (best of the 3×3 pixels around its projection; default 0.04)
    (see the module docstring). up: the world's up axis (default +z, data_synth and georeferenced projects).
    min_hole_px: holes smaller than this many pixels are ignored (default 4). min_points_hull: fewer projected
    points than this in a view give no hull (default 20).
    infinity: pixels that show no parallax between the photo and its neighbours (a backdrop or sky at infinity,
    :func:`at_infinity`) and that the cloud's points do not enclose are no holes and seed GrabCut's certain
    background; with a backdrop in view, the area below the envelope outside the hull keeps only what GrabCut
    puts with the scene (default True; needs the photos). Figures in docs/experiments/2026-11-26-classify.md.
    """

    footprint: float = 1.5
    hole_footprint: float = 2.5
    hole_gsd: float = 2.5
    grow_area: int = 3
    grow_max_px: int = 640
    max_radius_px: int = 12
    occlusion_tolerance: float = 0.02
    close_px: int = 3
    dilate_px: int = 2
    dilate_spacings: float = 3.0
    train_margin_spacings: float = 5.0
    holes: bool = True
    hole_area: HoleArea = HoleArea.HULL_BELOW
    explained_by: ExplainedBy = ExplainedBy.SEEN
    colour_tolerance: float = 0.04
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    min_hole_px: int = 4
    min_points_hull: int = 20
    infinity: bool = True

    constraints: ClassVar[Constraints] = {
        "footprint": Interval(float, 0, None, closed="neither"),
        "hole_gsd": Interval(float, 0, None),
        "grow_area": Interval(int, 0, None),
        "grow_max_px": Interval(int, 16, None),
        "max_radius_px": Interval(int, 1, None),
        "close_px": Interval(int, 0, None),
        "dilate_px": Interval(int, 0, None),
        "dilate_spacings": Interval(float, 0, None),
        "train_margin_spacings": Interval(float, 0, None),
        "hole_area": Choice(HoleArea),
        "explained_by": Choice(ExplainedBy),
    }
