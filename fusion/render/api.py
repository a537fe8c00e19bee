"""``render()``: one functional entry point over torch tensors for every backend."""

from __future__ import annotations

import torch

from core.errors import ConfigError, DataError
from fusion.render.cpu import rasterize_cpu
from fusion.render.gsplat_backend import gsplat_available, render_gsplat
from fusion.render.project_cpu import project_splats_cpu
from fusion.render.projection import project_gaussians
from fusion.render.reference import rasterize_reference
from fusion.render.sh import sh_to_colour
from fusion.render.types import NEAR_PLANE, TILE_SIZE, Backend, RenderResult


def resolve_backend(backend: Backend | str) -> Backend:
    """The concrete backend for a name: ``auto`` is ``gsplat`` when CUDA and gsplat are available, else ``cpu``."""
    try:
        chosen = Backend(backend)
    except ValueError:
        names = ", ".join(b.value for b in Backend)
        raise ConfigError(f"unknown render backend {backend!r}; choose one of {names}") from None
    if chosen is Backend.AUTO:
        return Backend.GSPLAT if gsplat_available() else Backend.CPU
    return chosen


def _check_inputs(means, quats, log_scales, logit_opacities, sh_coeffs, viewmat, K, width, height) -> int:
    n = means.shape[0] if means.dim() == 2 else -1
    expected = {
        "means": (means, (n, 3)),
        "quats": (quats, (n, 4)),
        "log_scales": (log_scales, (n, 3)),
        "logit_opacities": (logit_opacities, (n,)),
        "viewmat": (viewmat, (4, 4)),
        "K": (K, (3, 3)),
    }
    for name, (tensor, shape) in expected.items():
        if tuple(tensor.shape) != shape:
            raise DataError(f"render: {name} must have shape {shape}, got {tuple(tensor.shape)}")
    if sh_coeffs.dim() != 3 or sh_coeffs.shape[0] != n or sh_coeffs.shape[2] != 3:
        raise DataError(f"render: sh_coeffs must have shape ({n}, K, 3), got {tuple(sh_coeffs.shape)}")
    if sh_coeffs.shape[1] not in (1, 4, 9, 16):
        raise DataError(f"render: sh_coeffs has K={sh_coeffs.shape[1]} coefficients; K must be 1, 4, 9 or 16")
    if width <= 0 or height <= 0:
        raise ConfigError(f"render: image size must be positive, got {width}x{height}")
    return n


def render(
    means: torch.Tensor,
    quats: torch.Tensor,
    log_scales: torch.Tensor,
    logit_opacities: torch.Tensor,
    sh_coeffs: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    *,
    sh_degree: int | None = None,
    background: torch.Tensor | None = None,
    backend: Backend | str = Backend.AUTO,
    near_plane: float = NEAR_PLANE,
    tile_size: int = TILE_SIZE,
) -> RenderResult:
    """Render N Gaussians into one pinhole camera, differentiably.

    Parameters
    ----------
    means: (N, 3) positions in the frame ``viewmat`` maps from (metres; keep it local, float32 or float64).
    quats: (N, 4) rotations (w, x, y, z), not necessarily normalised.
    log_scales: (N, 3) natural log of σ per axis (metres).
    logit_opacities: (N,) logit of opacity.
    sh_coeffs: (N, K, 3) SH coefficients, DC first, K in {1, 4, 9, 16}.
    viewmat: (4, 4) world-to-camera matrix (OpenCV axes).
    K: (3, 3) pinhole intrinsics in pixels, COLMAP convention (pixel centres at +0.5).
    width, height: image size in pixels.
    sh_degree: SH degree to evaluate (default: the highest K allows).
    background: (3,) RGB blended behind the Gaussians (default black).
    backend: ``auto``, ``reference``, ``cpu`` or ``gsplat`` (see :class:`Backend`).
    near_plane: Gaussians with camera z below this are culled (metres).
    tile_size: tile edge in pixels for binning (the ``cpu`` kernels are compiled for 16 only). Images do not
        depend on it: the 3σ cut is per pixel.

    Returns a :class:`RenderResult`; gradients flow to means, quats, log_scales, logit_opacities and sh_coeffs.
    Computation runs in the dtype of ``means`` (float32 normally, float64 for gradient checks).
    """
    _check_inputs(means, quats, log_scales, logit_opacities, sh_coeffs, viewmat, K, width, height)
    max_degree = int(round(sh_coeffs.shape[1] ** 0.5)) - 1
    degree = max_degree if sh_degree is None else int(sh_degree)
    if not 0 <= degree <= max_degree:
        raise ConfigError(f"render: sh_degree {degree} needs {(degree + 1) ** 2} coefficients, got {max_degree + 1}²")
    dtype = means.dtype
    bg = torch.zeros(3, dtype=dtype) if background is None else torch.as_tensor(background, dtype=dtype).reshape(3)
    viewmat = viewmat.to(dtype)
    K = K.to(dtype)
    chosen = resolve_backend(backend)
    if chosen is Backend.GSPLAT:
        return render_gsplat(
            means, quats, log_scales, logit_opacities, sh_coeffs, viewmat, K, width, height,
            degree, bg, near_plane, tile_size,
        )  # fmt: skip

    if means.device.type != "cpu":
        raise ConfigError(f"render: backend {chosen.value!r} runs on CPU tensors, got {means.device}; use 'gsplat'")
    inputs = (means, quats, log_scales, logit_opacities, sh_coeffs, viewmat, K, width, height, degree)
    raster = _rasterize_cpu if chosen is Backend.CPU else _rasterize_reference
    image, means2d, depths, extents, visible = raster(*inputs, near_plane, tile_size)
    alpha = image[..., -1]
    colour = image[..., :3] + (1 - alpha)[..., None] * bg
    depth = image[..., 3] / alpha.clamp_min(1e-10)
    radii = torch.where(visible[:, None], torch.ceil(extents), torch.zeros_like(extents))
    return RenderResult(
        colour=colour,
        alpha=alpha,
        depth=depth,
        means2d=means2d,
        radii=radii.to(torch.int32),
        visible=visible,
        depths=depths,
        backend=chosen,
    )


_Raster = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]
"""(H, W, 5) image (premultiplied RGB, alpha-weighted z, alpha: the last channel), and per Gaussian the (N, 2) pixel
means, (N,) camera z (metres), (N, 2) pixel extents and (N,) bool visible."""


def _rasterize_cpu(
    means, quats, log_scales, logit_opacities, sh_coeffs, viewmat, K, width, height, degree, near_plane, tile_size
) -> _Raster:  # fmt: skip
    """The ``cpu`` backend: numba projection with SH evaluation, then the numba tile rasteriser."""
    sp = project_splats_cpu(
        means, quats, log_scales, logit_opacities, sh_coeffs[:, :1], sh_coeffs[:, 1:], viewmat, K, width, height,
        degree, near_plane=near_plane,
    )  # fmt: skip
    means2d, depths, extents, visible = sp.means2d, sp.depths, sp.extents, sp.visible
    features = torch.cat([sp.colours, depths[:, None]], dim=1)  # (N, 4): RGB, z; alpha is appended
    raster = (means2d, sp.conics, sp.opacities)
    image = rasterize_cpu(*raster, features, extents, depths, visible, width, height, tile_size)
    return image, means2d, depths, extents, visible


def _rasterize_reference(
    means, quats, log_scales, logit_opacities, sh_coeffs, viewmat, K, width, height, degree, near_plane, tile_size
) -> _Raster:  # fmt: skip
    """The ``reference`` backend: plain torch projection, SH evaluation and rasterisation (autograd gradients)."""
    proj = project_gaussians(means, quats, log_scales, viewmat, K, width, height, near_plane=near_plane)
    centre = -viewmat[:3, :3].T @ viewmat[:3, 3]
    colours = sh_to_colour(sh_coeffs, means - centre, degree)
    features = torch.cat([colours, proj.depths[:, None]], dim=1)
    opacities = torch.sigmoid(logit_opacities)
    means2d, depths, extents, visible = proj.means2d, proj.depths, proj.extents, proj.visible
    raster = (means2d, proj.conics, opacities)
    image = rasterize_reference(*raster, features, extents, depths, visible, width, height, tile_size)
    return image, means2d, depths, extents, visible
