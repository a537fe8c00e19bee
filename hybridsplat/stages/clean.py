"""Stage ``clean``: floaters, out-of-region and degenerate splats removed (splats/cleaned.ply), see fusion.clean."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hybridsplat.stages.base import Stage, StageContext, read_project_model


@dataclass(frozen=True)
class CleanStageOptions:
    """Options of the ``clean`` stage (see fusion.clean.CleanOptions; a negative value turns a check off).

    min_opacity: α below which a splat goes. max_scale_scene: largest σ as a share of the scene scale.
    cluster_eps_spacing: DBSCAN eps in median splat spacings; min_cluster_size: smaller clusters are floaters.
    """

    min_opacity: float = 0.02
    max_scale_scene: float = 0.2
    max_scale_spacing: float = -1.0
    cluster_eps_spacing: float = 50.0
    min_cluster_size: int = 3
    mask_dilation_px: int = 2


class CleanStage(Stage):
    name = "clean"
    Options = CleanStageOptions
    title = "splat cleaning"

    def inputs(self, ctx: StageContext) -> list[Path]:
        layout = ctx.layout
        return [layout.trained_splats, layout.masks_dir, layout.record("masks"), layout.dense_workspace.sparse]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.cleaned_splats]

    def needs(self, ctx: StageContext) -> str | None:
        return None if ctx.layout.trained_splats.is_file() else "no trained splats (stage 'train' was skipped)"

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply
        from hybridsplat.stages.train import read_masks

        o: CleanStageOptions = ctx.options(self)

        def opt(v: float) -> float | None:
            return None if v < 0 else v

        cameras, _ = read_project_model(ctx, ctx.layout.dense_workspace.sparse)
        splats = read_gaussian_ply(ctx.layout.trained_splats)
        from fusion.clean import CleanOptions, clean_splats  # torch: after the inputs are read

        options = CleanOptions(o.mask_dilation_px, opt(o.min_opacity), opt(o.max_scale_scene),
                               opt(o.max_scale_spacing), opt(o.cluster_eps_spacing), o.min_cluster_size)  # fmt: skip
        result = clean_splats(splats, cameras, read_masks(ctx, cameras, training=True), options)
        write_gaussian_ply(ctx.layout.cleaned_splats, result.splats)
        return vars(result.counts)

    def summary(self, counts: dict[str, Any]) -> str:
        return f"{counts['kept']} of {counts['input']} splats kept"
