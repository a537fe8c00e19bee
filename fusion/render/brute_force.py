"""An obvious per-pixel renderer in float64 numpy: the oracle for tests on tiny scenes (no torch, no tiles).

Written independently of the backends (quaternions through scipy, covariance inverse through numpy, every
Gaussian tested against every pixel; only the SH basis is shared, :mod:`fusion.render.sh_basis`, itself tested
against scipy), following the same conventions (see :mod:`fusion.render.types`).
Cost is O(N · H · W); use it for a few hundred Gaussians on images of a few thousand pixels.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from fusion.render.sh_basis import sh_basis_into
from fusion.render.types import ALPHA_MAX, ALPHA_MIN, EPS2D, EXTENT_SIGMA, NEAR_PLANE, T_MIN


def _sh_rgb(coeffs: np.ndarray, d: np.ndarray, degree: int) -> np.ndarray:
    """RGB (3,) from coefficients (K, 3) along unit direction d (3,), graphdeco's real SH basis
    (:mod:`fusion.render.sh_basis`, tested there against scipy's spherical harmonics)."""
    basis = np.empty((degree + 1) ** 2)
    sh_basis_into(degree, float(d[0]), float(d[1]), float(d[2]), basis)
    rgb = basis @ coeffs[: len(basis)]
    return np.maximum(rgb + 0.5, 0.0)


def render_brute_force(
    means: np.ndarray,
    quats_wxyz: np.ndarray,
    log_scales: np.ndarray,
    logit_opacities: np.ndarray,
    sh_coeffs: np.ndarray,
    viewmat: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    sh_degree: int | None = None,
    background: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Colour (H, W, 3), alpha (H, W) and expected depth (H, W), float64, from pre-activation parameters.

    Arguments as :func:`fusion.render.render` (numpy arrays): means (N, 3), quats (N, 4) wxyz, log σ (N, 3),
    logit opacities (N,), SH (N, K, 3), 4×4 world-to-camera, 3×3 intrinsics with pixel centres at +0.5.
    """
    means = np.asarray(means, np.float64)
    n = len(means)
    degree = int(round(np.sqrt(sh_coeffs.shape[1]))) - 1 if sh_degree is None else sh_degree
    bg = np.zeros(3) if background is None else np.asarray(background, np.float64)
    R_view, t_view = viewmat[:3, :3], viewmat[:3, 3]
    centre = -R_view.T @ t_view
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    q = np.asarray(quats_wxyz, np.float64)
    rot = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy wants (x, y, z, w) and normalises
    sigma = np.exp(np.asarray(log_scales, np.float64))
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(logit_opacities, np.float64)))

    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    T = np.ones((height, width))
    colour = np.zeros((height, width, 3))
    depth_sum = np.zeros((height, width))
    active = np.ones((height, width), bool)

    cam = means @ R_view.T + t_view
    for i in np.argsort(cam[:, 2], kind="stable"):
        x, y, z = cam[i]
        if z <= NEAR_PLANE:
            continue
        cov_cam = R_view @ rot[i] @ np.diag(sigma[i] ** 2) @ rot[i].T @ R_view.T
        lim_x = (width - cx) / fx + 0.15 * width / fx, cx / fx + 0.15 * width / fx
        lim_y = (height - cy) / fy + 0.15 * height / fy, cy / fy + 0.15 * height / fy
        tx = z * np.clip(x / z, -lim_x[1], lim_x[0])
        ty = z * np.clip(y / z, -lim_y[1], lim_y[0])
        J = np.array([[fx / z, 0, -fx * tx / z**2], [0, fy / z, -fy * ty / z**2]])
        cov2d = J @ cov_cam @ J.T + EPS2D * np.eye(2)
        inv = np.linalg.inv(cov2d)
        mean2d = np.array([fx * x / z + cx, fy * y / z + cy])
        d = np.stack([cols - mean2d[0], rows - mean2d[1]], axis=-1)
        maha2 = np.einsum("hwi,ij,hwj->hw", d, inv, d)
        alpha = np.minimum(ALPHA_MAX, opacity[i] * np.exp(-0.5 * maha2))
        hit = active & (maha2 <= EXTENT_SIGMA**2) & (alpha >= ALPHA_MIN)
        stop = hit & (T * (1 - alpha) < T_MIN)
        active &= ~stop
        hit &= ~stop
        rgb = _sh_rgb(sh_coeffs[i], (means[i] - centre) / np.linalg.norm(means[i] - centre), degree)
        w = np.where(hit, alpha * T, 0.0)
        colour += w[..., None] * rgb
        depth_sum += w * z
        T = np.where(hit, T * (1 - alpha), T)
    alpha_img = 1.0 - T
    if n == 0:
        alpha_img[:] = 0.0
    depth = np.where(alpha_img > 0, depth_sum / np.maximum(alpha_img, 1e-10), 0.0)
    return colour + (1 - alpha_img)[..., None] * bg, alpha_img, depth
