"""When things happen in a training run: the :class:`TrainSchedule`.

It owns every step-dependent decision that follows from :class:`fusion.train.options.TrainOptions` alone: the
learning rates (means: ``lr_means`` × scene scale decaying exponentially to ``lr_means_final`` of it over the run,
as in 3DGS; the other groups constant), the SH degree (one more every ``sh_degree_interval`` steps), the evaluation
windows (whole epochs), the snapshots, and when densification runs (the strategy's ``refine_stop`` lowered to
``refine_until`` of the run). It is a frozen value built once per run; its methods are pure functions of the step.

Steps: ``step`` is the 0-based index of the step being taken; ``done`` the 1-based count of finished steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from fusion.train.options import TrainOptions
from fusion.train.strategy import DefaultStrategy


def initial_learning_rates(options: TrainOptions, scene_scale: float) -> dict[str, float]:
    """Adam learning rate per parameter group at step 0 (means: ``lr_means`` × ``scene_scale`` in metres per step)."""
    return {
        "means": options.lr_means * scene_scale,
        "quats": options.lr_quats,
        "log_scales": options.lr_log_scales,
        "logit_opacities": options.lr_opacities,
        "sh_dc": options.lr_sh_dc,
        "sh_rest": options.lr_sh_rest,
    }


def clip_refinement(strategy: DefaultStrategy, refine_until: float, iterations: int) -> DefaultStrategy:
    """``strategy`` with its ``refine_stop`` lowered to ``int(refine_until × iterations)`` steps (never below its
    ``refine_start``); unchanged when it already stops earlier."""
    last_refine = int(refine_until * iterations)
    if strategy.refine_stop > last_refine:
        return replace(strategy, refine_stop=max(strategy.refine_start, last_refine))
    return strategy


@dataclass(frozen=True)
class TrainSchedule:
    """The step-dependent plan of one run (see the module docstring; steps in iterations).

    lr_means_start: the means' learning rate at step 0 (metres per step). lr_means_decay: its factor per step.
    eval_window: steps per evaluation window (whole epochs of ``n_views``). strategy: the densification strategy
    with its refinement window clipped. densifying_until: the step at which densification ends (0 when it never
    runs).
    """

    iterations: int
    sh_degree: int
    sh_degree_interval: int
    lr_means_start: float
    lr_means_decay: float
    eval_window: int
    snapshot_steps: tuple[int, ...]
    strategy: DefaultStrategy
    densifying_until: int

    @classmethod
    def from_options(cls, options: TrainOptions, scene_scale: float, n_views: int) -> TrainSchedule:
        """The schedule of a run of ``options`` over ``n_views`` (≥ 1) views in a scene of ``scene_scale``
        metres."""
        it = options.iterations
        strategy = clip_refinement(options.strategy, options.refine_until, it)
        return cls(
            iterations=it,
            sh_degree=options.sh_degree,
            sh_degree_interval=options.sh_degree_interval,
            lr_means_start=options.lr_means * scene_scale,
            lr_means_decay=options.lr_means_final ** (1.0 / max(1, it)),
            eval_window=n_views * math.ceil(options.eval_every / n_views),  # whole epochs: comparable windows
            snapshot_steps=tuple(options.snapshot_iterations),
            strategy=strategy,
            densifying_until=strategy.refine_stop if strategy.refine_start < strategy.refine_stop else 0,
        )

    def lr_means(self, step: int) -> float:
        """The means' learning rate of step ``step`` (metres per step): start × decay^step."""
        return self.lr_means_start * self.lr_means_decay**step

    def sh_degree_at(self, step: int) -> int:
        """The SH degree rendered at step ``step``."""
        return min(self.sh_degree, step // self.sh_degree_interval)

    def snapshot_after(self, done: int) -> bool:
        """Whether a snapshot of the trainable set is kept after ``done`` finished steps."""
        return done in self.snapshot_steps

    def evaluate_after(self, done: int) -> bool:
        """Whether an evaluation window closes after ``done`` finished steps (every window and the last step)."""
        return done % self.eval_window == 0 or done == self.iterations
