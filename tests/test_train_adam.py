"""FusedAdam (fusion/train/adam.py) against torch.optim.Adam: same trajectory, same state, same fallbacks."""

from __future__ import annotations

import torch

from fusion.train.adam import FusedAdam
from fusion.train.params import make_optimizer


def _params(seed: int) -> list[torch.nn.Parameter]:
    gen = torch.Generator().manual_seed(seed)
    shapes = [(5000, 3), (5000, 4), (5000,), (5000, 1, 3), (5000, 0, 3), (7, 2)]
    return [torch.nn.Parameter(torch.randn(s, generator=gen)) for s in shapes]


def _run(cls, steps: int = 12, **kw):
    params = _params(0)
    groups = [{"params": [p], "lr": 10.0 ** -(1 + i % 3), "name": str(i)} for i, p in enumerate(params)]
    opt = cls(groups, eps=1e-15, **kw)
    gen = torch.Generator().manual_seed(1)
    for step in range(steps):
        for i, p in enumerate(params):
            # Parameter 5 gets no gradient on odd steps: skipped, its step count stays behind.
            p.grad = None if (i == 5 and step % 2) else torch.randn(p.shape, generator=gen) * (1 + step)
        opt.param_groups[0]["lr"] *= 0.9  # the trainer's schedule changes lr between steps
        opt.step()
    return params, opt


def test_same_trajectory_and_state_as_torch_adam() -> None:
    ref_params, ref_opt = _run(torch.optim.Adam, foreach=True)
    params, opt = _run(FusedAdam, foreach=True)
    for a, b, pa, pb in zip(ref_params, params, ref_opt.param_groups, opt.param_groups, strict=True):
        torch.testing.assert_close(b.detach(), a.detach(), rtol=2e-6, atol=1e-7)
        sa, sb = ref_opt.state[pa["params"][0]], opt.state[pb["params"][0]]
        assert float(sa["step"]) == float(sb["step"]) and sb["step"].dtype == sa["step"].dtype
        # Moments to float32 rounding of their scale (torch's vectorised lerp rounds differently near zero).
        for key in ("exp_avg", "exp_avg_sq"):
            scale = float(sa[key].abs().max()) if sa[key].numel() else 1.0
            torch.testing.assert_close(sb[key], sa[key], rtol=1e-6, atol=1e-6 * scale)
    assert float(opt.state[params[5]]["step"]) == 6.0
    assert float((params[0].detach() - _params(0)[0].detach()).abs().min()) > 0  # every element moved


def test_unsupported_options_fall_back_to_torch() -> None:
    ref_params, _ = _run(torch.optim.Adam, amsgrad=True, weight_decay=0.01)
    params, _ = _run(FusedAdam, amsgrad=True, weight_decay=0.01)
    for a, b in zip(ref_params, params, strict=True):
        torch.testing.assert_close(b.detach(), a.detach(), rtol=1e-6, atol=1e-7)


def test_make_optimizer_is_fused_adam() -> None:
    names = ("means", "quats", "log_scales", "logit_opacities", "sh_dc", "sh_rest")
    params = dict(zip(names, _params(2), strict=False))
    opt = make_optimizer(params, {k: 1e-3 for k in names})
    assert isinstance(opt, FusedAdam) and isinstance(opt, torch.optim.Adam)
    assert [g["name"] for g in opt.param_groups] == list(names)
