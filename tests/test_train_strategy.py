"""Capped densification: growth clipped to the budget, largest gradients first, split/clone/prune/reset rules."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from core.errors import ConfigError
from fusion.train.params import PARAM_NAMES, make_optimizer, make_parameters
from fusion.train.strategy import DefaultStrategy


def params_of(n: int, sigma: float = 0.001, opacity: float = 0.5, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    tensors = {
        "means": torch.randn((n, 3), generator=g),
        "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        "log_scales": torch.full((n, 3), math.log(sigma)),
        "logit_opacities": torch.full((n,), math.log(opacity / (1 - opacity))),
        "sh_dc": torch.randn((n, 1, 3), generator=g),
        "sh_rest": torch.zeros((n, 3, 3)),
    }
    params = make_parameters(tensors)
    opt = make_optimizer(params, {k: 1e-3 for k in PARAM_NAMES})
    # one step so that Adam has moments to carry along
    sum(p.sum() for p in params.values()).backward()
    opt.step()
    opt.zero_grad()
    return params, opt


def fake_gradients(strategy, state, grads: np.ndarray) -> None:
    state.grad2d = torch.tensor(grads, dtype=torch.float32)
    state.count = torch.ones(len(grads), dtype=torch.int32)


def test_growth_never_exceeds_the_cap_and_prefers_large_gradients() -> None:
    n, cap = 100, 130
    params, opt = params_of(n)
    s = DefaultStrategy(cap=cap, refine_start=0, refine_every=10, refine_stop=1000, reset_every=0, budget_ramp=0.01)
    state = s.initial_state(n)
    grads = np.linspace(0, 1e-3, n)  # 80 % of them above the threshold
    fake_gradients(s, state, grads)
    counts = s.refine(state, params, opt, step=10, total_steps=1000, scene_scale=1.0, generator=torch.Generator())
    assert params["means"].shape[0] == cap
    assert counts.cloned == 30 and counts.split == 0 and counts.clipped == 80 - 30
    # the duplicated ones are the 30 with the largest gradients: their copies sit at the end
    copies = params["means"][n:].detach().numpy()
    top = params["means"][n - 30 : n].detach().numpy()
    np.testing.assert_array_equal(copies[np.argsort(copies[:, 0])], top[np.argsort(top[:, 0])])
    for group in opt.param_groups:  # Adam state follows every parameter
        p = group["params"][0]
        assert p is params[group["name"]] and opt.state[p]["exp_avg"].shape == p.shape


def test_budget_ramps_from_the_initial_count_to_the_cap() -> None:
    s = DefaultStrategy(cap=1000, refine_start=100, refine_stop=1100, budget_ramp=0.5)
    state = s.initial_state(200)
    assert s.budget(state, 100, 10_000) == 200
    assert s.budget(state, 350, 10_000) == 600
    assert s.budget(state, 600, 10_000) == 1000 and s.budget(state, 5000, 10_000) == 1000


def test_large_gaussians_split_in_two_smaller_ones() -> None:
    n = 10
    params, opt = params_of(n, sigma=0.2)
    s = DefaultStrategy(cap=100, refine_start=0, refine_every=1, reset_every=0, budget_ramp=0.01, grow_scale3d=0.01)
    state = s.initial_state(n)
    fake_gradients(s, state, np.array([1.0] * 3 + [0.0] * 7))
    before = params["log_scales"][:3].exp().detach().numpy()
    old_means = params["means"][:3, 0].detach().numpy().copy()
    counts = s.refine(state, params, opt, step=1, total_steps=100, scene_scale=1.0, generator=torch.Generator())
    assert counts.split == 3 and params["means"].shape[0] == n + 3
    new_sigma = params["log_scales"][-6:].exp().detach().numpy()
    np.testing.assert_allclose(new_sigma, np.concatenate([before, before]) / 1.6, rtol=1e-5)
    assert not np.isin(params["means"].detach().numpy()[:, 0], old_means).any()  # the originals are gone


def test_low_opacity_is_pruned_and_reset_caps_opacity() -> None:
    n = 20
    params, opt = params_of(n, opacity=0.5)
    with torch.no_grad():
        params["logit_opacities"][:5] = -10.0
    s = DefaultStrategy(cap=100, refine_start=0, refine_every=1, reset_every=2, grow_grad2d=1e9)
    state = s.initial_state(n)
    counts = s.refine(state, params, opt, step=1, total_steps=100, scene_scale=1.0, generator=torch.Generator())
    assert counts.pruned == 5 and params["means"].shape[0] == 15
    counts = s.refine(state, params, opt, step=2, total_steps=100, scene_scale=1.0, generator=torch.Generator())
    assert counts.resets == 1
    assert float(torch.sigmoid(params["logit_opacities"]).max()) == pytest.approx(2 * s.prune_opa, rel=1e-5)


def test_bad_options_are_config_errors() -> None:
    with pytest.raises(ConfigError):
        DefaultStrategy(cap=0)
    with pytest.raises(ConfigError):
        DefaultStrategy(budget_ramp=0.0)
