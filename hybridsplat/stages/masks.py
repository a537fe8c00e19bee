"""Stage ``masks``: one PNG per registered training photo (255 = needs splats) in classify/masks/.

Non-collaborative points (classify/points.ply), MVS holes and the user's ``--splat-masks`` are united (see
:mod:`classify.masks`). Held-out photos get no training mask. logs/masks.json (the stage record) lists each
photo's coverage and training margin (the train and clean stages dilate each region mask by it); empty masks are
marked so that training skips the photo, and a project without any
non-collaborative region or hole says that training is not needed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from classify.mask_options import MaskOptions
from hybridsplat.project_io import sparse_model
from hybridsplat.stages import sizes
from hybridsplat.stages.base import CliOption, ReportSection, Stage, StageContext, StageResult

HOLE_AREA_HELP = "Where MVS holes are looked for: hull_below | hull | below | enclosed."


@dataclass(frozen=True)
class MasksResult(StageResult):
    """What the masks stage made: masks of ``photos`` training photos, ``empty`` of them empty, their mean coverage
    (the share of a photo's pixels its mask covers, 0..1), whether any needs training (``training_needed``) and
    its ``figures`` (paths relative to the project; none when every mask is empty)."""

    photos: int = 0
    empty: int = 0
    mean_coverage: float = 0.0
    training_needed: bool = True
    figures: tuple[str, ...] = ()


class MasksStage(Stage):
    name = "masks"
    Options = MaskOptions
    Result = MasksResult
    title = "region masks per photo"
    command = "masks"
    command_help = "Region masks per registered photo: non-collaborative points, MVS holes and user masks, united."
    command_options = (
        CliOption("footprint", help="Point radius in point spacings."),
        CliOption("close_px", help="Closing radius in pixels."),
        CliOption("dilate_px", help="Dilation radius in pixels, at least."),
        CliOption(
            "dilate_spacings", help="Dilation radius in point spacings at the photo's median depth, when larger."
        ),
        CliOption("holes", help="Add MVS holes to the masks."),
        CliOption("hole_area", help=HOLE_AREA_HELP),
        CliOption("explained_by", help="Points that explain pixels: seen (fused by the photo or of its colour) | all."),
        CliOption("hole_gsd", help="Radius (ground sample distances) within which a point explains pixels."),
        CliOption("grow_area", help="GrabCut iterations growing the hole area by what looks like the scene (0 off)."),
        CliOption("infinity", help="Pixels at infinity (no parallax: sky, backdrop) are no holes."),
    )

    run_options = (CliOption("hole_area", help=HOLE_AREA_HELP),)

    def inputs(self, ctx: StageContext) -> list[Path]:
        paths = [ctx.layout.classified_points, ctx.layout.classify_report, sparse_model(ctx.layout)]
        if ctx.config.input.splat_masks:
            paths.append(Path(ctx.config.input.splat_masks))
        return paths

    def outputs(self, ctx: StageContext) -> list[Path]:
        # The figure is not listed: it is absent when every mask is empty (the record says whether it exists).
        return [ctx.layout.masks_dir, ctx.layout.record(self.name)]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout_names)}

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of the masks, the record, the figure and the log: a greyscale PNG per registered training photo
        at the largest camera's size; the record 4 KiB + 512 bytes a photo; the figure (up to 4 photos in 2
        columns, 5 in wide each, at 100 dpi) as an RGBA PNG; the log 64 KiB."""
        n = sizes.model_count(sparse_model(ctx.layout), "images") or len(ctx.source.spec.image_names)
        n = max(n - len(ctx.source.holdout_names), 0)
        width, height = sizes.largest(sizes.camera_sizes(sparse_model(ctx.layout)))
        record = 4 * sizes.KIB + 512 * n
        return n * sizes.png_bytes(width, height, 1) + record + _figure_bytes(n, width, height) + sizes.LOG_BYTES

    def run(self, ctx: StageContext) -> MasksResult:
        from classify.run import project_masks
        from core.io.atomic import remove_output
        from core.io.json_io import write_json_atomic

        opts: MaskOptions = ctx.options(self)
        user = Path(ctx.config.input.splat_masks) if ctx.config.input.splat_masks else None
        result = project_masks(
            ctx.layout.classified_points,
            ctx.layout.classify_report,
            sparse_model(ctx.layout),
            ctx.layout.mask_path,
            opts,
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
        figures = (str(ctx.layout.masks_figure.relative_to(ctx.layout.root)),) if result["figure"] else ()
        return MasksResult(
            photos=result["photos"],
            empty=result["empty"],
            mean_coverage=result["mean_coverage"],
            training_needed=result["training_needed"],
            figures=figures,
        )

    def summary(self, result: MasksResult) -> str:
        if not result.training_needed:
            return f"{result.photos} masks, all empty: no splat training needed"
        return f"{result.photos} masks, mean coverage {result.mean_coverage:.1%}, {result.empty} empty"

    def report_section(self, result: MasksResult) -> ReportSection | None:
        if not result.training_needed:
            line = f"{result.photos} masks, all empty: no splat training is needed."
        else:
            cov = result.mean_coverage
            share = f"{cov:.1%}" if math.isfinite(cov) else "n/a"
            line = (f"{result.photos} masks, mean coverage {share} of the photo, "
                    f"{result.empty} empty (skipped by training).")  # fmt: skip
        caption = "photos with their region masks (red: splats are trained there)"
        return ReportSection("Classification and region masks", (line,), tuple((f, caption) for f in result.figures))


def _figure_bytes(photos: int, width: int, height: int) -> int:
    """Upper bytes of classify/figures/masks.png (:func:`classify.figures.masks_png`): up to 4 of ``photos``
    photos of ``width`` × ``height`` px in 2 columns, 5 in wide each and 0.4 in of title a row."""
    panels = min(photos, 4)
    if panels == 0 or width <= 0:
        return 0
    cols = min(2, panels)
    rows = -(-panels // cols)
    return sizes.figure_png_bytes(5.0 * cols, rows * (5.0 * height / width + 0.4))
