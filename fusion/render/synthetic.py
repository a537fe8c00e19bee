"""Random Gaussian scenes in front of a pinhole camera, for tests and benchmarks (seeded, deterministic)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class SplatScene:
    """Arguments of :func:`fusion.render.render` for one camera (tensors in ``dtype``).

    means (N, 3), quats (N, 4) wxyz, log_scales (N, 3), logit_opacities (N,), sh_coeffs (N, K, 3),
    viewmat (4, 4) world-to-camera, K (3, 3) pinhole with pixel centres at +0.5, width, height.
    """

    means: torch.Tensor
    quats: torch.Tensor
    log_scales: torch.Tensor
    logit_opacities: torch.Tensor
    sh_coeffs: torch.Tensor
    viewmat: torch.Tensor
    K: torch.Tensor
    width: int
    height: int

    @property
    def params(self) -> tuple[torch.Tensor, ...]:
        """The five differentiable parameter tensors, in :func:`render`'s order."""
        return self.means, self.quats, self.log_scales, self.logit_opacities, self.sh_coeffs

    @property
    def trainable(self) -> dict[str, torch.Tensor]:
        """The parameter tensors under the trainer's names (fusion.train.params), SH split into DC and rest."""
        return {
            "means": self.means,
            "quats": self.quats,
            "log_scales": self.log_scales,
            "logit_opacities": self.logit_opacities,
            "sh_dc": self.sh_coeffs[:, :1],
            "sh_rest": self.sh_coeffs[:, 1:],
        }

    @property
    def camera(self) -> tuple[torch.Tensor, torch.Tensor, int, int]:
        return self.viewmat, self.K, self.width, self.height


def random_scene(
    n: int,
    width: int,
    height: int,
    *,
    seed: int = 0,
    sh_degree: int = 0,
    depth_range: tuple[float, float] = (2.0, 6.0),
    sigma_px: tuple[float, float] = (0.5, 2.5),
    opacity: tuple[float, float] = (0.5, 0.9),
    posed: bool = True,
    dtype: torch.dtype = torch.float32,
) -> SplatScene:
    """N anisotropic Gaussians filling the view at depths ``depth_range`` (m) with image-space σ in ``sigma_px``.

    The scene is generated in the camera frame (focal 0.8·width, centred principal point); with ``posed`` a
    random rigid transform moves it into a world frame and ``viewmat`` is set so the view is unchanged.
    """
    rng = np.random.default_rng(seed)
    f = 0.8 * width
    z = rng.uniform(*depth_range, n)
    u = rng.uniform(-0.1 * width, 1.1 * width, n)
    v = rng.uniform(-0.1 * height, 1.1 * height, n)
    cam = np.stack([(u - width / 2) / f * z, (v - height / 2) / f * z, z], axis=1)
    log_scales = np.log(rng.uniform(*sigma_px, (n, 3)) * z[:, None] / f)
    quats = rng.normal(size=(n, 4))
    logit = np.log(p := rng.uniform(*opacity, n)) - np.log1p(-p)
    sh = np.concatenate(
        [rng.normal(0.0, 0.6, (n, 1, 3)), rng.normal(0.0, 0.25, (n, (sh_degree + 1) ** 2 - 1, 3))], axis=1
    )
    R = Rotation.from_rotvec(rng.normal(0, 0.7, 3)).as_matrix() if posed else np.eye(3)
    t = rng.normal(0, 2.0, 3) if posed else np.zeros(3)
    # cam = R world + t  ->  world = Rᵀ (cam - t); the Gaussians' own rotations move with the frame.
    world = (cam - t) @ R
    rot_w = Rotation.from_matrix(R.T) * Rotation.from_quat(quats[:, [1, 2, 3, 0]])
    quats_w = rot_w.as_quat()[:, [3, 0, 1, 2]] * np.linalg.norm(quats, axis=1, keepdims=True)
    viewmat = np.eye(4)
    viewmat[:3, :3], viewmat[:3, 3] = R, t
    K = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])

    def tt(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a)).to(dtype)

    return SplatScene(tt(world), tt(quats_w), tt(log_scales), tt(logit), tt(sh), tt(viewmat), tt(K), width, height)
