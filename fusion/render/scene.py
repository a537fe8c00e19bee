"""Rendering a stored :class:`core.GaussianSet` at a COLMAP camera, large-coordinate safe."""

from __future__ import annotations

import warnings

import numpy as np
import torch

from core.cameras import Camera, View
from core.errors import ConfigError
from core.gaussians import GaussianSet
from fusion.render.api import render
from fusion.render.types import Backend, RenderResult


def render_gaussian_set(
    gaussians: GaussianSet,
    camera: Camera,
    view: View,
    *,
    cameras_origin: np.ndarray | None = None,
    background: tuple[float, float, float] | np.ndarray | None = None,
    sh_degree: int | None = None,
    backend: Backend | str = Backend.AUTO,
    ignore_distortion: bool = False,
) -> RenderResult:
    """Render a Gaussian set from one COLMAP view, without gradients; returns tensors (``.to_numpy()`` for arrays).

    ``view`` acts on coordinates relative to ``cameras_origin`` (float64 world coordinates; default: the
    Gaussians' own origin). Means and pose are shifted in float64 so that the camera centre becomes the origin of
    the rendering frame before anything is cast to float32, so UTM-sized coordinates keep sub-millimetre precision.

    Distorted camera models are refused (render and compare against undistorted images) unless
    ``ignore_distortion`` is set, in which case the pinhole part is rendered and a warning says so.
    """
    if camera.model.has_distortion:
        if not ignore_distortion:
            raise ConfigError(
                f"camera {camera.camera_id} uses the distorted model {camera.model.value}; the renderer draws "
                "pinhole images: undistort the images and model first, or pass ignore_distortion=True"
            )
        warnings.warn(
            f"camera {camera.camera_id} ({camera.model.value}): distortion ignored, rendering its pinhole part",
            stacklevel=2,
        )
    origin = gaussians.origin if cameras_origin is None else np.asarray(cameras_origin, np.float64).reshape(3)
    R = view.rotation
    centre_local = view.center  # camera centre relative to ``origin``
    # Rendering frame: world axes, origin at the camera centre -> viewmat = [R | 0].
    means = gaussians.means + (gaussians.origin - origin) - centre_local
    viewmat = np.eye(4)
    viewmat[:3, :3] = R
    with torch.no_grad():
        return render(
            torch.from_numpy(means.astype(np.float32)),
            torch.from_numpy(gaussians.quats),
            torch.from_numpy(gaussians.log_scales),
            torch.from_numpy(gaussians.logit_opacities),
            torch.from_numpy(np.ascontiguousarray(gaussians.sh_coeffs)),
            torch.from_numpy(viewmat.astype(np.float32)),
            torch.from_numpy(camera.K().astype(np.float32)),
            camera.width,
            camera.height,
            sh_degree=sh_degree,
            background=None if background is None else torch.tensor(np.asarray(background, np.float32)),
            backend=backend,
        )
