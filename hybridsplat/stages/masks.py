"""Stage ``masks``: one PNG per registered training photo (255 = needs splats) in classify/masks/.

Non-collaborative points (classify/points.ply), MVS holes and the user's ``--splat-masks`` are united (see
:mod:`classify.masks`). Held-out photos get no training mask. logs/masks.json (the stage record) lists each
photo's coverage and training margin (the train and clean stages dilate each region mask by it); empty masks are
marked so that training skips the photo, and a project without any
non-collaborative region or hole says that training is not needed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from classify.masks import MaskOptions
from hybridsplat.stages.base import Stage, StageContext


@dataclass(frozen=True)
class MasksStageOptions:
    """Options of the ``masks`` stage (see :class:`classify.masks.MaskOptions`).

    footprint: point radius in spacings (1.5). hole_gsd: radius within which a point explains pixels when looking
    for holes, in ground sample distances (2.5; 0 = ``hole_footprint`` point spacings, 2.5). close_px /
    dilate_px: closing and dilation radii (3 / 2 px); dilate_spacings: the dilation in point spacings at the
    photo's median depth when larger (3). train_margin_spacings: the training masks' extra margin (5; see
    classify.masks.MaskOptions), recorded per photo in logs/masks.json.
    holes: add MVS holes (True). hole_area: hull_below | hull | below | enclosed (hull_below).
    explained_by: seen | all (seen): which points explain pixels when looking for holes.
    grow_area: GrabCut iterations growing the valid area by what looks like the reconstructed scene (3; 0 = off).
    infinity: pixels at infinity (no parallax between neighbouring photos: sky, a distant backdrop) outside what
    the cloud encloses are no holes (True).
    """

    footprint: float = 1.5
    hole_gsd: float = 2.5
    hole_footprint: float = 2.5
    close_px: int = 3
    dilate_px: int = 2
    dilate_spacings: float = 3.0
    train_margin_spacings: float = 5.0
    holes: bool = True
    hole_area: str = "hull_below"
    explained_by: str = "seen"
    grow_area: int = 3
    infinity: bool = True

    def mask_options(self) -> MaskOptions:
        return MaskOptions(
            footprint=self.footprint,
            hole_gsd=self.hole_gsd,
            hole_footprint=self.hole_footprint,
            close_px=self.close_px,
            dilate_px=self.dilate_px,
            dilate_spacings=self.dilate_spacings,
            train_margin_spacings=self.train_margin_spacings,
            holes=self.holes,
            hole_area=self.hole_area,
            explained_by=self.explained_by,
            grow_area=self.grow_area,
            infinity=self.infinity,
        )

    def __post_init__(self) -> None:
        self.mask_options()  # validates


class MasksStage(Stage):
    name = "masks"
    Options = MasksStageOptions
    title = "region masks per photo"

    def inputs(self, ctx: StageContext) -> list[Path]:
        paths = [ctx.layout.classified_points, ctx.layout.classify_report, ctx.layout.sparse]
        if ctx.config.input.splat_masks:
            paths.append(Path(ctx.config.input.splat_masks))
        return paths

    def outputs(self, ctx: StageContext) -> list[Path]:
        # The figure is not listed: it is absent when every mask is empty (the record says whether it exists).
        return [ctx.layout.masks_dir, ctx.layout.record(self.name)]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout_names)}

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from classify.run import project_masks
        from core.io.atomic import remove_output
        from core.io.json_io import write_json_atomic

        opts: MasksStageOptions = ctx.options(self)
        user = Path(ctx.config.input.splat_masks) if ctx.config.input.splat_masks else None
        result = project_masks(
            ctx.layout.classified_points,
            ctx.layout.classify_report,
            ctx.layout.sparse,
            ctx.layout.mask_path,
            opts.mask_options(),
            user_mask_dir=user,
            held_out=set(ctx.source.holdout_names),
            progress=ctx.progress,
            figure=ctx.layout.masks_figure,
            image_dir=ctx.source.image_dir,
            dense_dir=ctx.layout.dense,
        )
        write_json_atomic(ctx.layout.record(self.name), result)
        if not result["figure"]:
            remove_output(ctx.layout.masks_figure)  # a figure of an earlier run would be stale
        counts = {k: result[k] for k in ("photos", "empty", "mean_coverage", "training_needed")}
        counts["figures"] = [str(ctx.layout.masks_figure.relative_to(ctx.layout.root))] if result["figure"] else []
        return counts

    def summary(self, counts: dict[str, Any]) -> str:
        if not counts["training_needed"]:
            return f"{counts['photos']} masks, all empty: no splat training needed"
        return f"{counts['photos']} masks, mean coverage {counts['mean_coverage']:.1%}, {counts['empty']} empty"
