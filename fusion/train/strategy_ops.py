"""The tensor operations of the densification strategies (as gsplat's ``strategy/ops.py``).

:mod:`fusion.train.strategy` holds the strategies' hyper-parameters and decides *when* to refine; this module does
the work on the trainable tensors and their Adam moments: accumulate screen-space gradients, duplicate, split,
prune and reset opacities (:class:`fusion.train.strategy.DefaultStrategy`). It is imported on first use, so that
the strategies (and the trainer's options built on them) can be named and configured without loading torch.

Parameters are the leaf tensors of :mod:`fusion.train.params` (training frame, metres); every operation that
changes the set goes through :func:`fusion.train.params.update_parameters` so the Adam moments follow.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import torch

from fusion.render.projection import quat_to_rotmat
from fusion.train.params import update_parameters
from fusion.train.strategy import DefaultState, RefineCounts

if TYPE_CHECKING:
    from fusion.train.strategy import DefaultStrategy


# -- DefaultStrategy ----------------------------------------------------------------------------------------------
def zero_accumulators(n: int) -> DefaultState:
    """A :class:`DefaultState` for ``n`` Gaussians: float32 gradient sums and int32 counts, all zero."""
    return DefaultState(torch.zeros(n), torch.zeros(n, dtype=torch.int32), n)


def no_regularisation() -> torch.Tensor:
    """The 0-d zero loss term of a strategy without regularisers."""
    return torch.zeros(())


def accumulate_grad2d(state: DefaultState, grad: torch.Tensor, width: int, height: int) -> None:
    """Add the NDC-scaled norms of the pixel gradients (N, 2) of the projected means of a ``width`` × ``height``
    view to the Gaussians that received one (norm > 0), and count them."""
    g = grad.detach()
    norm = torch.sqrt((g[:, 0] * (width / 2)) ** 2 + (g[:, 1] * (height / 2)) ** 2)
    touched = norm > 0
    state.grad2d += torch.where(touched, norm, torch.zeros_like(norm))
    state.count += touched.to(torch.int32)


def reset_accumulators(state: DefaultState) -> None:
    """Zero the gradient sums and counts (after a refinement)."""
    state.grad2d.zero_()
    state.count.zero_()


def grow(
    strategy: DefaultStrategy,
    state: DefaultState,
    params: dict[str, torch.nn.Parameter],
    optimizer: torch.optim.Adam,
    step: int,
    total_steps: int,
    scene_scale: float,
    generator: torch.Generator,
) -> RefineCounts:
    """Duplicate (small) or split (large: largest σ > ``grow_scale3d`` × ``scene_scale`` metres) the Gaussians whose
    mean gradient exceeds ``grow_grad2d``, the largest gradients first within the strategy's budget."""
    counts = RefineCounts()
    n = params["means"].shape[0]
    avg = state.grad2d / state.count.clamp_min(1).to(state.grad2d.dtype)
    candidates = torch.nonzero(avg > strategy.grow_grad2d).squeeze(1)
    room = max(0, strategy.budget(state, step, total_steps) - n)
    if len(candidates) > room:
        order = torch.argsort(avg[candidates], descending=True, stable=True)
        counts.clipped = int(len(candidates) - room)
        candidates = candidates[order[:room]]
    if len(candidates) == 0:
        return counts
    big = params["log_scales"].detach()[candidates].exp().amax(dim=1) > strategy.grow_scale3d * scene_scale
    split_ids = candidates[big]
    clone_ids = candidates[~big]
    if len(clone_ids):
        duplicate(state, params, optimizer, clone_ids)
        counts.cloned = int(len(clone_ids))
    if len(split_ids):
        split(state, params, optimizer, split_ids, generator)
        counts.split = int(len(split_ids))
    return counts


def duplicate(
    state: DefaultState, params: dict[str, torch.nn.Parameter], optimizer: torch.optim.Adam, ids: torch.Tensor
) -> None:
    """Append a copy of the Gaussians ``ids`` (int64) with zeroed Adam moments and accumulators."""
    update_parameters(
        params,
        optimizer,
        lambda _, p: torch.cat([p, p[ids]]),
        lambda _, s: torch.cat([s, torch.zeros_like(s[ids])]),
    )
    state.grad2d = torch.cat([state.grad2d, torch.zeros(len(ids))])
    state.count = torch.cat([state.count, torch.zeros(len(ids), dtype=torch.int32)])


def split(
    state: DefaultState,
    params: dict[str, torch.nn.Parameter],
    optimizer: torch.optim.Adam,
    ids: torch.Tensor,
    generator: torch.Generator,
) -> None:
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


def prune(
    strategy: DefaultStrategy,
    state: DefaultState,
    params: dict[str, torch.nn.Parameter],
    optimizer: torch.optim.Adam,
    step: int,
    scene_scale: float,
) -> RefineCounts:
    """Remove the Gaussians with α < ``prune_opa`` and, after the first opacity reset, those whose largest σ
    exceeds ``prune_scale3d`` × ``scene_scale`` metres; the strongest one always stays."""
    opacity = torch.sigmoid(params["logit_opacities"].detach())
    drop = opacity < strategy.prune_opa
    if strategy.reset_every > 0 and step > strategy.reset_every:
        drop |= params["log_scales"].detach().exp().amax(dim=1) > strategy.prune_scale3d * scene_scale
    if drop.all():  # keep the strongest one so the set never becomes empty
        drop[torch.argmax(opacity)] = False
    if not drop.any():
        return RefineCounts()
    keep = ~drop
    update_parameters(params, optimizer, lambda _, p: p[keep], lambda _, s: s[keep])
    state.grad2d = state.grad2d[keep]
    state.count = state.count[keep]
    return RefineCounts(pruned=int(drop.sum()))


def reset_opacity(params: dict[str, torch.nn.Parameter], optimizer: torch.optim.Adam, prune_opa: float) -> None:
    """Clamp every opacity to 2 × ``prune_opa`` and zero the opacities' Adam moments (3DGS's opacity reset)."""
    ceiling = math.log(2 * prune_opa / (1 - 2 * prune_opa))

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
