"""Evaluation windows and early stopping on held-back pixels.

A seeded ``holdout_fraction`` of each view's mask pixels never enters the loss (:mod:`fusion.train.views`). Over
each evaluation window (whole epochs, :class:`fusion.train.schedule.TrainSchedule`) :class:`EvalWindow` sums the
squared error of the renders on those pixels and the photometric loss; closing the window gives a
:class:`Checkpoint` with the window's hold-out PSNR. :class:`EarlyStop` is the plateau test on that PSNR: stop when
it has not improved by ``min_improvement_db`` for ``patience`` windows in a row, never before ``min_step`` (the
larger of ``min_iterations`` and the end of densification) and never at the last step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from fusion.train.options import TrainOptions
from fusion.train.views import TrainView


@dataclass(frozen=True)
class Checkpoint:
    """Training state at the end of an evaluation window: step, mean loss over the window, hold-out PSNR (dB) of
    the window's renders, trainable count, seconds since the start."""

    step: int
    loss: float
    holdout_psnr: float
    gaussians: int
    seconds: float


@dataclass
class EvalWindow:
    """Sums over the steps of one evaluation window.

    sq_err / n_err: summed squared error (colour units², [0, 1] images) over the hold-out pixel channels rendered
    and their count; loss_sum / n_loss: summed photometric loss and step count.
    """

    sq_err: float = 0.0
    n_err: int = 0
    loss_sum: float = 0.0
    n_loss: int = 0

    def add_holdout(self, colour: torch.Tensor, view: TrainView) -> None:
        """Add the error of a render (H, W, 3) on ``view``'s hold-out pixels (clamped to [0, 1] first)."""
        with torch.no_grad():
            hold = view.holdout_mask
            if bool(hold.any()):
                diff = (colour.detach().clamp(0, 1) - view.image)[hold]
                self.sq_err += float((diff * diff).sum())
                self.n_err += int(diff.numel())

    def add_loss(self, loss: float) -> None:
        """Add one step's photometric loss."""
        self.loss_sum += loss
        self.n_loss += 1

    def holdout_psnr(self) -> float:
        """PSNR (dB) of the window's hold-out pixels (MSE floored at 1e-10); NaN when none was rendered."""
        if not self.n_err:
            return float("nan")
        return -10.0 * math.log10(max(self.sq_err / max(self.n_err, 1), 1e-10))

    def checkpoint(self, step: int, gaussians: int, seconds: float) -> Checkpoint:
        """The window's :class:`Checkpoint` after ``step`` finished steps with ``gaussians`` trainable splats."""
        return Checkpoint(step, self.loss_sum / max(self.n_loss, 1), self.holdout_psnr(), gaussians, seconds)


@dataclass
class EarlyStop:
    """The plateau test on the hold-out PSNR (dB) of successive windows (see the module docstring).

    min_improvement_db: the gain that counts as an improvement. patience: windows without one before stopping.
    min_step: no stop before this many finished steps. last_step: the run's length (no stop there: it ends anyway).
    best / stale: the best PSNR so far and the windows since it improved.
    """

    min_improvement_db: float
    patience: int
    min_step: int
    last_step: int
    best: float = -math.inf
    stale: int = 0

    @classmethod
    def from_options(cls, options: TrainOptions, densifying_until: int) -> EarlyStop:
        """The test of ``options``, never stopping while the strategy densifies (before ``densifying_until``)."""
        return cls(
            options.min_improvement_db,
            options.patience,
            max(options.min_iterations, densifying_until),
            options.iterations,
        )

    def update(self, psnr: float, step: int) -> bool:
        """Record the PSNR of the window that closed after ``step`` finished steps; True = stop now."""
        if psnr > self.best + self.min_improvement_db:
            self.best, self.stale = psnr, 0
        else:
            self.stale += 1
        return self.stale >= self.patience and step >= self.min_step and step < self.last_step
