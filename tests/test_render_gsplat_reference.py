"""Projection and SH against gsplat's own pure-PyTorch implementation (runs on CPU, no CUDA needed).

gsplat is an optional dependency (extra ``cuda``; for these tests ``pip install --no-deps gsplat`` is enough):
the module is skipped when it does not import.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fusion.render.projection import project_gaussians
from fusion.render.sh import sh_to_colour
from fusion.render.synthetic import random_scene

torch_impl = pytest.importorskip("gsplat.cuda._torch_impl", reason="gsplat is not installed (optional, extra 'cuda')")


@pytest.mark.parametrize("posed", [False, True])
def test_means2d_conics_depths_match_gsplat(posed):
    scene = random_scene(500, 64, 48, seed=31, posed=posed, depth_range=(0.5, 8.0), dtype=torch.float64)
    # Some Gaussians far outside the view exercise the Jacobian clamp, some behind the near plane the culling.
    means = scene.means.clone()
    ours = project_gaussians(means, scene.quats, scene.log_scales, scene.viewmat, scene.K, 64, 48)
    covars, _ = torch_impl._quat_scale_to_covar_preci(scene.quats, torch.exp(scene.log_scales), compute_preci=False)
    radii, means2d, depths, conics, _ = torch_impl._fully_fused_projection(
        means, covars, scene.viewmat[None], scene.K[None], 64, 48, eps2d=0.3, near_plane=0.01
    )
    valid = (radii[0] > 0).all(dim=-1) & ours.visible
    assert valid.sum() > 300
    np.testing.assert_allclose(ours.means2d[valid].numpy(), means2d[0][valid].numpy(), rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(ours.conics[valid].numpy(), conics[0][valid].numpy(), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ours.depths.numpy(), depths[0].numpy(), rtol=1e-12)
    # gsplat's box is 3.33σ, ours 3σ: everything we keep, gsplat keeps too.
    assert not (ours.visible & ~(radii[0] > 0).all(dim=-1)).any()


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_matches_gsplat(degree):
    gen = torch.Generator().manual_seed(degree)
    coeffs = torch.randn(300, 16, 3, generator=gen, dtype=torch.float64)
    dirs = torch.randn(300, 3, generator=gen, dtype=torch.float64)
    ours = sh_to_colour(coeffs, dirs, degree)
    theirs = torch.clamp_min(torch_impl._spherical_harmonics(degree, dirs, coeffs) + 0.5, 0.0)
    np.testing.assert_allclose(ours.numpy(), theirs.numpy(), atol=1e-12)
