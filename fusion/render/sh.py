"""Real spherical harmonics up to degree 3, evaluated per view direction (graphdeco's basis and signs).

Coefficients are (N, K, 3) with K = (degree + 1)², DC first (gsplat's ``colors`` layout). The colour of a
Gaussian seen along unit direction d (from the camera centre to the mean) is ``max(Σₖ Yₖ(d) cₖ + 0.5, 0)``.
"""

from __future__ import annotations

import torch

from fusion.render.sh_basis import SH_C0, SH_C1, SH_C2, SH_C3, sh_basis_into

__all__ = ["SH_C0", "SH_C1", "SH_C2", "SH_C3", "sh_basis", "sh_to_colour"]


def sh_basis(degree: int, dirs: torch.Tensor) -> torch.Tensor:
    """SH basis values (N, (degree+1)²) for unit directions ``dirs`` (N, 3) (:mod:`fusion.render.sh_basis`)."""
    if not 0 <= degree <= 3:
        raise ValueError(f"SH degree must be 0..3, got {degree}")
    x, y, z = dirs.unbind(-1)
    basis: list = [None] * (degree + 1) ** 2
    sh_basis_into(degree, x, y, z, basis)
    basis[0] = torch.full_like(x, SH_C0)
    return torch.stack(basis, dim=-1)


def sh_to_colour(sh_coeffs: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """RGB (N, 3) from SH coefficients (N, K, 3) seen along directions (N, 3) (normalised here), degree ≤ 3.

    Only the first (degree+1)² coefficients are used; +0.5 offset and clamp at 0 as in 3DGS.
    """
    k = (degree + 1) ** 2
    unit = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    basis = sh_basis(degree, unit)
    rgb = (basis[:, :, None] * sh_coeffs[:, :k, :]).sum(dim=1)
    return (rgb + 0.5).clamp_min(0.0)
