"""Which view each training step fits: the :class:`ViewSampler`.

Every view is visited once per epoch in a seeded permutation (a new one drawn at the start of each epoch, i.e. at
steps that are multiples of the view count). The sampler owns the run's NumPy generator after initialisation (the
same generator that subsampled the initial set, so the draws stay in one seeded sequence), the current permutation
and the visit counts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class ViewSampler:
    """Per-step view choice (see the module docstring).

    rng: the run's seeded generator. order: (V,) int64, the current epoch's permutation. counts: (V,) int64 steps
    spent on each view.
    """

    rng: np.random.Generator
    order: np.ndarray
    counts: np.ndarray

    @classmethod
    def start(cls, n_views: int, rng: np.random.Generator) -> ViewSampler:
        """A sampler over ``n_views`` views; draws the first epoch's permutation from ``rng``."""
        return cls(rng, rng.permutation(n_views), np.zeros(n_views, np.int64))

    @property
    def n_views(self) -> int:
        return len(self.counts)

    def next(self, step: int) -> int:
        """The view index for step ``step`` (0-based)."""
        pos = step % self.n_views
        if pos == 0 and step > 0:
            self.order = self.rng.permutation(self.n_views)
        vi = int(self.order[pos])
        self.counts[vi] += 1
        return vi
