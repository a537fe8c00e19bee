"""Rendering trainable splats together with frozen context Gaussians for one training view.

The frozen Gaussians never change, so their projection, colour and culling are computed once per view and cached
(:class:`ContextProjection`); each step only the trainable splats are projected (with autograd) and both sets are
composited in one rasterisation so that occlusion between them is exact (the context's own gradients are never
computed). Same conventions and kernels as :func:`fusion.render.render` (backends ``cpu`` and ``reference``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from core.errors import ConfigError
from fusion.render.cpu import rasterize_cpu
from fusion.render.project_cpu import project_splats_cpu
from fusion.render.projection import project_gaussians
from fusion.render.reference import rasterize_reference
from fusion.render.sh import sh_to_colour
from fusion.train.params import ContextGaussians
from fusion.train.views import TrainView, boxes_touch_tiles


@dataclass(frozen=True)
class ContextProjection:
    """The frozen Gaussians that matter for one view (visible and touching an active tile), projected."""

    means2d: torch.Tensor  # (M, 2)
    conics: torch.Tensor  # (M, 3)
    depths: torch.Tensor  # (M,)
    extents: torch.Tensor  # (M, 2)
    opacities: torch.Tensor  # (M,)
    colours: torch.Tensor  # (M, 3)
    index: torch.Tensor  # (M,) int64 rows of the frozen set

    def __len__(self) -> int:
        return int(self.means2d.shape[0])


@dataclass(frozen=True)
class StepRender:
    """A training render: colour (H, W, 3) over the background, alpha (H, W), and the trainable splats'
    projected means (N, 2, gradients retained) and visibility (N,) bool."""

    colour: torch.Tensor
    alpha: torch.Tensor
    means2d: torch.Tensor
    visible: torch.Tensor


def project_context(context: ContextGaussians | None, view: TrainView) -> ContextProjection | None:
    """Project the frozen set into ``view`` once (no gradients), keeping only the Gaussians that can matter."""
    if context is None or len(context) == 0:
        return None
    # The numba kernels (float64 inside, one scalar code path per Gaussian) for either backend, not the float32
    # torch twins: a near-flat surfel's 2D covariance determinant cancels, and the float32 conics were neither
    # accurate nor reproducible from run to run (docs/experiments/2026-11-29-resume-determinism.md).
    with torch.no_grad():
        sp = project_splats_cpu(
            context.means, context.quats, context.log_scales, context.logit_opacities, context.sh_coeffs[:, :1],
            context.sh_coeffs[:, 1:], view.viewmat, view.K, view.width, view.height,
            int(round(context.sh_coeffs.shape[1] ** 0.5)) - 1,
        )  # fmt: skip
        keep = sp.visible
        if view.tile_prefix is not None:
            keep = keep & boxes_touch_tiles(sp.means2d, sp.extents, view.tile_prefix)
        idx = torch.nonzero(keep).squeeze(1)
        return ContextProjection(
            sp.means2d[idx].contiguous(),
            sp.conics[idx].contiguous(),
            sp.depths[idx].contiguous(),
            sp.extents[idx].contiguous(),
            sp.opacities[idx].contiguous(),
            sp.colours[idx].contiguous(),
            idx,
        )


def _project_trainable(
    params: dict[str, torch.Tensor], view: TrainView, sh_degree: int, backend: str
) -> tuple[torch.Tensor, ...]:
    """The trainable splats projected into ``view``: means2d, conics, depths, extents, visible, colours, opacities."""
    if backend == "cpu":
        sp = project_splats_cpu(
            params["means"], params["quats"], params["log_scales"], params["logit_opacities"], params["sh_dc"],
            params["sh_rest"], view.viewmat, view.K, view.width, view.height, sh_degree,
        )  # fmt: skip
        return sp.means2d, sp.conics, sp.depths, sp.extents, sp.visible, sp.colours, sp.opacities
    proj = project_gaussians(
        params["means"], params["quats"], params["log_scales"], view.viewmat, view.K, view.width, view.height
    )
    k = (sh_degree + 1) ** 2
    sh = torch.cat([params["sh_dc"], params["sh_rest"][:, : k - 1]], dim=1)
    colours = sh_to_colour(sh, params["means"] - view.camera_centre, sh_degree)
    opacities = torch.sigmoid(params["logit_opacities"])
    return proj.means2d, proj.conics, proj.depths, proj.extents, proj.visible, colours, opacities


def render_step(
    params: dict[str, torch.Tensor],
    view: TrainView,
    context: ContextProjection | None,
    sh_degree: int,
    background: torch.Tensor,
    backend: str = "cpu",
    loss_pixels_only: bool = False,
) -> StepRender:
    """Render trainable splats (``params`` as in :mod:`fusion.train.params`) plus the cached context into ``view``.

    loss_pixels_only: composite only ``view.render_pixels`` (the pixels the L1 + D-SSIM loss reads; the others get
    the background and no gradient). Exact for that loss, which reads nothing else (the trainer's steps); False
    renders every pixel.
    """
    if backend not in ("cpu", "reference"):
        raise ConfigError(f"training renders with the 'cpu' or 'reference' backend, got {backend!r}")
    means2d, conics, depths, extents, visible, colours, opacities = _project_trainable(params, view, sh_degree, backend)
    if means2d.requires_grad:
        means2d.retain_grad()
    if view.tile_prefix is not None and len(visible):
        visible = visible & boxes_touch_tiles(means2d, extents, view.tile_prefix)
    features = torch.cat([colours, depths[:, None]], dim=1)
    parts = [(means2d, conics, depths, extents, opacities, features, visible)]
    if context is not None and len(context):
        ctx_features = torch.cat([context.colours, context.depths[:, None]], dim=1)
        ones = torch.ones(len(context), dtype=torch.bool)
        parts.append((context.means2d, context.conics, context.depths, context.extents, context.opacities,
                      ctx_features, ones))  # fmt: skip
    if len(parts) == 1:
        m2, con, dep, ext, opa, feat, vis = parts[0]
    else:
        m2, con, dep, ext, opa, feat, vis = (torch.cat(list(x), dim=0) for x in zip(*parts, strict=True))
    pixels = view.render_pixels if loss_pixels_only else None
    image = _rasterize(m2, con, opa, feat, ext, dep, vis, view, pixels, len(means2d), backend)
    alpha = image[..., -1]
    colour = image[..., :3] + (1 - alpha)[..., None] * background
    return StepRender(colour, alpha, means2d, visible)


def _rasterize(
    m2, con, opa, feat, ext, dep, vis, view: TrainView, pixels, n_trainable: int, backend: str
) -> torch.Tensor:  # fmt: skip
    """One rasterisation of the concatenated rows (the first ``n_trainable`` trainable, the rest frozen): the
    (H, W, C + 1) image."""
    if backend == "cpu":
        frozen = np.zeros(len(m2), bool)
        frozen[n_trainable:] = True  # the context: its backward only composites
        return rasterize_cpu(m2, con, opa, feat, ext, dep.detach(), vis, view.width, view.height, pixels=pixels,
                             frozen=frozen)  # fmt: skip
    return rasterize_reference(m2, con, opa, feat, ext, dep.detach(), vis, view.width, view.height, pixels=pixels)
