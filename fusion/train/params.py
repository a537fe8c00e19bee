"""Trainable splat parameters, the frozen context, and the Adam bookkeeping densification needs.

Parameters are leaf tensors named as in :data:`PARAM_NAMES`, in the training frame (metres, float32):

- ``means`` (N, 3); ``quats`` (N, 4) (w, x, y, z), unnormalised; ``log_scales`` (N, 3) log σ;
- ``logit_opacities`` (N,); ``sh_dc`` (N, 1, 3); ``sh_rest`` (N, K − 1, 3) with K = (max degree + 1)².

The optimiser is a ``torch.optim.Adam`` (its fused subclass :class:`fusion.train.adam.FusedAdam`) with one
parameter group per name (``group["name"]``) so that densification can index, extend and replace a parameter
together with its Adam moments (as gsplat's strategies do), and the learning rate of ``means`` can follow its
schedule.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from core.gaussians import GaussianSet, num_sh_bases
from fusion.spz_format import SPZ_F_DC_LIMIT, SPZ_LOG_SCALE_RANGE
from fusion.train.adam import FusedAdam

PARAM_NAMES = ("means", "quats", "log_scales", "logit_opacities", "sh_dc", "sh_rest")

VIEWER_LOG_SCALE_RANGE = SPZ_LOG_SCALE_RANGE
"""log σ every trained Gaussian keeps (σ from 45 µm to 379 m): the range of SPZ's scale code, the narrowest of the
viewer formats the merge writes (compressed PLY and SOG scale per chunk or table; the PLY holds floats), so that no
export clips a trained scale. A σ under 45 µm is far below a pixel's footprint in any photo survey."""
VIEWER_F_DC_LIMIT = SPZ_F_DC_LIMIT
"""|f_dc| every trained Gaussian keeps (colour −0.44 … 1.44 before the SH rest): SPZ's colour code's range."""


def clamp_to_viewer_range(params: dict[str, torch.Tensor]) -> None:
    """Project the trainable ``log_scales`` and ``sh_dc`` onto what the viewer formats hold, in place
    (:data:`VIEWER_LOG_SCALE_RANGE`, :data:`VIEWER_F_DC_LIMIT`): taken after every optimiser step, so the fit
    works within the bounds instead of having an export clip its result."""
    with torch.no_grad():
        params["log_scales"].clamp_(*VIEWER_LOG_SCALE_RANGE)
        params["sh_dc"].clamp_(-VIEWER_F_DC_LIMIT, VIEWER_F_DC_LIMIT)


@dataclass
class ContextGaussians:
    """Frozen Gaussians rendered with the trainable ones (no gradient, never densified); same layout, float32."""

    means: torch.Tensor
    quats: torch.Tensor
    log_scales: torch.Tensor
    logit_opacities: torch.Tensor
    sh_coeffs: torch.Tensor  # (M, K, 3), DC first

    def __len__(self) -> int:
        return int(self.means.shape[0])

    def subset(self, keep: torch.Tensor) -> ContextGaussians:
        return ContextGaussians(
            self.means[keep], self.quats[keep], self.log_scales[keep], self.logit_opacities[keep], self.sh_coeffs[keep]
        )


def tensors_from_set(gs: GaussianSet, centre: np.ndarray, sh_degree: int) -> dict[str, torch.Tensor]:
    """The set's parameters as float32 tensors in the training frame (local means minus ``centre``, float64 shift).

    SH is truncated or zero-padded to ``sh_degree``.
    """
    gs = gs.with_sh_degree(sh_degree)
    return {
        "means": torch.from_numpy((gs.means - np.asarray(centre, np.float64)).astype(np.float32)),
        "quats": torch.from_numpy(gs.quats.copy()),
        "log_scales": torch.from_numpy(gs.log_scales.copy()),
        "logit_opacities": torch.from_numpy(gs.logit_opacities.copy()),
        "sh_dc": torch.from_numpy(gs.sh_dc[:, None, :].copy()),
        "sh_rest": torch.from_numpy(np.ascontiguousarray(gs.sh_rest)),
    }


def context_from_set(gs: GaussianSet, centre: np.ndarray, sh_degree: int) -> ContextGaussians:
    t = tensors_from_set(gs, centre, sh_degree)
    return ContextGaussians(
        t["means"], t["quats"], t["log_scales"], t["logit_opacities"], torch.cat([t["sh_dc"], t["sh_rest"]], dim=1)
    )


def set_from_tensors(
    params: dict[str, torch.Tensor], centre: np.ndarray, origin: np.ndarray, sh_degree: int | None = None
) -> GaussianSet:
    """A :class:`GaussianSet` (local frame of ``origin``) from training-frame parameters; SH cut to ``sh_degree``.
    The set owns copies: the optimiser updates the parameters in place, so a view would change with them."""
    p = {k: v.detach().cpu().numpy().copy() for k, v in params.items()}
    gs = GaussianSet(
        p["means"].astype(np.float64) + np.asarray(centre, np.float64),
        p["log_scales"],
        p["quats"],
        p["logit_opacities"],
        p["sh_dc"][:, 0, :],
        p["sh_rest"],
        np.asarray(origin, np.float64),
    )
    return gs if sh_degree is None else gs.with_sh_degree(sh_degree)


def make_parameters(tensors: dict[str, torch.Tensor]) -> dict[str, torch.nn.Parameter]:
    """Leaf parameters (float32 copies) for every name in :data:`PARAM_NAMES`."""
    return {k: torch.nn.Parameter(tensors[k].detach().clone().float().contiguous()) for k in PARAM_NAMES}


def make_optimizer(params: dict[str, torch.nn.Parameter], lrs: dict[str, float]) -> torch.optim.Adam:
    """Adam (eps 1e-15 as in 3DGS) with one group per parameter name: a :class:`fusion.train.adam.FusedAdam`
    (a ``torch.optim.Adam`` whose step is one fused numba pass on both cores)."""
    groups = [{"params": [params[k]], "lr": lrs[k], "name": k} for k in PARAM_NAMES]
    return FusedAdam(groups, eps=1e-15, foreach=True)


def update_parameters(
    params: dict[str, torch.nn.Parameter],
    optimizer: torch.optim.Adam,
    param_fn: Callable[[str, torch.Tensor], torch.Tensor],
    state_fn: Callable[[str, torch.Tensor], torch.Tensor],
) -> None:
    """Replace every parameter by ``param_fn(name, old)`` and its Adam moments by ``state_fn(key, old_moment)``.

    Both functions act on the first (Gaussian) dimension: index, concatenate, or both.
    """
    for group in optimizer.param_groups:
        name = group["name"]
        old = group["params"][0]
        new = torch.nn.Parameter(param_fn(name, old.detach()).contiguous())
        state = optimizer.state.pop(old, None)
        if state is not None:
            for key in ("exp_avg", "exp_avg_sq"):
                if key in state:
                    state[key] = state_fn(key, state[key]).contiguous()
            optimizer.state[new] = state
        group["params"][0] = new
        params[name] = new


def empty_tensors(sh_degree: int) -> dict[str, torch.Tensor]:
    """Zero-length parameter tensors for an SH degree."""
    k = num_sh_bases(sh_degree)
    return {
        "means": torch.zeros((0, 3)),
        "quats": torch.zeros((0, 4)),
        "log_scales": torch.zeros((0, 3)),
        "logit_opacities": torch.zeros(0),
        "sh_dc": torch.zeros((0, 1, 3)),
        "sh_rest": torch.zeros((0, k - 1, 3)),
    }
