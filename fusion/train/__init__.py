"""fusion.train: splats trained inside masks next to frozen MVS Gaussians (and the whole-scene baseline).

- :func:`train_splats` / :class:`TrainOptions` / :class:`TrainResult` — the trainer (:mod:`fusion.train.trainer`).
- :class:`DefaultStrategy` / :class:`MCMCStrategy` — capped densification (:mod:`fusion.train.strategy`).
- :func:`masked_photometric_loss` — 0.8 · L1 + 0.2 · (1 − SSIM) over mask pixels (:mod:`fusion.train.loss`).
"""

from fusion.train.loss import masked_photometric_loss, ssim_map
from fusion.train.priors import PriorOptions
from fusion.train.strategy import DefaultStrategy, MCMCStrategy, RefineCounts
from fusion.train.trainer import (
    HardViewOptions,
    StepInfo,
    TrainOptions,
    TrainResult,
    scene_scale,
    splat_normals,
    train_splats,
)

__all__ = [
    "DefaultStrategy",
    "HardViewOptions",
    "PriorOptions",
    "MCMCStrategy",
    "RefineCounts",
    "StepInfo",
    "TrainOptions",
    "TrainResult",
    "masked_photometric_loss",
    "scene_scale",
    "splat_normals",
    "ssim_map",
    "train_splats",
]
