"""Densification and pruning under a hard Gaussian budget.

:class:`DefaultStrategy` follows gsplat's ``DefaultStrategy`` (3DGS): every ``refine_every`` steps inside
[``refine_start``, ``refine_stop``), Gaussians whose mean screen-space gradient (NDC units: pixel gradient × W/2,
× H/2, averaged over the steps in which they received a gradient) exceeds ``grow_grad2d`` are duplicated when
small (largest σ ≤ ``grow_scale3d`` × scene scale) and split in two smaller ones otherwise; low-opacity and (after
the first opacity reset) over-large Gaussians are pruned; opacities are reset every ``reset_every`` steps. Unlike
gsplat the growth is clipped (GSH-Net-style coarse-to-fine): the count may rise from the initial one to ``cap``
linearly over the first ``budget_ramp`` share of the refinement window, and when more Gaussians qualify than the
budget allows, the ones with the largest gradients win. The count never exceeds ``cap``.

Statistics are only gathered from Gaussians that received a gradient, i.e. touched a loss pixel: in masked
training, seeing a Gaussian outside the mask does not dilute its mean gradient.

A strategy is a frozen dataclass of hyper-parameters; its mutable state is an explicit :class:`DefaultState`. What
the trainer asks of a strategy is the :class:`Strategy` protocol: ``initial_state``, an
extra loss term (``regularisation``), statistics after each backward pass (``after_backward``) and the refinement
after each optimiser step (``refine``), as in gsplat's ``Strategy`` (``step_pre_backward`` / ``step_post_backward``).

This module decides *when* and *how much*; the tensor work is in :mod:`fusion.train.strategy_ops` (gsplat's
``strategy/ops.py``), imported on first use: the strategies can be named, built and checked without torch (the
pipeline's configuration reads :class:`fusion.train.options.TrainOptions` that way).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import ModuleType
from typing import TYPE_CHECKING, Protocol

from core.errors import ConfigError

if TYPE_CHECKING:
    import torch


@dataclass
class RefineCounts:
    """What one refinement (or a whole run, summed) did to the trainable set."""

    cloned: int = 0
    split: int = 0
    pruned: int = 0
    resets: int = 0
    clipped: int = 0  # candidates refused because of the budget

    def add(self, other: RefineCounts) -> None:
        for name in ("cloned", "split", "pruned", "resets", "clipped"):
            setattr(self, name, getattr(self, name) + getattr(other, name))


@dataclass
class DefaultState:
    """Per-Gaussian accumulators of :class:`DefaultStrategy` (length N, float32 / int32) and run totals."""

    grad2d: torch.Tensor
    count: torch.Tensor
    n_initial: int
    totals: RefineCounts = field(default_factory=RefineCounts)


class StrategyState(Protocol):
    """The running state of a strategy: at least the initial count and the run totals."""

    n_initial: int
    totals: RefineCounts


class Strategy(Protocol):
    """The interface between the trainer and a densification strategy (:class:`DefaultStrategy`; a test's toy
    strategy). Steps count iterations; ``refine`` gets the 1-based count of finished steps."""

    @property
    def cap(self) -> int:
        """The largest trainable count the strategy ever allows."""
        ...

    @property
    def refine_start(self) -> int: ...

    @property
    def refine_stop(self) -> int: ...

    def initial_state(self, n: int) -> StrategyState:
        """A fresh state for ``n`` initial Gaussians."""
        ...

    def regularisation(self, params: dict[str, torch.Tensor]) -> torch.Tensor:
        """A 0-d loss term the strategy adds to every step's loss (a zero tensor when none)."""
        ...

    def after_backward(self, state, means2d: torch.Tensor, width: int, height: int, step: int) -> None:
        """Gather statistics from the gradients of the projected means (N, 2, px) of a ``width`` × ``height`` view."""
        ...

    def refine(
        self,
        state,
        params: dict[str, torch.nn.Parameter],
        optimizer: torch.optim.Adam,
        step: int,
        total_steps: int,
        scene_scale: float,
        generator: torch.Generator,
    ) -> RefineCounts:
        """Change the trainable set (and its Adam moments) after the optimiser step; ``scene_scale`` in metres."""
        ...


def _ops() -> ModuleType:
    """:mod:`fusion.train.strategy_ops` (torch), imported on first use."""
    from fusion.train import strategy_ops

    return strategy_ops


@dataclass(frozen=True)
class DefaultStrategy:
    """gsplat-default-like densification with clipped growth (see the module docstring; lengths relative to the
    scene scale, steps in iterations)."""

    cap: int = 60_000
    refine_start: int = 100
    refine_stop: int = 15_000
    refine_every: int = 100
    grow_grad2d: float = 2e-4
    grow_scale3d: float = 0.01
    prune_opa: float = 0.005
    prune_scale3d: float = 0.1
    reset_every: int = 3000
    budget_ramp: float = 0.5

    def __post_init__(self) -> None:
        if self.cap < 1:
            raise ConfigError(f"cap must be >= 1 Gaussian, got {self.cap}")
        if self.refine_every < 1 or self.refine_start < 0 or self.refine_stop < self.refine_start:
            raise ConfigError("need refine_every >= 1 and 0 <= refine_start <= refine_stop")
        if not 0.0 < self.budget_ramp <= 1.0:
            raise ConfigError(f"budget_ramp must lie in (0, 1], got {self.budget_ramp}")

    def initial_state(self, n: int) -> DefaultState:
        return _ops().zero_accumulators(n)

    def regularisation(self, params: dict[str, torch.Tensor]) -> torch.Tensor:
        """Extra loss terms the strategy needs (none)."""
        return _ops().no_regularisation()

    def after_backward(
        self, state: DefaultState, means2d: torch.Tensor, width: int, height: int, step: int, **_: object
    ) -> None:
        """Accumulate the NDC-scaled screen-space gradient norms of Gaussians that received a gradient."""
        if step >= self.refine_stop or means2d.grad is None:
            return
        _ops().accumulate_grad2d(state, means2d.grad, width, height)

    def budget(self, state: DefaultState, step: int, total_steps: int) -> int:
        """The largest count allowed after the refinement at ``step`` (clipped coarse-to-fine growth)."""
        stop = min(self.refine_stop, total_steps)
        span = max(1.0, self.budget_ramp * (stop - self.refine_start))
        share = min(1.0, max(0.0, (step - self.refine_start) / span))
        start = min(state.n_initial, self.cap)
        return int(start + share * (self.cap - start))

    def refine(
        self,
        state: DefaultState,
        params: dict[str, torch.nn.Parameter],
        optimizer: torch.optim.Adam,
        step: int,
        total_steps: int,
        scene_scale: float,
        generator: torch.Generator,
        **_: object,
    ) -> RefineCounts:
        """Grow, prune and reset as the schedule says at ``step`` (1-based count of finished steps)."""
        counts = RefineCounts()
        if self.refine_start <= step < self.refine_stop and step % self.refine_every == 0 and step > 0:
            ops = _ops()
            counts.add(ops.grow(self, state, params, optimizer, step, total_steps, scene_scale, generator))
            counts.add(ops.prune(self, state, params, optimizer, step, scene_scale))
            ops.reset_accumulators(state)
        if self.reset_every > 0 and step % self.reset_every == 0 and 0 < step < self.refine_stop:
            _ops().reset_opacity(params, optimizer, self.prune_opa)
            counts.resets += 1
        state.totals.add(counts)
        return counts
