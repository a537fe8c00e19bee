"""Geometric losses for flat splats whose rendered depth and normals agree (PGSR / 2DGS style).

Pure functions over torch tensors, differentiable, float32 or float64 (computed in the dtype of the inputs). They
read the geometry outputs of :func:`fusion.render.render` with ``render_geometry=True``
(:class:`fusion.render.types.RenderGeometry`): a rendered depth map (``plane_depth``, ``median_depth`` or the
expected ``depth``), the blended normal map and the splats' log-scales.

Conventions (``shared/DESIGN.md``): camera frame with OpenCV axes (x right, y down, z forward), depths are camera
z in metres, intrinsics ``K`` (3, 3) pinhole with pixel (col, row) centred at (col + 0.5, row + 0.5) (COLMAP),
normals are unit vectors in the camera frame facing the camera (``n · p <= 0`` for a surface point p).
Invalid pixels are masked, never NaN: every function returns finite values and finite gradients.

- :func:`normal_from_depth`: the normal of a depth map, from back-projected neighbours (central differences);
- :func:`depth_normal_consistency`: ``1 − cos`` between the rendered normals and the depth map's normals;
- :func:`flatness_loss`: the smallest scale of each splat (or its ratio to the middle one), PGSR's flatness term;
- :func:`mvs_depth_loss`: masked L1 of log or inverse depth against a trusted MVS depth (the per-pixel form of the
  centre-based ``depth_prior`` of :mod:`fusion.train.priors`, whose :class:`~fusion.train.priors.ViewPrior` gives
  the ``prior_depth`` and ``weight`` it takes).
"""

from __future__ import annotations

from typing import Literal

import torch

_EPS = 1e-12


def pixel_rays(K: torch.Tensor, width: int, height: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """(H, W, 3) rays ``K⁻¹ (col + 0.5, row + 0.5, 1)`` through the pixel centres (z = 1: ``depth · ray`` is the
    camera-frame point of a pixel at z-depth ``depth``). Skew is ignored (as in the renderer's projection)."""
    K = K.to(dtype)
    u = (torch.arange(width, dtype=dtype) + 0.5 - K[0, 2]) / K[0, 0]
    v = (torch.arange(height, dtype=dtype) + 0.5 - K[1, 2]) / K[1, 1]
    return torch.stack(
        [u[None, :].expand(height, width), v[:, None].expand(height, width), torch.ones(height, width, dtype=dtype)],
        dim=-1,
    )


def _safe_normalise(v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit vectors along the last axis and their norms; the norm is clamped (finite gradient at 0)."""
    norm = (v * v).sum(-1).clamp_min(_EPS).sqrt()
    return v / norm[..., None], norm


def normal_from_depth(
    depth: torch.Tensor,
    K: torch.Tensor,
    valid: torch.Tensor | None = None,
    *,
    min_depth: float = 1e-6,
    max_relative_step: float | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Normals of a z-depth map by crossing central differences of its back-projected pixels.

    depth: (H, W) camera z-depth in metres. K: (3, 3) intrinsics of the map's resolution. valid: (H, W) bool,
    the pixels whose depth is meaningful (default: depth > min_depth).
    max_relative_step: when set, pixels whose 4 neighbours differ in depth from theirs by more than this fraction
    are masked (depth edges); None keeps them.

    With P(u, v) = depth · K⁻¹ (u + 0.5, v + 0.5, 1), the normal is ``(P(v+1) − P(v−1)) × (P(u+1) − P(u−1))``
    normalised: in OpenCV axes this faces the camera for any surface the camera sees (it is not flipped, so its
    gradient is smooth). Returns (H, W, 3) unit normals (0 where invalid) and the (H, W) bool validity: the pixel
    and its 4 neighbours valid, not on the image border, and a non-degenerate cross product. Gradients flow to
    ``depth`` through the 4 neighbours (the centre pixel's own depth only enters the validity).
    """
    h, w = depth.shape
    if h < 3 or w < 3:
        return torch.zeros(h, w, 3, dtype=depth.dtype), torch.zeros(h, w, dtype=torch.bool)
    ok = depth.detach() > min_depth
    if valid is not None:
        ok = ok & valid
    d = torch.where(ok, depth, torch.ones_like(depth))  # keeps masked pixels finite, gradients included
    K = K.to(depth.dtype)
    fx, fy = K[0, 0], K[1, 1]
    u = ((torch.arange(w, dtype=depth.dtype) + 0.5 - K[0, 2]) / fx)[None, :]
    v = ((torch.arange(h, dtype=depth.dtype) + 0.5 - K[1, 2]) / fy)[:, None]
    x, y = d * u, d * v  # back-projected points (x, y, d)
    # differences along +u (columns) and +v (rows) at the inner pixels, component by component
    ux, uy, uz = (t[1:-1, 2:] - t[1:-1, :-2] for t in (x, y, d))
    vx, vy, vz = (t[2:, 1:-1] - t[:-2, 1:-1] for t in (x, y, d))
    cross = torch.stack([vy * uz - vz * uy, vz * ux - vx * uz, vx * uy - vy * ux], dim=-1)  # dv × du
    normal, norm = _safe_normalise(cross)
    inner = ok[1:-1, 1:-1] & ok[1:-1, 2:] & ok[1:-1, :-2] & ok[2:, 1:-1] & ok[:-2, 1:-1]
    centre = d.detach()[1:-1, 1:-1]
    # |du × dv| of a fronto-parallel surface is ~4 z² / (fx fy): smaller by 1e6 is degenerate (grazing)
    inner = inner & (norm.detach() > 4e-6 * centre * centre / (fx * fy).abs())
    if max_relative_step is not None:
        dd = d.detach()
        steps = torch.stack([dd[1:-1, 2:], dd[1:-1, :-2], dd[2:, 1:-1], dd[:-2, 1:-1]]) - centre
        inner = inner & ((steps.abs().amax(dim=0) / centre) <= max_relative_step)
    out = torch.nn.functional.pad(normal * inner[..., None], (0, 0, 1, 1, 1, 1))
    return out, torch.nn.functional.pad(inner, (1, 1, 1, 1))


def _masked_mean(values: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Σ w·v / Σ w over the pixels, 0 (keeping the graph) where Σ w = 0."""
    total = weight.sum()
    return (weight * values).sum() / total.clamp_min(_EPS)


def depth_normal_consistency(
    rendered_normal: torch.Tensor, depth_normal: torch.Tensor, weight_mask: torch.Tensor
) -> torch.Tensor:
    """Masked mean of ``1 − cos(rendered_normal, depth_normal)`` (0 = agree, 2 = opposite), a scalar.

    rendered_normal: (H, W, 3) the blended normal map (``RenderGeometry.normal``; premultiplied by alpha, so it is
    normalised here). depth_normal: (H, W, 3) normals of the rendered depth (:func:`normal_from_depth`).
    weight_mask: (H, W) bool or float weights (e.g. the loss pixels × the validity of ``normal_from_depth``);
    pixels where either normal is shorter than 1e-6 get weight 0. Gradients flow into both normal maps (detach
    ``depth_normal`` for PGSR's one-sided variant). Differs from 2DGS, which does not normalise the rendered
    normal and weights by alpha instead.
    """
    a, na = _safe_normalise(rendered_normal)
    b, nb = _safe_normalise(depth_normal)
    weight = weight_mask.to(rendered_normal.dtype) * ((na.detach() > 1e-6) & (nb.detach() > 1e-6))
    return _masked_mean(1.0 - (a * b).sum(-1), weight)


def flatness_loss(log_scales: torch.Tensor, mode: Literal["min", "ratio"] = "min") -> torch.Tensor:
    """PGSR's flatness term over splats: a scalar.

    log_scales: (N, 3) natural log of σ per axis (metres), the trainable parameter.
    ``min``: mean over splats of the smallest σ (metres; PGSR's ``‖min(s₁, s₂, s₃)‖₁``; scale-dependent, so its
    weight should be divided by the scene scale). ``ratio``: mean of σ_min / σ_mid (dimensionless, in (0, 1]; does
    not shrink splats that are already flat at any size). The gradient flows to the smallest axis (and for
    ``ratio`` the middle one) only: which axis that is, is piecewise constant. 0 for N = 0.
    """
    if log_scales.shape[0] == 0:
        return log_scales.sum() * 0.0
    ordered = torch.sort(log_scales, dim=1).values
    if mode == "min":
        return torch.exp(ordered[:, 0]).mean()
    if mode == "ratio":
        return torch.exp(ordered[:, 0] - ordered[:, 1]).mean()
    raise ValueError(f"flatness_loss: mode must be 'min' or 'ratio', got {mode!r}")


def mvs_depth_loss(
    depth: torch.Tensor,
    prior_depth: torch.Tensor,
    weight: torch.Tensor,
    valid: torch.Tensor | None = None,
    *,
    kind: Literal["log", "inverse"] = "log",
    min_depth: float = 1e-6,
) -> torch.Tensor:
    """Masked L1 between a rendered depth map and a trusted MVS depth, a scalar.

    depth: (H, W) rendered z-depth (metres; e.g. ``RenderGeometry.plane_depth``). prior_depth: (H, W) trusted MVS
    z-depth (metres; ``ViewPrior.depth``, 0 where none). weight: (H, W) float weights (``ViewPrior.weight``).
    valid: (H, W) bool validity of ``depth`` (e.g. ``plane_valid``); default depth > min_depth.
    ``log``: ``Σ w |log z − log z_prior| / Σ w`` (relative error, the edge-aware log-L1 of
    :mod:`fusion.train.priors`). ``inverse``: ``Σ w |1/z − 1/z_prior| / Σ w`` (1/m; dominated by near pixels, as
    disparity errors are). Pixels where either depth is <= min_depth or invalid get weight 0.
    """
    ok = (depth.detach() > min_depth) & (prior_depth > min_depth)
    if valid is not None:
        ok = ok & valid
    z = torch.where(ok, depth, torch.ones_like(depth))
    zp = torch.where(ok, prior_depth.to(depth.dtype), torch.ones_like(depth))
    if kind == "log":
        err = (torch.log(z) - torch.log(zp)).abs()
    elif kind == "inverse":
        err = (1.0 / z - 1.0 / zp).abs()
    else:
        raise ValueError(f"mvs_depth_loss: kind must be 'log' or 'inverse', got {kind!r}")
    return _masked_mean(err, weight.to(depth.dtype) * ok)
