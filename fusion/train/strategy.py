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


@dataclass
class MCMCState:
    """State of :class:`MCMCStrategy`: the initial count and the run totals (no per-Gaussian accumulators)."""

    n_initial: int
    totals: RefineCounts = field(default_factory=RefineCounts)


def _relocation(opacity: torch.Tensor, log_scales: torch.Tensor, ratio: torch.Tensor, max_ratio: int = 51):
    """Opacity and log-scales of a Gaussian split into ``ratio`` copies that render like the original (MCMC paper,
    Eq. 9; gsplat's ``compute_relocation``): α' = 1 − (1 − α)^(1/r),
    σ' = α σ / Σᵢ₌₁..ᵣ Σₖ₌₀..ᵢ₋₁ C(i−1, k) (−1)^k α'^(k+1) / √(k+1)."""
    r = ratio.clamp(1, max_ratio).to(opacity.dtype)
    new_opacity = 1.0 - (1.0 - opacity).clamp_min(1e-12) ** (1.0 / r)
    denom = torch.zeros_like(opacity)
    for i in range(1, int(r.max()) + 1 if len(r) else 1):
        term = torch.zeros_like(opacity)
        for k in range(i):
            term = term + math.comb(i - 1, k) * (-1) ** k / math.sqrt(k + 1) * new_opacity ** (k + 1)
        denom = denom + torch.where(r >= i, term, torch.zeros_like(term))
    scale_factor = (opacity / denom.clamp_min(1e-12)).clamp(1e-6, 1.0)
    return new_opacity.clamp(1e-4, 1 - 1e-4), log_scales + torch.log(scale_factor)[:, None]


@dataclass(frozen=True)
class MCMCStrategy:
    """MCMC-style densification (3DGS as MCMC; gsplat's ``MCMCStrategy``): every ``refine_every`` steps inside the
    window, dead Gaussians (α < ``min_opacity``) are moved onto live ones sampled by opacity, then the count grows by
    ``grow_rate`` (never above ``cap``) by splitting sampled Gaussians the same way; after every step positions get
    noise scaled by (1 − α) and the covariance (``noise_lr`` × the current means learning rate). Needs its opacity and
    scale L1 regularisers (:meth:`regularisation`). The count never exceeds ``cap``."""

    cap: int = 100_000
    refine_start: int = 500
    refine_stop: int = 25_000
    refine_every: int = 100
    min_opacity: float = 0.005
    grow_rate: float = 0.05
    noise_lr: float = 5e5
    opacity_reg: float = 0.01
    scale_reg: float = 0.01

    def __post_init__(self) -> None:
        if self.cap < 1 or self.refine_every < 1 or self.grow_rate < 0:
            raise ConfigError("cap and refine_every must be >= 1 and grow_rate >= 0")

    def initial_state(self, n: int) -> MCMCState:
        return MCMCState(n)

    def regularisation(self, params: dict[str, torch.Tensor]) -> torch.Tensor:
        return (
            self.opacity_reg * torch.sigmoid(params["logit_opacities"]).mean()
            + self.scale_reg * params["log_scales"].exp().mean()
        )

    def after_backward(self, state: MCMCState, means2d: torch.Tensor, width: int, height: int, step: int,
                       **_: object) -> None:  # fmt: skip
        return None

    def refine(
        self,
        state: MCMCState,
        params: dict[str, torch.nn.Parameter],
        optimizer: torch.optim.Adam,
        step: int,
        total_steps: int,
        scene_scale: float,
        generator: torch.Generator,
        lr_means: float = 0.0,
        **_: object,
    ) -> RefineCounts:
        counts = RefineCounts()
        if self.refine_start <= step < self.refine_stop and step % self.refine_every == 0 and step > 0:
            counts.relocated = self._relocate(params, optimizer, generator)
            counts.cloned = self._add(params, optimizer, generator)
        if lr_means > 0:
            self._noise(params, lr_means, generator)
        state.totals.add(counts)
        return counts

    def _sample(self, opacity: torch.Tensor, n: int, generator: torch.Generator) -> torch.Tensor:
        return torch.multinomial(opacity.clamp_min(1e-12), n, replacement=True, generator=generator)

    def _split_into(self, params, optimizer, sources: torch.Tensor, targets: torch.Tensor | None) -> None:
        """Copies of ``sources`` (with repeats) go to ``targets`` (rows overwritten) or are appended (None); the
        sources and copies get the relocated opacity and scale, and the copies zeroed Adam moments."""
        opacity = torch.sigmoid(params["logit_opacities"].detach())
        ratio = torch.bincount(sources, minlength=len(opacity))[sources] + 1
        new_op, new_ls = _relocation(opacity[sources], params["log_scales"].detach()[sources], ratio)
        uniq = torch.unique(sources)

        def param_fn(name: str, p: torch.Tensor) -> torch.Tensor:
            p = p.clone()
            if name == "logit_opacities":
                p[sources] = torch.logit(new_op)
            elif name == "log_scales":
                p[sources] = new_ls
            copy = p[sources]
            if targets is None:
                return torch.cat([p, copy])
            p[targets] = copy
            return p

        def state_fn(_: str, s: torch.Tensor) -> torch.Tensor:
            s = s.clone()
            s[uniq] = 0
            if targets is None:
                return torch.cat([s, torch.zeros_like(s[sources])])
            s[targets] = 0
            return s

        update_parameters(params, optimizer, param_fn, state_fn)

    def _relocate(self, params, optimizer, generator) -> int:
        opacity = torch.sigmoid(params["logit_opacities"].detach())
        dead = torch.nonzero(opacity <= self.min_opacity).squeeze(1)
        alive = torch.nonzero(opacity > self.min_opacity).squeeze(1)
        if len(dead) == 0 or len(alive) == 0:
            return 0
        sources = alive[self._sample(opacity[alive], len(dead), generator)]
        self._split_into(params, optimizer, sources, dead)
        return int(len(dead))

    def _add(self, params, optimizer, generator) -> int:
        n = params["means"].shape[0]
        target = min(self.cap, int(math.floor(n * (1.0 + self.grow_rate))))
        extra = max(0, target - n)
        if extra == 0:
            return 0
        opacity = torch.sigmoid(params["logit_opacities"].detach())
        self._split_into(params, optimizer, self._sample(opacity, extra, generator), None)
        return extra

    def _noise(self, params, lr_means: float, generator: torch.Generator) -> None:
        with torch.no_grad():
            opacity = torch.sigmoid(params["logit_opacities"])
            R = quat_to_rotmat(params["quats"])
            s2 = params["log_scales"].exp() ** 2
            cov = torch.einsum("nij,nj,nkj->nik", R, s2, R)
            gate = 1.0 / (1.0 + torch.exp(-100.0 * ((1.0 - opacity) - 0.995)))
            z = torch.randn(params["means"].shape, generator=generator)
            noise = torch.einsum("nij,nj->ni", cov, z) * (gate * self.noise_lr * lr_means)[:, None]
            params["means"].add_(noise)
