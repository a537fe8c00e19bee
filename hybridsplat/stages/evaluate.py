"""Stage ``eval``: every product against the ground truth (C2C to the reference cloud) and the held-out photos.

Held-out views are the input's own (a data_synth scene's ``test/`` with ``sparse/test``) or the photos held out of
MVS and training (their undistorted copies in the dense workspace). Masked image metrics use the held-out views'
masks: the true non-collaborative materials of a data_synth scene.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import ConfigError
from hybridsplat.stages.base import Stage, StageContext


@dataclass(frozen=True)
class EvalStageOptions:
    """Options of the ``eval`` stage.

    tau_gsd: completeness / F-score threshold in ground-sample distances (scenes that know their GSD).
    tau_m: the same threshold in metres (used when set, > 0; for real data with a LiDAR reference).
    reference: a reference cloud (PLY/LAS/LAZ/E57) for C2C; default: the input's own (a data_synth scene's LiDAR).
    lpips_weights: LPIPS v0.1 AlexNet weights (.npz); empty = $HYBRIDSPLAT_LPIPS_WEIGHTS or ../shared/data/lpips.
    """

    tau_gsd: float = 3.0
    tau_m: float = 0.0
    reference: str = ""
    lpips_weights: str = ""

    def __post_init__(self) -> None:
        if self.tau_gsd <= 0 or self.tau_m < 0:
            raise ConfigError(f"tau_gsd must be > 0 and tau_m >= 0, got {self.tau_gsd}, {self.tau_m}")


@dataclass(frozen=True)
class HeldOutViews:
    model: Path  # COLMAP model with the held-out cameras
    photos: Path
    names: tuple[str, ...] | None  # None: every view of the model


class EvalStage(Stage):
    name = "eval"
    Options = EvalStageOptions
    title = "evaluation against ground truth"

    def _reference(self, ctx: StageContext) -> Path | None:
        opts: EvalStageOptions = ctx.options(self)
        return Path(opts.reference) if opts.reference else ctx.source.spec.reference_cloud

    def _held_out(self, ctx: StageContext) -> HeldOutViews | None:
        holdout = ctx.source.holdout
        if holdout.source == "every":  # photos of the input: their undistorted copies in the dense workspace
            ws = ctx.layout.dense_workspace
            return HeldOutViews(ws.sparse, ws.images, holdout.names)
        if holdout.source == "input":
            return HeldOutViews(holdout.model, holdout.image_dir, None)
        return None

    def inputs(self, ctx: StageContext) -> list[Path]:
        layout, spec = ctx.layout, ctx.source.spec
        truth = [self._reference(ctx), ctx.source.holdout.model, ctx.source.holdout.image_dir, spec.test_labels]
        return [layout.fused_ply, layout.mvs_gaussians, layout.merged_ply, *(p for p in truth if p)]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.eval_dir]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout.names)}

    def needs(self, ctx: StageContext) -> str | None:
        if self._reference(ctx) is None and self._held_out(ctx) is None:
            return "nothing to compare with: no reference cloud and no held-out photos (see --holdout)"
        return None

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from core.io.colmap import read_model
        from core.io.gaussian_ply import read_gaussian_ply
        from eval.evaluate import ImageInputs, evaluate_product
        from eval.geometry import GeometryOptions
        from recon.workspace import read_fused

        opts: EvalStageOptions = ctx.options(self)
        layout, spec = ctx.layout, ctx.source.spec
        reference = self._reference(ctx)
        tau = opts.tau_m if opts.tau_m > 0 else (opts.tau_gsd * spec.gsd_m if spec.gsd_m else None)
        images = None
        held_out = self._held_out(ctx)
        if held_out is not None:
            cameras, _ = read_model(held_out.model)
            views = [v for v in cameras if held_out.names is None or v.name in held_out.names]
            masks = self._truth_masks(ctx) if held_out.names is None else None
            images = ImageInputs(cameras, views, held_out.photos, masks)
        lpips_model = _lpips_or_none(opts.lpips_weights or None)
        products = {
            "mvs": (read_fused(layout.dense), read_gaussian_ply(layout.mvs_gaussians)),
            "merged": (layout.merged_points_ply, read_gaussian_ply(layout.merged_ply)),
        }
        counts: dict[str, Any] = {"lpips": lpips_model is not None, "views": len(images.views) if images else 0}
        for done, (name, (cloud, gaussians)) in enumerate(products.items()):
            ctx.progress("products", done, len(products))
            result = evaluate_product(
                layout.metrics_json,
                name,
                cloud=cloud if reference is not None else None,
                reference=reference,
                gaussians=gaussians,
                images=images,
                geometry=GeometryOptions(tau=tau),
                lpips_model=lpips_model,
            )
            if result.c2c is not None:
                counts[f"{name}_c2c_mean_m"] = result.c2c.stats.mean
            if result.images is not None:
                counts[f"{name}_psnr"] = result.images.full.mean.psnr if result.images.full else None
        ctx.progress("products", len(products), len(products))
        evaluate_product(layout.metrics_json, "splats", skip_reason="no splats were trained (no training stage yet)")
        return counts

    def _truth_masks(self, ctx: StageContext) -> Path | None:
        """Masks of the true non-collaborative materials of the held-out views (data_synth), or None."""
        from core.io.images import read_image, write_image

        spec = ctx.source.spec
        if spec.test_labels is None or not spec.non_collaborative_ids:
            return None
        out = ctx.layout.eval_masks_dir
        for label_path in sorted(spec.test_labels.glob("*.png")):
            labels = read_image(label_path, grayscale=True)
            mask = np.isin(labels, np.asarray(spec.non_collaborative_ids, dtype=labels.dtype)).astype(np.uint8) * 255
            write_image(out / label_path.name, mask)
        return out

    def summary(self, counts: dict[str, Any]) -> str:
        parts = []
        for name in ("mvs", "merged"):
            if f"{name}_c2c_mean_m" in counts:
                parts.append(f"{name} C2C mean {counts[f'{name}_c2c_mean_m']:.3g} m")
            if counts.get(f"{name}_psnr") is not None:
                parts.append(f"{name} PSNR {counts[f'{name}_psnr']:.2f} dB")
        return ", ".join(parts)


def _lpips_or_none(weights: str | None) -> object | None:
    """The LPIPS model when weights can be found, else None (LPIPS left out, said once as a warning)."""
    import warnings

    from core.errors import HybridSplatError
    from eval.lpips import LPIPS

    try:
        return LPIPS.from_path(weights)
    except HybridSplatError as err:
        warnings.warn(f"LPIPS left out of the image metrics: {err.one_line()}", stacklevel=2)
        return None
