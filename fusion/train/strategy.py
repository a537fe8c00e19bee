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

A strategy is a frozen dataclass of hyper-parameters; its mutable state is an explicit :class:`DefaultState`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from core.errors import ConfigError
from fusion.render.projection import quat_to_rotmat
from fusion.train.params import update_parameters


@dataclass
class RefineCounts:
    """What one refinement (or a whole run, summed) did to the trainable set."""

    cloned: int = 0
    split: int = 0
    pruned: int = 0
    relocated: int = 0
    resets: int = 0
    clipped: int = 0  # candidates refused because of the budget

    def add(self, other: RefineCounts) -> None:
        for name in ("cloned", "split", "pruned", "relocated", "resets", "clipped"):
            setattr(self, name, getattr(self, name) + getattr(other, name))


@dataclass
class DefaultState:
    """Per-Gaussian accumulators of :class:`DefaultStrategy` (length N, float32 / int32) and run totals."""

    grad2d: torch.Tensor
    count: torch.Tensor
    n_initial: int
    totals: RefineCounts = field(default_factory=RefineCounts)


def _select(t: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    return t[keep]


@dataclass(frozen=True)
class DefaultStrategy:
    """gsplat-default-like densification with clipped growth (see the module docstring; lengths relative to the
    scene scale, steps in iterations)."""

    cap: int = 100_000
    refine_start: int = 500
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
        return DefaultState(torch.zeros(n), torch.zeros(n, dtype=torch.int32), n)

    def regularisation(self, params: dict[str, torch.Tensor]) -> torch.Tensor:
        """Extra loss terms the strategy needs (none)."""
        return torch.zeros(())

    def after_backward(
        self, state: DefaultState, means2d: torch.Tensor, width: int, height: int, step: int, **_: object
    ) -> None:
        """Accumulate the NDC-scaled screen-space gradient norms of Gaussians that received a gradient."""
        if step >= self.refine_stop or means2d.grad is None:
            return
        g = means2d.grad.detach()
        norm = torch.sqrt((g[:, 0] * (width / 2)) ** 2 + (g[:, 1] * (height / 2)) ** 2)
        touched = norm > 0
        state.grad2d += torch.where(touched, norm, torch.zeros_like(norm))
        state.count += touched.to(torch.int32)

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
            counts.add(self._grow(state, params, optimizer, step, total_steps, scene_scale, generator))
            counts.add(self._prune(state, params, optimizer, step, scene_scale))
            state.grad2d.zero_()
            state.count.zero_()
        if self.reset_every > 0 and step % self.reset_every == 0 and 0 < step < self.refine_stop:
            self._reset_opacity(params, optimizer)
            counts.resets += 1
        state.totals.add(counts)
        return counts

    # -- operations ----------------------------------------------------------------------------
    def _grow(self, state, params, optimizer, step, total_steps, scene_scale, generator) -> RefineCounts:
        counts = RefineCounts()
        n = params["means"].shape[0]
        avg = state.grad2d / state.count.clamp_min(1).to(state.grad2d.dtype)
        candidates = torch.nonzero(avg > self.grow_grad2d).squeeze(1)
        room = max(0, self.budget(state, step, total_steps) - n)
        if len(candidates) > room:
            order = torch.argsort(avg[candidates], descending=True, stable=True)
            counts.clipped = int(len(candidates) - room)
            candidates = candidates[order[:room]]
        if len(candidates) == 0:
            return counts
        big = params["log_scales"].detach()[candidates].exp().amax(dim=1) > self.grow_scale3d * scene_scale
        split_ids = candidates[big]
        clone_ids = candidates[~big]
        if len(clone_ids):
            self._duplicate(state, params, optimizer, clone_ids)
            counts.cloned = int(len(clone_ids))
        if len(split_ids):
            self._split(state, params, optimizer, split_ids, generator)
            counts.split = int(len(split_ids))
        return counts

    def _duplicate(self, state, params, optimizer, ids: torch.Tensor) -> None:
        update_parameters(
            params,
            optimizer,
            lambda _, p: torch.cat([p, p[ids]]),
            lambda _, s: torch.cat([s, torch.zeros_like(s[ids])]),
        )
        state.grad2d = torch.cat([state.grad2d, torch.zeros(len(ids))])
        state.count = torch.cat([state.count, torch.zeros(len(ids), dtype=torch.int32)])

    def _split(self, state, params, optimizer, ids: torch.Tensor, generator: torch.Generator) -> None:
        """Each Gaussian in ids becomes two, centred at samples of itself, with σ / 1.6 (3DGS)."""
        scales = params["log_scales"].detach()[ids].exp()
        R = quat_to_rotmat(params["quats"].detach()[ids])
        noise = torch.randn((2, len(ids), 3), generator=generator) * scales[None]
        offsets = torch.einsum("nij,bnj->bni", R, noise)  # (2, M, 3)
        n = params["means"].shape[0]
        rest = torch.ones(n, dtype=torch.bool)
        rest[ids] = False

        def param_fn(name: str, p: torch.Tensor) -> torch.Tensor:
            if name == "means":
                new = (p[ids][None] + offsets).reshape(-1, 3)
            elif name == "log_scales":
                new = (p[ids] - math.log(1.6)).repeat(2, 1)
            else:
                new = p[ids].repeat(2, *([1] * (p.dim() - 1)))
            return torch.cat([p[rest], new])

        def state_fn(_: str, s: torch.Tensor) -> torch.Tensor:
            return torch.cat([s[rest], torch.zeros((2 * len(ids), *s.shape[1:]), dtype=s.dtype)])

        update_parameters(params, optimizer, param_fn, state_fn)
        state.grad2d = torch.cat([state.grad2d[rest], torch.zeros(2 * len(ids))])
        state.count = torch.cat([state.count[rest], torch.zeros(2 * len(ids), dtype=torch.int32)])

    def _prune(self, state, params, optimizer, step, scene_scale) -> RefineCounts:
        opacity = torch.sigmoid(params["logit_opacities"].detach())
        drop = opacity < self.prune_opa
        if self.reset_every > 0 and step > self.reset_every:
            drop |= params["log_scales"].detach().exp().amax(dim=1) > self.prune_scale3d * scene_scale
        if drop.all():  # keep the strongest one so the set never becomes empty
            drop[torch.argmax(opacity)] = False
        if not drop.any():
            return RefineCounts()
        keep = ~drop
        update_parameters(params, optimizer, lambda _, p: p[keep], lambda _, s: s[keep])
        state.grad2d = state.grad2d[keep]
        state.count = state.count[keep]
        return RefineCounts(pruned=int(drop.sum()))

    def _reset_opacity(self, params, optimizer) -> None:
        ceiling = math.log(2 * self.prune_opa / (1 - 2 * self.prune_opa))

        def param_fn(name: str, p: torch.Tensor) -> torch.Tensor:
            return p.clamp_max(ceiling) if name == "logit_opacities" else p

        def state_fn(key: str, s: torch.Tensor) -> torch.Tensor:
            return s

        update_parameters(params, optimizer, param_fn, state_fn)
        for group in optimizer.param_groups:
            if group["name"] == "logit_opacities":
                st = optimizer.state.get(group["params"][0])
                if st:
                    st["exp_avg"].zero_()
                    st["exp_avg_sq"].zero_()
