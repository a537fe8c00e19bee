"""The ``gsplat`` backend: gsplat's CUDA rasteriser, imported lazily and probed at run time (extra ``cuda``).

Where it differs from the ``cpu`` and ``reference`` backends (gsplat 1.5.3): per-Gaussian alpha is clamped at
:data:`GSPLAT_ALPHA_MAX` (0.999, not 0.99); a Gaussian's footprint is cut by its opacity-aware extent rather than 3σ
(so edges differ slightly in colour); ``RenderResult.means2d`` is a view of the projected means that gsplat
consumes, so it receives no gradient (densification on this backend reads none). How far the two renderers agree,
measured on an H200 with ``bench/bench_gpu_paths.py``: docs/experiments/2026-11-27-gpu-paths.md.
"""

from __future__ import annotations

import functools

import torch

from core.errors import ConfigError
from fusion.render.types import EPS2D, Backend, RenderResult

GSPLAT_ALPHA_MAX = 0.999  # gsplat 1.5's clamp on a Gaussian's alpha at one pixel (ours: types.ALPHA_MAX = 0.99)


@functools.cache
def gsplat_available() -> bool:
    """True when torch sees a CUDA device and ``gsplat.rasterization`` imports."""
    if not torch.cuda.is_available():
        return False
    try:
        from gsplat import rasterization  # noqa: F401
    except Exception:  # a broken or CPU-only gsplat install raises many kinds of errors
        return False
    return True


def render_gsplat(
    means: torch.Tensor,
    quats: torch.Tensor,
    log_scales: torch.Tensor,
    logit_opacities: torch.Tensor,
    sh_coeffs: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    sh_degree: int,
    background: torch.Tensor,
    near_plane: float,
    tile_size: int,
) -> RenderResult:
    """Render with ``gsplat.rasterization`` on CUDA (same arguments as :func:`fusion.render.render`)."""
    if not gsplat_available():
        raise ConfigError("backend 'gsplat' needs a CUDA GPU and the gsplat package (pip install 'hybridsplat[cuda]')")
    from gsplat import rasterization

    if means.shape[0] == 0:  # gsplat's kernels die of a floating-point exception on an empty set (gsplat 1.5.3)
        return _background_only(background, width, height, means.dtype)

    def dev(t: torch.Tensor) -> torch.Tensor:  # gsplat's kernels take float32 CUDA tensors
        return t.to(device="cuda", dtype=torch.float32)

    colours, alphas, meta = rasterization(
        means=dev(means),
        quats=dev(quats),
        scales=torch.exp(dev(log_scales)),
        opacities=torch.sigmoid(dev(logit_opacities)),
        colors=dev(sh_coeffs[:, : (sh_degree + 1) ** 2]),
        viewmats=dev(viewmat)[None],
        Ks=dev(K)[None],
        width=width,
        height=height,
        sh_degree=sh_degree,
        near_plane=near_plane,
        eps2d=EPS2D,
        tile_size=tile_size,
        render_mode="RGB+ED",
        backgrounds=dev(background)[None],
        packed=False,
    )
    radii = meta["radii"][0]
    if radii.dim() == 1:  # gsplat < 1.5 returns one radius per Gaussian
        radii = radii[:, None].expand(-1, 2)
    means2d = meta["means2d"]
    return RenderResult(
        colour=colours[0, ..., :3],
        alpha=alphas[0, ..., 0],
        depth=colours[0, ..., 3],
        means2d=means2d[0] if means2d.dim() == 3 else means2d,
        radii=radii.to(torch.int32),
        visible=(radii > 0).all(dim=-1),
        depths=meta["depths"][0],
        backend=Backend.GSPLAT,
    )


def _background_only(background: torch.Tensor, width: int, height: int, dtype: torch.dtype) -> RenderResult:
    """What every backend returns for no Gaussians: the background, zero alpha and depth, empty per-Gaussian rows."""
    cuda = torch.device("cuda")
    return RenderResult(
        colour=background.to(device=cuda, dtype=dtype).expand(height, width, 3).clone(),
        alpha=torch.zeros((height, width), device=cuda, dtype=dtype),
        depth=torch.zeros((height, width), device=cuda, dtype=dtype),
        means2d=torch.zeros((0, 2), device=cuda, dtype=dtype),
        radii=torch.zeros((0, 2), device=cuda, dtype=torch.int32),
        visible=torch.zeros(0, device=cuda, dtype=torch.bool),
        depths=torch.zeros(0, device=cuda, dtype=dtype),
        backend=Backend.GSPLAT,
    )
