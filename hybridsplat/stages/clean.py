"""Stage ``clean``: floaters, out-of-region and degenerate splats removed (splats/cleaned.ply), see fusion.clean."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fusion.clean_options import CleanOptions
from hybridsplat.disk_space import tree_bytes
from hybridsplat.stages import sizes
from hybridsplat.stages.base import CliOption, Stage, StageContext, StageResult


@dataclass(frozen=True)
class CleanResult(StageResult):
    """What the clean stage did (:class:`fusion.clean.CleanCounts`): of ``input`` trained splats, how many it
    removed outside every training mask, below the opacity, of extreme scale and in isolated clusters, and how
    many it ``kept``."""

    input: int = 0
    outside_masks: int = 0
    low_opacity: int = 0
    extreme_scale: int = 0
    isolated: int = 0
    kept: int = 0


class CleanStage(Stage):
    name = "clean"
    Options = CleanOptions
    Result = CleanResult
    title = "splat cleaning"
    command = "clean"
    command_help = (
        "Remove trained splats outside every mask, near-transparent, over-large or in small isolated clusters."
    )
    command_options = (
        CliOption("min_opacity", help="Remove splats with opacity below this (none: off)."),
        CliOption("min_cluster_size", help="Clusters smaller than this are floaters."),
    )

    def inputs(self, ctx: StageContext) -> list[Path]:
        layout = ctx.layout
        return [layout.trained_splats, layout.masks_dir, layout.record("masks"), layout.dense_workspace.sparse]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.cleaned_splats]

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of splats/cleaned.ply, a subset of splats/trained.ply in the same layout: at most that file's
        size, plus an origin sidecar and the log (64 KiB)."""
        return tree_bytes([ctx.layout.trained_splats]) + sizes.SIDECAR_BYTES + sizes.LOG_BYTES

    def needs(self, ctx: StageContext) -> str | None:
        return None if ctx.layout.trained_splats.is_file() else "no trained splats (stage 'train' was skipped)"

    def run(self, ctx: StageContext) -> CleanResult:
        from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply
        from hybridsplat.project_io import read_project_model, read_region_masks

        cameras, _ = read_project_model(ctx.layout, ctx.layout.dense_workspace.sparse)
        splats = read_gaussian_ply(ctx.layout.trained_splats)
        masks = read_region_masks(ctx.layout, cameras, training=True)
        from fusion.clean import clean_splats  # torch: after the inputs are read

        result = clean_splats(splats, cameras, masks, ctx.options(self))
        write_gaussian_ply(ctx.layout.cleaned_splats, result.splats)
        return CleanResult(**vars(result.counts))

    def summary(self, result: CleanResult) -> str:
        return f"{result.kept} of {result.input} splats kept"
