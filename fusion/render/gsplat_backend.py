"""The ``gsplat`` backend: gsplat's CUDA rasteriser, imported lazily and probed at run time (extra ``cuda``)."""

from __future__ import annotations

import functools

import torch

from core.errors import ConfigError
from fusion.render.types import EPS2D, Backend, RenderResult


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
