"""EWA projection of 3D Gaussians to screen-space 2D Gaussians (PyTorch, autograd), shared by the
``reference`` and ``cpu`` backends.

Conventions: ``viewmat`` is the 4×4 world-to-camera matrix (OpenCV axes: x right, y down, z forward), ``K`` the
3×3 pinhole intrinsics with COLMAP's pixel convention (pixel (col, row) has its centre at (col + 0.5, row + 0.5)),
quaternions are (w, x, y, z) and need not be normalised.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from fusion.render.types import EPS2D, EXTENT_SIGMA, NEAR_PLANE


@dataclass(frozen=True)
class Projection:
    """Screen-space Gaussians of one camera (N rows, dtype of the inputs).

    means2d: (N, 2) pixel coordinates of the projected means.
    conics: (N, 3) (a, b, c) of the inverse dilated 2D covariance: the Gaussian's exponent at pixel offset
        (dx, dy) from its mean is ``power = -0.5 (a dx² + c dy²) - b dx dy``.
    depths: (N,) camera-frame z of the means (metres).
    extents: (N, 2) half-widths in pixels of the axis-aligned box around the 3σ ellipse (detached).
    visible: (N,) bool, z > near plane and box overlapping the image (detached).
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    extents: torch.Tensor
    visible: torch.Tensor


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (N, 3, 3) from quaternions (N, 4) in (w, x, y, z) order, normalised here."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]  # fmt: skip
    return torch.stack(rows, dim=-1).reshape(-1, 3, 3)


def project_gaussians(
    means: torch.Tensor,
    quats: torch.Tensor,
    log_scales: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    *,
    near_plane: float = NEAR_PLANE,
    eps2d: float = EPS2D,
) -> Projection:
    """Project Gaussians (means (N, 3) in the frame of ``viewmat``, quats (N, 4) wxyz, log σ (N, 3)) to the image.

    The 3D covariance ``R S Sᵀ Rᵀ`` is rotated into the camera and mapped through the Jacobian of the pinhole
    projection at the mean (EWA splatting); ``eps2d`` px² is added to its diagonal. As in graphdeco and gsplat,
    the mean used for the Jacobian is clamped to 1.3× the field of view so that Gaussians far outside the image do
    not blow up. Culled Gaussians keep finite (meaningless) values so that gradients stay finite.
    """
    R = viewmat[:3, :3]
    t = viewmat[:3, 3]
    p_cam = means @ R.T + t
    x, y, z = p_cam.unbind(-1)
    in_front = z > near_plane
    z_safe = torch.where(in_front, z, torch.ones_like(z))

    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    means2d = torch.stack([fx * x / z_safe + cx, fy * y / z_safe + cy], dim=-1)

    # Jacobian of (fx x/z + cx, fy y/z + cy) at the mean, with x/z and y/z clamped to 1.3× the image.
    lim_x_pos = (width - cx) / fx + 0.3 * (0.5 * width / fx)
    lim_x_neg = cx / fx + 0.3 * (0.5 * width / fx)
    lim_y_pos = (height - cy) / fy + 0.3 * (0.5 * height / fy)
    lim_y_neg = cy / fy + 0.3 * (0.5 * height / fy)
    tx = z_safe * torch.clamp(x / z_safe, -lim_x_neg, lim_x_pos)
    ty = z_safe * torch.clamp(y / z_safe, -lim_y_neg, lim_y_pos)
    # Jacobian rows: (fx/z, 0, -fx tx/z²) and (0, fy/z, -fy ty/z²).
    j00, j02 = fx / z_safe, -fx * tx / (z_safe * z_safe)
    j11, j12 = fy / z_safe, -fy * ty / (z_safe * z_safe)

    # Σ_cam = M Mᵀ with M = R_view R_q S (one 3×3 × 3×3N product); Σ_2d = (J M)(J M)ᵀ + eps2d I, written out
    # element-wise because batched 3×3 matmuls are slow on CPU.
    M = torch.einsum("ij,njk->nik", R, quat_to_rotmat(quats)) * torch.exp(log_scales)[:, None, :]
    jm0 = j00[:, None] * M[:, 0, :] + j02[:, None] * M[:, 2, :]
    jm1 = j11[:, None] * M[:, 1, :] + j12[:, None] * M[:, 2, :]
    s_xx = (jm0 * jm0).sum(-1) + eps2d
    s_xy = (jm0 * jm1).sum(-1)
    s_yy = (jm1 * jm1).sum(-1) + eps2d
    det = (s_xx * s_yy - s_xy * s_xy).clamp_min(1e-12)
    conics = torch.stack([s_yy / det, -s_xy / det, s_xx / det], dim=-1)

    with torch.no_grad():
        extents = EXTENT_SIGMA * torch.stack([s_xx, s_yy], dim=-1).sqrt()
        m2 = means2d.detach()
        overlaps = (
            (m2[:, 0] + extents[:, 0] > 0)
            & (m2[:, 0] - extents[:, 0] < width)
            & (m2[:, 1] + extents[:, 1] > 0)
            & (m2[:, 1] - extents[:, 1] < height)
        )
        visible = in_front & overlaps & torch.isfinite(m2).all(dim=-1)
    return Projection(means2d, conics, z, extents, visible)
