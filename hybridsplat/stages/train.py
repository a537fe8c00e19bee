"""Stage ``train``: new splats trained inside the region masks next to the frozen MVS Gaussians (splats/trained.ply
and splats/snapshots/), see fusion.train.

Reads the undistorted photos and model of the dense workspace (held-out photos excluded), the classified cloud
(``needs_splats`` per MVS point), the masks (classify/masks/<image name>.png, 255 = needs splats), the MVS Gaussians
(export/mvs_gaussians.ply, one per fused point) and the SfM points. Skipped when the scene has no classification or
no mask pixel.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import ConfigError, DataError
from hybridsplat.stages.base import Stage, StageContext, read_project_model


@dataclass(frozen=True)
class TrainStageOptions:
    """Options of the ``train`` stage (see fusion.train.TrainOptions for the training defaults).

    iterations: maximum steps (early stop on the hold-out mask pixels); see below for the default.
    downscale: integer factor for photos and masks; raised so that the longer side is at most ``max_image_size``
        pixels (CPU-sized by default; 0 = no limit); the factor used is recorded in the manifest.
    cap: hard Gaussian budget, further limited to ``splats_per_mask_pixel`` × the mask pixels of all training
        photos (at least 1000) so that small regions get small budgets.
    sh_degree: highest SH degree. flat: surface-aligned splats. rays_per_view: ray seeds per photo.
    snapshot_iterations: steps after which the splats are kept in splats/snapshots/.
    depth_prior / normal_prior: weights of the depth (edge-aware log-L1) and normal-consistency priors from the
        trusted MVS surface around each mask (fusion.train.priors; 0 turns one off). Off by default: on data_synth
        tabletop (24 views 320×240, truth masks, 500 steps) 0.2 / 0.1 changed the merged survey points' mean C2C by
        −0.02 mm (0 with the hull test) and their completeness by 0 (−0.001) but cost 0.24 dB (0.46 dB) masked PSNR;
        the geometry of the point product comes from the survey-point rule of the merge stage. prior_border_px: decay
        length from the mask edge inwards at the training resolution (negative: the whole mask);
        prior_edge_scale: image-gradient scale of the edge-aware weight (negative: off); prior_hull_share: the prior
        is kept where its surface point lands inside this share of the other views' masks (negative: off).
    iterations: 1000 keeps a CPU run of the 11 fountain-P11 photos (500×333 training size, 270 k frozen MVS
        Gaussians, about 0.3 s a step on 2 cores) inside 15 minutes. On the demo tabletop (seed 1, masks of the
        default model; held-out views, merged product inside the true non-collaborative masks; the 2000-step
        whole-scene baseline scores 21.85 dB there, 22.16 dB at 4000) the masked PSNR / merged C2C mean / train
        time were 21.00 dB / 1.85 mm / 59 s at 600 steps, 21.30 dB / 2.06 mm / 99 s at 1000, 21.57 dB / 2.39 mm /
        204 s at 1500, and 21.56 dB / 2.23 mm / 177 s at 1500 with refine_until 0.35 (MVS alone: 11.17 dB /
        2.28 mm); 3000 steps gave 21.59 dB (405 s): a plateau, while the training photos' own hold-out pixels kept
        improving (24.4 → 26.0 dB). Training inside masks widened by the masks stage's training margin instead
        (``train_margin_spacings``): 21.93 dB / 2.41 mm at 1500 steps with 3 spacings (226 s), 22.26 dB / 2.46 mm
        with 5 (207 s; the default).
    refine_start / refine_until: densification (clone, split, prune; fusion.train.DefaultStrategy) runs from step
        ``refine_start`` until the share ``refine_until`` of ``iterations`` (never in the last half by default).
        Densifying to the last step had cost the demo 1.1 dB (600 steps: 18.99 dB, with refine_until 0.5: 20.13).
    hard_views: hard-view mining mid-training (fusion.train.HardViewOptions defaults); off by default.
    photometric: ``l1_ssim`` (3DGS) or ``smoothl1_msssim`` (fusion.train.msssim).
    lpips_weight: weight of an LPIPS term on the mask pixels (fusion.train.perceptual) from ``lpips_start`` × the
        iterations on; 0 = off (the default). lpips_weights: the LPIPS v0.1 AlexNet weights (.npz); empty =
        $HYBRIDSPLAT_LPIPS_WEIGHTS or ../shared/data/lpips (eval.lpips.find_weights); resolved and checked before
        training starts, only when the term is on. On the demo (600 steps, from step 480; held-out views, merged,
        inside the masks; seed 1) 0.1 changed PSNR / SSIM / LPIPS by −0.09 dB / −0.008 / −0.001 and 0.2 by
        0.00 dB / −0.007 / −0.017 (seed 2: −0.29 dB / −0.015 / −0.016), for ~0.12 s of CPU per LPIPS step
        (AlexNet forward of both crops + backward, crops ~210×320 px): off by default.
    """

    iterations: int = 1000
    downscale: int = 1
    max_image_size: int = 640
    cap: int = 60_000
    splats_per_mask_pixel: float = 0.25
    sh_degree: int = 3
    flat: bool = False
    rays_per_view: int = 400
    snapshot_iterations: tuple[int, ...] = (500, 1000, 1500)
    depth_prior: float = 0.0
    normal_prior: float = 0.0
    prior_border_px: float = 8.0
    prior_edge_scale: float = 0.1
    prior_hull_share: float = 0.8
    refine_start: int = 100
    refine_until: float = 0.5
    hard_views: bool = False
    photometric: str = "l1_ssim"
    lpips_weight: float = 0.0
    lpips_start: float = 0.8
    lpips_weights: str = ""

    def prior_options(self):
        from fusion.train.priors import PriorOptions

        if self.depth_prior <= 0 and self.normal_prior <= 0:
            return None
        border = self.prior_border_px if self.prior_border_px > 0 else None
        edge = self.prior_edge_scale if self.prior_edge_scale > 0 else None
        hull = self.prior_hull_share if self.prior_hull_share >= 0 else None
        return PriorOptions(max(self.depth_prior, 0.0), max(self.normal_prior, 0.0), border, edge_scale=edge,
                            hull_share=hull)  # fmt: skip

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.downscale < 1 or self.cap < 1 or self.max_image_size < 0:
            raise ConfigError("iterations, downscale and cap must be >= 1, max_image_size >= 0")
        if self.refine_start < 0 or not 0.0 < self.refine_until <= 1.0:
            raise ConfigError(f"need refine_start >= 0 and 0 < refine_until <= 1, got {self.refine_start}, "
                              f"{self.refine_until}")  # fmt: skip
        if not self.splats_per_mask_pixel > 0:
            raise ConfigError(f"splats_per_mask_pixel must be > 0, got {self.splats_per_mask_pixel}")
        if not (self.lpips_weight >= 0 and 0.0 <= self.lpips_start <= 1.0):
            raise ConfigError(f"need lpips_weight >= 0 and lpips_start in [0, 1], got {self.lpips_weight}, "
                              f"{self.lpips_start}")  # fmt: skip


def training_downscale(cameras, downscale: int, max_image_size: int) -> int:
    """The integer photo downscale for training: at least ``downscale``, and enough that the longer side of every
    camera is at most ``max_image_size`` pixels (0 = no limit)."""
    longest = max(max(cameras.camera_of(v).width, cameras.camera_of(v).height) for v in cameras)
    return max(downscale, -(-longest // max_image_size) if max_image_size else 1)


def read_masks(ctx: StageContext, cameras, training: bool = False) -> dict[str, np.ndarray]:
    """Masks (bool, at each camera's size; resized nearest when classify wrote another size) by image name.

    training: the training masks, i.e. each region mask dilated by a disk (OpenCV's ellipse element, as in the
    masks stage) of its photo's ``train_margin_px`` (recorded by the masks stage, see
    classify.masks.MaskOptions.train_margin_spacings; 0 when the record has none)."""
    import cv2

    from core.io.images import read_image

    margins: dict[str, int] = {}
    record = ctx.layout.record("masks")
    if training and record.is_file():
        from core.io.json_io import read_json

        per_photo = read_json(record).get("per_photo", [])
        margins = {p["name"]: int(p.get("train_margin_px", 0)) for p in per_photo}
    masks = {}
    for view in cameras:
        path = ctx.layout.mask_path(view.name)
        if not path.is_file():
            continue
        m = read_image(path, grayscale=True) > 127
        margin = margins.get(view.name, 0)
        if margin > 0 and m.any():
            disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
            m = cv2.dilate(m.astype(np.uint8), disk) > 0
        cam = cameras.camera_of(view)
        if m.shape != (cam.height, cam.width):
            m = cv2.resize(m.astype(np.uint8), (cam.width, cam.height), interpolation=cv2.INTER_NEAREST) > 0
        masks[view.name] = m
    return masks


def needs_splats_per_gaussian(ctx: StageContext, mvs) -> np.ndarray:
    """``needs_splats`` of the classified cloud, one per MVS Gaussian (same order, or matched by nearest position)."""
    return classified_field_per_gaussian(ctx, mvs, "needs_splats").astype(bool)


def classified_field_per_gaussian(ctx: StageContext, mvs, field: str) -> np.ndarray:
    """A per-point field of the classified cloud (``needs_splats``, ``classification``, ...), one value per MVS
    Gaussian (same order, or matched by nearest position)."""
    from scipy.spatial import cKDTree

    from core.io import read_point_cloud

    cloud = read_point_cloud(ctx.layout.classified_points)
    if field not in cloud.fields:
        raise DataError(f"classified cloud has no {field!r} field", ctx.layout.classified_points)
    values = np.asarray(cloud.fields[field])
    if len(cloud) == len(mvs):
        return values
    _, idx = cKDTree(cloud.world_positions).query(mvs.world_means, k=1, workers=-1)
    return values[idx]


class TrainStage(Stage):
    name = "train"
    Options = TrainStageOptions
    title = "masked splat training"

    def inputs(self, ctx: StageContext) -> list[Path]:
        ws = ctx.layout.dense_workspace
        layout = ctx.layout
        return [layout.classified_points, layout.masks_dir, layout.record("masks"), layout.mvs_gaussians, ws.sparse,
                ws.images]  # fmt: skip

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.trained_splats, ctx.layout.snapshots_dir]

    def needs(self, ctx: StageContext) -> str | None:
        if not ctx.layout.classified_points.is_file():
            return "no classified cloud (classify/points.ply): no region to train splats in"
        masks = ctx.layout.masks_dir
        if not masks.is_dir() or not any(masks.glob("*.png")):
            return "no region masks (classify/masks): nothing needs splats"
        record = ctx.layout.record("masks")
        if record.is_file():
            from core.io.json_io import read_json_object

            if read_json_object(record).get("training_needed") is False:
                return "every region mask is empty: no non-collaborative region or hole needs splats"
        return None

    def run(self, ctx: StageContext) -> dict[str, Any]:
        from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply
        from core.io.images import read_image

        opts: TrainStageOptions = ctx.options(self)
        layout = ctx.layout
        lpips_file, lpips_arrays = None, None
        if opts.lpips_weight > 0:  # resolved and checked first: a missing or bad file fails before any work
            from eval.lpips import find_weights, read_weights

            lpips_file = find_weights(opts.lpips_weights or None)
            lpips_arrays = read_weights(lpips_file)
        ws = layout.dense_workspace
        cameras, _ = read_project_model(ctx, ws.sparse)
        _, sfm = read_project_model(ctx, layout.sparse)
        held_out = set(ctx.source.holdout_names) if ctx.source is not None else set()
        masks = read_masks(ctx, cameras, training=True)
        masks = {k: m for k, m in masks.items() if k not in held_out}  # never train on those
        if not any(m.any() for m in masks.values()):
            return {"trained": 0, "reason": "masks are empty"}
        images = {v.name: read_image(ws.images / v.name) for v in cameras if v.name in masks}
        mvs = read_gaussian_ply(layout.mvs_gaussians).with_origin(cameras.origin)
        needs = needs_splats_per_gaussian(ctx, mvs)
        # torch from here on: the inputs above have been read and checked
        from fusion.train import DefaultStrategy, HardViewOptions, TrainOptions, train_splats
        from fusion.train.init import InitOptions, seed_splats

        sfm_local = sfm.world_positions - cameras.origin if len(sfm) else None
        seeds = seed_splats(cameras, masks, images, mvs.means, np.clip(mvs.base_colors * 255, 0, 255), needs,
                            sfm_local, sfm.colors if len(sfm) else None,
                            InitOptions(rays_per_view=opts.rays_per_view, seed=ctx.config.seed))  # fmt: skip
        downscale = training_downscale(cameras, opts.downscale, opts.max_image_size)
        mask_pixels = sum(int(m.sum()) for m in masks.values()) / downscale**2
        cap = min(opts.cap, max(1000, round(opts.splats_per_mask_pixel * mask_pixels)))
        train_opts = TrainOptions(iterations=opts.iterations, downscale=downscale, seed=ctx.config.seed,
                                  sh_degree=opts.sh_degree, flat=opts.flat,
                                  snapshot_iterations=opts.snapshot_iterations, priors=opts.prior_options(),
                                  hard_views=HardViewOptions() if opts.hard_views else None,
                                  photometric=opts.photometric, refine_until=opts.refine_until,
                                  lpips_weight=opts.lpips_weight, lpips_start=opts.lpips_start,
                                  strategy=DefaultStrategy(cap=cap, refine_start=opts.refine_start))  # fmt: skip
        lpips = None
        if lpips_arrays is not None:
            from eval.lpips import LPIPS

            lpips = LPIPS(lpips_arrays)

        def progress(info) -> None:
            ctx.progress(
                f"loss {info.loss:.4f} masked PSNR {info.holdout_psnr:.2f} dB, {info.gaussians} splats",
                info.step,
                info.iterations,
            )

        result = train_splats(cameras, images, masks, seeds.gaussians, mvs.subset(~needs), train_opts, progress,
                              lpips=lpips)  # fmt: skip
        write_gaussian_ply(layout.trained_splats, result.splats)
        layout.snapshots_dir.mkdir(parents=True, exist_ok=True)
        for step, snap in sorted(result.snapshots.items()):
            write_gaussian_ply(layout.snapshots_dir / f"splats_{step:06d}.ply", snap)
        return {
            "trained": len(result.splats),
            "downscale": downscale,
            "cap": cap,
            "iterations": result.iterations,
            "stopped_early": result.stopped_early,
            "holdout_psnr_db": result.final_holdout_psnr,
            "views_used": result.views_used,
            "views_without_mask": result.views_without_mask,
            "mask_pixels": result.mask_pixels,
            "context_gaussians": result.context_total,
            "context_culled": result.context_culled,
            "prior_views": result.prior_views,
            "prior_pixels": result.prior_pixels,
            "seeds": {
                "mvs": seeds.from_mvs,
                "sfm": seeds.from_sfm,
                "rays": seeds.from_rays,
                "rays_without_depth": seeds.rays_without_depth,
            },  # fmt: skip
            "refine": vars(result.refine),
            "resolution": list(result.resolution),
            "seconds_training": result.seconds,
            "lpips_weights": str(lpips_file) if lpips_file is not None else None,
        }

    def summary(self, counts: dict[str, Any]) -> str:
        if not counts.get("trained"):
            return "no splats trained"
        return (
            f"{counts['trained']} splats after {counts['iterations']} steps, "
            f"masked PSNR {counts['holdout_psnr_db']:.2f} dB"
        )
