"""Geometry outputs of the renderer (``render(..., render_geometry=True)``): normals, plane distance and depth,
median depth, for the reference and cpu backends.

Analytic truth: a dense layer of flat Gaussians on a plane renders the plane's normal and depth (every Gaussian
shares the plane's normal n and distance δ, so the blended plane is the plane itself wherever alpha is high: only
the 1/255 and T cuts and float rounding separate them); the median depth of a fronto-parallel layer at z = d is d;
of two layers, the front one's where it is opaque enough (T < 0.5 behind it), the back one's otherwise. Gradients:
float64 ``gradcheck`` of every parameter through every geometry output for both backends, and cpu == reference at
the tolerances of the colour path (``tests/test_render_backends.py``: the cpu kernel's polynomial exp).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from fusion.render import render
from fusion.render.synthetic import random_scene

PARAMS = ["means", "quats", "log_scales", "logit_opacities", "sh_coeffs"]
W, H = 64, 48
K = torch.tensor([[60.0, 0.0, 32.0], [0.0, 60.0, 24.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


def plane_layer(
    normal: np.ndarray, centre: np.ndarray, half: float, spacing: float, opacity: float, thin: float = 1e-3
) -> tuple[torch.Tensor, ...]:
    """Flat Gaussians (camera frame, viewmat = identity) on a square grid of ``spacing`` (m) covering ±half (m) of
    the plane through ``centre`` with unit ``normal``: in-plane σ = spacing, σ along the normal = thin·spacing.
    Returns means, quats, log_scales, logit_opacities, sh_coeffs (float64)."""
    n = normal / np.linalg.norm(normal)
    e1 = np.cross(n, [0.0, 1.0, 0.0] if abs(n[1]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    a = np.arange(-half, half + 1e-9, spacing)
    ga, gb = np.meshgrid(a, a, indexing="ij")
    means = centre + ga.reshape(-1, 1) * e1 + gb.reshape(-1, 1) * e2
    rot = np.stack([e1, e2, np.cross(e1, e2)], axis=1)  # columns: axes; the third is ±n, the thin one
    quat = Rotation.from_matrix(rot).as_quat()[[3, 0, 1, 2]]
    count = len(means)
    log_scales = np.log([spacing, spacing, thin * spacing])
    return (
        torch.from_numpy(means),
        torch.from_numpy(np.tile(quat, (count, 1))),
        torch.from_numpy(np.tile(log_scales, (count, 1))),
        torch.full((count,), float(np.log(opacity / (1 - opacity))), dtype=torch.float64),
        torch.full((count, 1, 3), 0.2, dtype=torch.float64),
    )


def pixel_rays(K: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """(H, W, 3) float64 rays K⁻¹ (col + 0.5, row + 0.5, 1) through the pixel centres (z = 1; no skew)."""
    u = (torch.arange(width, dtype=torch.float64) + 0.5 - K[0, 2]) / K[0, 0]
    v = (torch.arange(height, dtype=torch.float64) + 0.5 - K[1, 2]) / K[1, 1]
    return torch.stack([u[None, :].expand(height, width), v[:, None].expand(height, width),
                        torch.ones(height, width, dtype=torch.float64)], dim=-1)  # fmt: skip


def _render(params: tuple[torch.Tensor, ...], backend: str):
    return render(*params, torch.eye(4, dtype=torch.float64), K, W, H, backend=backend, render_geometry=True)


def _angle_deg(a: torch.Tensor, b: np.ndarray) -> torch.Tensor:
    a = a / a.norm(dim=-1, keepdim=True)
    return torch.rad2deg(torch.arccos((a * torch.from_numpy(b)).sum(-1).clamp(-1, 1)))


@pytest.mark.parametrize("backend", ["reference", "cpu"])
def test_tilted_plane_gives_its_normal_and_depth(backend):
    """A 35°/20° tilted plane of flat Gaussians: rendered normal within 1e-3° of the plane's (facing the camera) and
    plane depth within 1e-6 relative of the ray-plane intersection."""
    rot = Rotation.from_euler("yx", [35, 20], degrees=True).as_matrix()
    normal = rot @ np.array([0.0, 0.0, -1.0])  # facing the camera
    centre = np.array([0.0, 0.0, 3.0])
    res = _render(plane_layer(-normal, centre, 3.5, 0.08, 0.9), backend)  # given the back side: must be flipped
    geo = res.geometry
    inner = res.alpha > 0.99
    inner[:2], inner[-2:], inner[:, :2], inner[:, -2:] = False, False, False, False
    assert int(inner.sum()) > 0.8 * (W - 4) * (H - 4)
    assert float(_angle_deg(geo.normal[inner], normal).max()) < 1e-3
    rays = pixel_rays(K, W, H)
    truth = float(normal @ centre) / (rays @ torch.from_numpy(normal))
    assert bool(geo.plane_valid[inner].all())
    torch.testing.assert_close(geo.plane_depth[inner], truth[inner], rtol=1e-6, atol=0)


@pytest.mark.parametrize("backend", ["reference", "cpu"])
def test_fronto_parallel_plane_median_depth(backend):
    """Median depth of an opaque layer at z = 2.5 is 2.5 wherever alpha > 0.5 (exactly: every centre has z 2.5)."""
    res = _render(plane_layer(np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 2.5]), 2.0, 0.08, 0.9), backend)
    geo = res.geometry
    assert bool((geo.median_valid == (res.alpha > 0.5)).all())
    assert int(geo.median_valid.sum()) == W * H
    torch.testing.assert_close(geo.median_depth, torch.full((H, W), 2.5, dtype=torch.float64), rtol=0, atol=1e-12)


@pytest.mark.parametrize("backend", ["reference", "cpu"])
@pytest.mark.parametrize("front_opacity, expected", [(0.9, 2.0), (0.03, 4.0)], ids=["opaque-front", "faint-front"])
def test_two_layers_median_depth(backend, front_opacity, expected):
    """Layers at z = 2 and 4 (the back one opaque): the median depth is the front one's when the front layer alone
    takes T below 0.5, else the back one's; the expected depth lies in between for the faint front."""
    front = plane_layer(np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 2.0]), 1.5, 0.07, front_opacity)
    back = plane_layer(np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 4.0]), 3.0, 0.12, 0.9)
    params = tuple(torch.cat([a, b]) for a, b in zip(front, back, strict=True))
    res = _render(params, backend)
    geo = res.geometry
    assert bool(geo.median_valid.all())
    torch.testing.assert_close(geo.median_depth, torch.full((H, W), expected, dtype=torch.float64), rtol=0, atol=1e-12)
    if expected == 4.0:
        assert bool(((res.depth > 2.05) & (res.depth < 3.95)).all())


def test_off_by_default_and_same_images_when_on():
    """Without render_geometry the result has no geometry; with it, colour, alpha and depth are unchanged."""
    scene = random_scene(300, 48, 32, seed=5, sh_degree=1)
    for backend in ("reference", "cpu"):
        off = render(*scene.params, *scene.camera, backend=backend)
        on = render(*scene.params, *scene.camera, backend=backend, render_geometry=True)
        assert off.geometry is None and on.geometry is not None
        for name in ("colour", "alpha", "depth"):
            torch.testing.assert_close(getattr(on, name), getattr(off, name), rtol=1e-6, atol=1e-6)
        g = on.geometry
        for t in (g.normal, g.plane_dist, g.plane_depth, g.median_depth):
            assert bool(torch.isfinite(t).all())
        assert bool((g.median_depth[~g.median_valid] == 0).all()) and bool((g.median_id[~g.median_valid] == -1).all())
        assert bool((g.plane_depth[~g.plane_valid] == 0).all())


def _geometry_image(res) -> torch.Tensor:
    g = res.geometry
    parts = [res.colour, res.alpha[..., None], res.depth[..., None], g.normal, g.plane_dist[..., None]]
    parts += [g.plane_depth[..., None], g.median_depth[..., None]]
    return torch.cat(parts, dim=-1)  # (H, W, 11)


@pytest.mark.parametrize("backend", ["reference", "cpu"])
@pytest.mark.parametrize("index", range(len(PARAMS)), ids=PARAMS)
def test_gradcheck_geometry_float64(backend, index):
    """Random projections of the Jacobian of every output, geometry included, against central differences."""
    scene = random_scene(6, 14, 10, seed=21, sh_degree=1, sigma_px=(1.0, 2.5), dtype=torch.float64)
    params = list(scene.params)
    weights = torch.rand(10, 14, 11, generator=torch.Generator().manual_seed(2), dtype=torch.float64)

    def f(x: torch.Tensor) -> torch.Tensor:
        args = params[:index] + [x] + params[index + 1 :]
        res = render(*args, *scene.camera, backend=backend, render_geometry=True)
        return (_geometry_image(res) * weights).sum(dim=-1)

    x = params[index].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(f, (x,), eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)


def test_cpu_equals_reference_geometry_and_gradients():
    """cpu vs reference at 1k Gaussians, float64: geometry images to 1e-5, the same median Gaussians, gradients of
    every parameter through the geometry outputs to 1e-4 norm-relative (the polynomial exp, rel. error < 3e-6)."""
    scene = random_scene(1000, 64, 48, seed=9, sh_degree=1, dtype=torch.float64)
    weights = torch.rand(48, 64, 11, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    out = {}
    for backend in ("reference", "cpu"):
        params = [p.clone().requires_grad_(True) for p in scene.params]
        res = render(*params, *scene.camera, backend=backend, render_geometry=True)
        image = _geometry_image(res)
        (image * weights).sum().backward()
        out[backend] = (res, image.detach(), [p.grad for p in params])
    (ref, ref_img, ref_grads), (cpu, cpu_img, cpu_grads) = out["reference"], out["cpu"]
    assert bool((ref.geometry.median_id == cpu.geometry.median_id).all())
    assert bool((ref.geometry.plane_valid == cpu.geometry.plane_valid).all())
    torch.testing.assert_close(cpu_img, ref_img, rtol=1e-5, atol=1e-5)
    for name, a, b in zip(PARAMS, ref_grads, cpu_grads, strict=True):
        rel = float((a - b).norm() / a.norm())
        assert rel < 1e-4, f"{name}: relative gradient difference {rel:.2e}"


def test_geometry_kernel_matches_colour_kernel_with_pixels_and_frozen():
    """The 8-feature cpu kernels give the 4-feature kernels' image and gradients on the shared channels, with a
    pixel map and frozen Gaussians (float64, to rounding)."""
    from fusion.render.cpu import rasterize_cpu, rasterize_geometry_cpu
    from fusion.render.projection import project_gaussians

    w, h = 40, 32
    scene = random_scene(300, w, h, seed=13, sh_degree=0, sigma_px=(1.0, 4.0), dtype=torch.float64)
    proj = project_gaussians(scene.means, scene.quats, scene.log_scales, scene.viewmat, scene.K, w, h)
    gen = torch.Generator().manual_seed(3)
    features = torch.rand(300, 8, generator=gen, dtype=torch.float64)
    opacities = torch.sigmoid(scene.logit_opacities)
    pixels = np.zeros((h, w), bool)
    pixels[3:25, 5:33] = True
    frozen = (torch.rand(300, generator=gen) < 0.3).numpy()
    weights = torch.rand(h, w, 9, generator=gen, dtype=torch.float64)
    weights[..., 4:8] = 0.0  # the geometry channels carry no loss, so the two passes have the same gradients
    grads = {}
    for name in ("colour", "geometry"):
        feats = features if name == "geometry" else features[:, :4]
        leaves = [t.detach().clone().requires_grad_(True) for t in (proj.means2d, proj.conics, opacities, feats)]
        args = (*leaves, proj.extents, proj.depths, proj.visible, w, h)
        if name == "geometry":
            image, median = rasterize_geometry_cpu(*args, pixels=pixels, frozen=frozen)
            image = torch.cat([image[..., :4], image[..., -1:]], dim=-1)
            assert bool((median[~torch.from_numpy(pixels)] == -1).all()) and int((median >= 0).sum()) > 100
        else:
            image = rasterize_cpu(*args, pixels=pixels, frozen=frozen)
        (image * torch.cat([weights[..., :4], weights[..., -1:]], dim=-1)).sum().backward()
        grads[name] = (image.detach(), [t.grad for t in leaves])
    (img_c, g_c), (img_g, g_g) = grads["colour"], grads["geometry"]
    torch.testing.assert_close(img_g, img_c, rtol=1e-12, atol=1e-12)
    for a, b in zip(g_c[:3], g_g[:3], strict=True):
        torch.testing.assert_close(b, a, rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(g_g[3][:, :4], g_c[3], rtol=1e-9, atol=1e-12)


def test_numba_normals_match_torch_normals_and_gradcheck():
    """gaussian_normals_cpu (numba, hand backward) == gaussian_normals (torch autograd): values and gradients to
    1e-12 in float64, and finite differences of the numba one."""
    from fusion.render.normals_cpu import gaussian_normals_cpu
    from fusion.render.projection import gaussian_normals

    scene = random_scene(200, 32, 24, seed=17, dtype=torch.float64)
    gen = torch.Generator().manual_seed(4)
    wn = torch.randn(200, 3, generator=gen, dtype=torch.float64)
    wd = torch.randn(200, generator=gen, dtype=torch.float64)
    out = []
    for fn in (gaussian_normals, gaussian_normals_cpu):
        means, quats = scene.means.clone().requires_grad_(True), (2.0 * scene.quats).requires_grad_(True)
        normals, plane = fn(means, quats, scene.log_scales, scene.viewmat)
        ((normals * wn).sum() + (plane * wd).sum()).backward()
        out.append((normals.detach(), plane.detach(), means.grad, quats.grad))
    assert float(out[0][1].min()) >= 0.0
    for a, b in zip(*out, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-12, atol=1e-12)
    means, quats = scene.means[:12].clone().requires_grad_(True), scene.quats[:12].clone().requires_grad_(True)

    def f(m: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        normals, plane = gaussian_normals_cpu(m, q, scene.log_scales[:12], scene.viewmat)
        return torch.cat([normals.reshape(-1), plane])

    assert torch.autograd.gradcheck(f, (means, quats))


def test_gsplat_refuses_render_geometry():
    from core.errors import ConfigError

    scene = random_scene(5, 16, 12, seed=1)
    with pytest.raises(ConfigError, match="render_geometry"):
        render(*scene.params, *scene.camera, backend="gsplat", render_geometry=True)
