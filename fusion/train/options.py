"""The trainer's configuration: :class:`TrainOptions`, and the seeding options :class:`InitOptions`
(:func:`fusion.train.init.seed_splats`).

Frozen dataclasses of hyper-parameters only (learning rates per step as in 3DGS / gsplat, lengths in metres,
shares of the run in [0, 1]); they are validated on construction and never hold running state. What the options
mean for each step is worked out once per run by :class:`fusion.train.schedule.TrainSchedule`. This module and the
strategies it names (:mod:`fusion.train.strategy`) import no torch: the pipeline's configuration and the command
line can read, write and check the options without loading it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from core.errors import ConfigError
from fusion.train.strategy import DefaultStrategy


@dataclass(frozen=True)
class TrainOptions:
    """Options of :func:`fusion.train.train_splats` (learning rates per step as in 3DGS / gsplat; lengths in metres).

    iterations: maximum number of steps (1000 keep a CPU run of a dozen photos within minutes). downscale: integer
    factor for photos, masks and intrinsics (2 on a CPU: a quarter of the pixels). sh_degree: highest SH degree,
    reached one degree per ``sh_degree_interval`` steps.
    scale_reg: weight of mean(σ) / scene scale (keeps splats small).
    holdout_fraction / eval_every / patience / min_improvement_db / min_iterations: early stopping
    (:mod:`fusion.train.early_stop`).
    refine_until: share of ``iterations`` after which the strategy no longer densifies (its ``refine_stop`` is
    lowered to it; 3DGS: 15 000 of 30 000 steps). Gaussians added late are never fitted: a split at the last step
    replaces each Gaussian by two unfitted halves. Early stopping waits for the end of densification too.
    snapshot_iterations: steps after which a copy of the trainable set is kept. backend: ``cpu`` or ``reference``.
    """

    iterations: int = 1000
    downscale: int = 1
    seed: int = 0
    sh_degree: int = 3
    sh_degree_interval: int = 500
    ssim_lambda: float = 0.2
    lr_means: float = 1.6e-4
    lr_means_final: float = 0.01
    lr_log_scales: float = 5e-3
    lr_quats: float = 1e-3
    lr_opacities: float = 5e-2
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20
    scale_reg: float = 0.0
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    holdout_fraction: float = 0.05
    eval_every: int = 100
    patience: int = 3
    min_improvement_db: float = 0.05
    min_iterations: int = 600
    refine_until: float = 0.5
    snapshot_iterations: tuple[int, ...] = ()
    backend: str = "cpu"
    strategy: DefaultStrategy = field(default_factory=DefaultStrategy)

    def __post_init__(self) -> None:
        if self.iterations < 1:
            raise ConfigError(f"iterations must be >= 1, got {self.iterations}")
        if not 0 <= self.sh_degree <= 3:
            raise ConfigError(f"sh_degree must be 0..3, got {self.sh_degree}")
        if self.sh_degree_interval < 1 or self.eval_every < 1 or self.patience < 1:
            raise ConfigError("sh_degree_interval, eval_every and patience must be >= 1")
        if not 0.0 < self.refine_until <= 1.0:
            raise ConfigError(f"refine_until must lie in (0, 1], got {self.refine_until}")
        if not 0.0 <= self.ssim_lambda <= 1.0:
            raise ConfigError(f"ssim_lambda must lie in [0, 1], got {self.ssim_lambda}")
        if self.backend not in ("cpu", "reference"):
            raise ConfigError(f"backend must be 'cpu' or 'reference', got {self.backend!r}")


@dataclass(frozen=True)
class InitOptions:
    """Options of :func:`seed_splats`.

    rays_per_view: mask pixels sampled per view for ray seeds (0 disables them). band_px: width of the band
    around the mask whose trusted MVS depths are interpolated. min_sfm_views: views in whose masks an SfM point
    must fall. k_scale: neighbours for the initial σ. min_spacing: seeds closer than this (m) to an earlier one are
    dropped (0 keeps all). max_seeds: cap on the total (seeded subsample). initial_opacity: α of every seed.
    """

    rays_per_view: int = 400
    band_px: int = 12
    min_sfm_views: int = 1
    k_scale: int = 3
    min_spacing: float = 0.0
    max_seeds: int = 30_000
    initial_opacity: float = 0.1
    seed: int = 0

    def __post_init__(self) -> None:
        if self.rays_per_view < 0 or self.band_px < 1 or self.k_scale < 1 or self.max_seeds < 1:
            raise ConfigError("rays_per_view >= 0, band_px >= 1, k_scale >= 1 and max_seeds >= 1 are required")
        if not 0.0 < self.initial_opacity < 1.0:
            raise ConfigError(f"initial_opacity must lie in (0, 1), got {self.initial_opacity}")
