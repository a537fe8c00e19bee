"""Adam with the update fused into one numba pass per parameter tensor (both cores).

:class:`FusedAdam` is a ``torch.optim.Adam``: same constructor, parameter groups, state layout (``step``,
``exp_avg``, ``exp_avg_sq``) and update formula (``foreach`` variant: lerp of the first moment, bias corrections as
Python scalars), so densification can index and replace moments as before and checkpoints load in either. Only the
plain configuration is fused (float32 contiguous CPU tensors, no AMSGrad, weight decay, maximize, capturable or
differentiable mode); anything else, and a closure, take ``torch.optim.Adam.step``. Written by hand because
``torch.optim.Adam`` makes six passes over the parameters (lerp, mul, addcmul, sqrt, div-add, addcdiv), each a
separate thread-pool dispatch per tensor list, where one pass suffices.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit

from fusion.render.threads import chunk, run_calls


@njit(nogil=True, cache=True)
def _adam_kernel(p, g, m, v, w1, beta2, w2, step_size, bc2_sqrt, eps, start, stop):  # pragma: no cover - numba
    """In place over [start, stop): m ← m + w1 (g − m); v ← β2 v + w2 g²; p ← p − step (m / (√v / bc2 + ε))."""
    for i in range(start, stop):
        gi = g[i]
        mi = m[i] + w1 * (gi - m[i])
        vi = v[i] * beta2 + w2 * (gi * gi)
        m[i] = mi
        v[i] = vi
        p[i] = p[i] - step_size * (mi / (np.sqrt(vi) / bc2_sqrt + eps))


def _fusable(group: dict, p: torch.Tensor) -> bool:
    plain = not (
        group.get("amsgrad", False)
        or group.get("maximize", False)
        or group.get("weight_decay", 0.0) != 0.0
        or group.get("capturable", False)
        or group.get("differentiable", False)
        or group.get("fused", False)
        or isinstance(group.get("lr"), torch.Tensor)
    )
    g = p.grad
    return (
        plain
        and p.device.type == "cpu"
        and p.dtype == torch.float32
        and p.is_contiguous()
        and g is not None
        and not g.is_sparse
        and g.dtype == torch.float32
    )


def _state_ok(state: dict | None) -> bool:
    """A fresh state, or moments the kernel can update in place (float32, contiguous)."""
    if not state:
        return True
    moments = [state.get("exp_avg"), state.get("exp_avg_sq")]
    return all(isinstance(m, torch.Tensor) and m.dtype == torch.float32 and m.is_contiguous() for m in moments)


class FusedAdam(torch.optim.Adam):
    """``torch.optim.Adam`` whose plain float32 CPU step is one fused numba pass (see the module docstring)."""

    @torch.no_grad()
    def step(self, closure=None):  # type: ignore[override]
        if closure is not None or not all(
            _fusable(group, p) and _state_ok(self.state.get(p))
            for group in self.param_groups
            for p in group["params"]
            if p.grad is not None
        ):
            return super().step(closure)
        work = []
        f32 = np.float32
        for group in self.param_groups:
            beta1, beta2 = group["betas"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state[p]
                if len(state) == 0:
                    state["step"] = torch.zeros((), dtype=torch.float32)
                    state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                    state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                state["step"] += 1
                step = float(state["step"])
                bias1 = 1 - beta1**step
                bias2_sqrt = (1 - beta2**step) ** 0.5
                arrays = [
                    t.detach().numpy().reshape(-1)
                    for t in (p, p.grad.contiguous(), state["exp_avg"], state["exp_avg_sq"])
                ]
                scalars = (
                    f32(1 - beta1),
                    f32(beta2),
                    f32(1 - beta2),
                    f32(group["lr"] / bias1),
                    f32(bias2_sqrt),
                    f32(group["eps"]),
                )
                work.append((arrays, scalars))
        if not work:
            return None

        def run(th: int, n: int) -> None:
            for arrays, scalars in work:
                start, stop = chunk(arrays[0].shape[0], th, n)
                if stop > start:
                    _adam_kernel(*arrays, *scalars, start, stop)

        run_calls(run, "adam")
        return None
