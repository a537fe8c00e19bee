"""Which view each training step fits: the :class:`ViewSampler`.

Outside the hard-view mining window every view is visited once per epoch in a seeded permutation (a new one
drawn at the start of each epoch, i.e. at steps that are multiples of the view count); inside it, views are drawn
with :meth:`fusion.train.options.HardViewOptions.probabilities` of their running losses. The sampler owns the
run's NumPy generator after initialisation (the same generator that subsampled the initial set, so the draws stay
in one seeded sequence), the current permutation, the per-view running losses and the visit counts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fusion.train.options import HardViewOptions


@dataclass
class ViewSampler:
    """Per-step view choice (see the module docstring).

    rng: the run's seeded generator. hard: mining options (None = plain epochs). order: (V,) int64, the current
    epoch's permutation. running: (V,) float64 running photometric loss per view (NaN = not seen; only kept with
    mining). counts: (V,) int64 steps spent on each view.
    """

    rng: np.random.Generator
    hard: HardViewOptions | None
    order: np.ndarray
    running: np.ndarray
    counts: np.ndarray

    @classmethod
    def start(cls, n_views: int, rng: np.random.Generator, hard: HardViewOptions | None) -> ViewSampler:
        """A sampler over ``n_views`` views; draws the first epoch's permutation from ``rng``."""
        return cls(rng, hard, rng.permutation(n_views), np.full(n_views, np.nan), np.zeros(n_views, np.int64))

    @property
    def n_views(self) -> int:
        return len(self.counts)

    def next(self, step: int, mining: bool) -> int:
        """The view index for step ``step`` (0-based); ``mining``: the step lies in the mining window."""
        if self.hard is not None and mining:
            vi = int(self.rng.choice(self.n_views, p=self.hard.probabilities(self.running)))
        else:
            pos = step % self.n_views
            if pos == 0 and step > 0:
                self.order = self.rng.permutation(self.n_views)
            vi = int(self.order[pos])
        self.counts[vi] += 1
        return vi

    def record_loss(self, view: int, loss: float) -> None:
        """Fold a step's photometric loss on ``view`` into its running loss (only with mining options)."""
        if self.hard is None:
            return
        ema, old = self.hard.ema, self.running[view]
        self.running[view] = loss if not np.isfinite(old) else (1 - ema) * old + ema * loss
