"""Contract suite for every renderer backend, plus agreement with the brute-force oracle and between backends."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from core.errors import ConfigError, DataError
from fusion.render import Backend, render, render_brute_force
from fusion.render.gsplat_backend import GSPLAT_ALPHA_MAX, gsplat_available
from fusion.render.synthetic import random_scene
from fusion.render.types import ALPHA_MAX

BACKENDS = [
    pytest.param("reference", id="reference"),
    pytest.param("cpu", id="cpu"),
    pytest.param(
        "gsplat",
        id="gsplat",
        marks=[
            pytest.mark.gpu,
            pytest.mark.skipif(not gsplat_available(), reason="gsplat backend needs CUDA and the gsplat package"),
        ],
    ),
]
BG = torch.tensor([0.2, 0.4, 0.6])


def _render(scene, backend, **kw):
    return render(*scene.params, *scene.camera, backend=backend, **kw)


def _cpu(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().double().numpy()


def _single(mean, sigma, opacity, rgb, width=32, height=24, f=40.0, quat=(1.0, 0.0, 0.0, 0.0)):
    """One isotropic Gaussian, identity camera; returns render() arguments."""
    sh = ((torch.tensor(rgb, dtype=torch.float64) - 0.5) / 0.28209479177387814).reshape(1, 1, 3)
    logit = math.log(opacity / (1 - opacity)) if opacity < 1 else 20.0
    return (
        torch.tensor([mean], dtype=torch.float32),
        torch.tensor([quat], dtype=torch.float32),
        torch.full((1, 3), math.log(sigma), dtype=torch.float32),
        torch.tensor([logit], dtype=torch.float32),
        sh.float(),
        torch.eye(4),
        torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]]),
        width,
        height,
    )


# -- contract ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
def test_result_shapes_and_types(backend):
    scene = random_scene(40, 40, 30, seed=1, sh_degree=2)
    res = _render(scene, backend, background=BG)
    assert res.colour.shape == (30, 40, 3) and res.alpha.shape == (30, 40) and res.depth.shape == (30, 40)
    assert res.means2d.shape == (40, 2) and res.radii.shape == (40, 2) and res.visible.shape == (40,)
    assert res.radii.dtype == torch.int32 and res.visible.dtype == torch.bool
    assert res.backend is Backend(backend)
    alpha = _cpu(res.alpha)
    assert np.isfinite(_cpu(res.colour)).all() and (alpha >= 0).all() and (alpha <= 1).all()
    assert ((_cpu(res.radii) > 0).all(axis=1) == _cpu(res.visible).astype(bool)).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_single_gaussian_matches_closed_form(backend):
    """Centre pixel of one isotropic Gaussian: alpha = o·exp(-½ d² / (σ_px² + 0.3)), colour over background."""
    z, sigma, f = 4.0, 0.05, 40.0
    # Mean projected to (16.3, 12.2): offset from the centre of pixel (16, 12) is (-0.2, -0.3) px.
    mean = [(16.3 - 16) / f * z, (12.2 - 12) / f * z, z]
    args = _single(mean, sigma, 0.7, [0.9, 0.2, 0.1], f=f)
    res = render(*args, background=BG, backend=backend)
    var = (f * sigma / z) ** 2 + 0.3
    alpha = 0.7 * math.exp(-0.5 * (0.2**2 + 0.3**2) / var)
    expected = alpha * np.array([0.9, 0.2, 0.1]) + (1 - alpha) * BG.numpy()
    assert _cpu(res.alpha)[12, 16] == pytest.approx(alpha, abs=1e-5)
    np.testing.assert_allclose(_cpu(res.colour)[12, 16], expected, atol=1e-5)
    assert _cpu(res.depth)[12, 16] == pytest.approx(z, rel=1e-5)
    np.testing.assert_allclose(_cpu(res.means2d)[0], [16.3, 12.2], atol=1e-4)
    # Beyond 3σ nothing is drawn: background only.
    reach = 3 * math.sqrt(var)
    far_col = int(16.3 + reach + 1.5)
    assert _cpu(res.alpha)[12, far_col] == 0.0
    np.testing.assert_allclose(_cpu(res.colour)[12, far_col], BG.numpy(), atol=1e-7)


@pytest.mark.parametrize("backend", BACKENDS)
def test_opacity_clamp_and_early_termination(backend):
    """Opaque red (alpha clamps to 0.99), half-transparent green, then opaque blue and white that are not drawn.

    T: 1 -> 0.01 -> ~0.005 -> blue would bring it to ~5e-5 < 1e-4: the pixel stops before blue.
    """
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0], [0.0, 0.0, 4.0], [0.0, 0.0, 5.0]])
    rgb = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]])
    n = len(means)
    f, sigma = 40.0, 1.0  # σ ≥ 8 px: alpha of an opaque Gaussian clamps to 0.99 near its centre
    args = (
        means,
        torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.full((n, 3), math.log(sigma)),
        torch.tensor([20.0, 0.0, 20.0, 20.0]),
        ((rgb - 0.5) / 0.28209479177387814)[:, None, :],
        torch.eye(4),
        torch.tensor([[f, 0, 16], [0, f, 12], [0, 0, 1]]),
        32,
        24,
    )
    res = render(*args, backend=backend)
    # Pixel (15, 11) has its centre (-0.5, -0.5) px from every projected mean.
    var2 = (f * sigma / 3.0) ** 2 + 0.3
    a2 = 0.5 * math.exp(-0.5 * 0.5 / var2)
    top = GSPLAT_ALPHA_MAX if backend == "gsplat" else ALPHA_MAX  # gsplat clamps at 0.999 (measured on an H200)
    np.testing.assert_allclose(_cpu(res.colour)[11, 15], [top, (1 - top) * a2, 0.0], atol=1e-5)
    assert _cpu(res.alpha)[11, 15] == pytest.approx(1 - (1 - top) * (1 - a2), abs=1e-6)
    expected_depth = (top * 2 + (1 - top) * a2 * 3) / (1 - (1 - top) * (1 - a2))
    assert _cpu(res.depth)[11, 15] == pytest.approx(expected_depth, rel=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_empty_and_culled_sets_give_background(backend):
    scene = random_scene(10, 24, 16, seed=2)
    behind = scene.viewmat[:3, :3].T @ (torch.tensor([0.0, 0.0, -1.0]) - scene.viewmat[:3, 3])
    means = behind.expand(10, 3).clone()  # all 1 m behind the camera
    res = render(means, *scene.params[1:], *scene.camera, background=BG, backend=backend)
    assert not _cpu(res.visible).any() and (_cpu(res.radii) == 0).all()
    np.testing.assert_allclose(_cpu(res.colour), np.broadcast_to(BG.numpy(), (16, 24, 3)), atol=1e-7)
    empty = [p[:0] for p in scene.params]
    res = render(*empty, *scene.camera, background=BG, backend=backend)
    assert (_cpu(res.alpha) == 0).all() and (_cpu(res.depth) == 0).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_quaternion_sign_and_norm_do_not_matter(backend):
    scene = random_scene(30, 32, 24, seed=3)
    a = _render(scene, backend).colour
    q = -3.0 * scene.quats
    b = render(scene.means, q, *scene.params[2:], *scene.camera, backend=backend).colour
    np.testing.assert_allclose(_cpu(a), _cpu(b), atol=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_means2d_gradient_for_densification(backend, request):
    if backend == "gsplat":  # seen on an H200 (gsplat 1.5.3): means2d.grad stays None; fails loudly once it works
        request.applymarker(pytest.mark.xfail(strict=True, reason="gsplat: means2d is a view gsplat never reads"))
    scene = random_scene(30, 32, 24, seed=4)
    params = [p.clone().requires_grad_(True) for p in scene.params]
    res = render(*params, *scene.camera, backend=backend)
    res.means2d.retain_grad()
    res.colour.sum().backward()
    g = _cpu(res.means2d.grad)
    vis = _cpu(res.visible).astype(bool)
    assert np.abs(g[vis]).sum() > 0 and (g[~vis] == 0).all()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in params)


@pytest.mark.parametrize("backend", BACKENDS)
def test_deterministic(backend):
    scene = random_scene(200, 48, 32, seed=5, sh_degree=1)
    a, b = _render(scene, backend), _render(scene, backend)
    assert torch.equal(a.colour, b.colour) and torch.equal(a.depth, b.depth)


def test_cpu_threads_do_not_change_results():
    """Each tile belongs to one thread and gradients are summed per intersection, so 1 and 2 threads agree bitwise."""
    import numba

    scene = random_scene(3000, 64, 48, seed=6, sh_degree=1)
    outputs = []
    before = numba.get_num_threads()
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            params = [p.clone().requires_grad_(True) for p in scene.params]
            res = render(*params, *scene.camera, backend="cpu")
            (res.colour.sum() + res.depth.sum()).backward()
            outputs.append([res.colour, res.depth] + [p.grad for p in params])
    finally:
        numba.set_num_threads(before)
    for a, b in zip(*outputs, strict=True):
        assert torch.equal(a, b)


def test_input_errors():
    scene = random_scene(5, 16, 16)
    with pytest.raises(DataError, match="quats"):
        render(scene.means, scene.quats[:, :3], *scene.params[2:], *scene.camera)
    with pytest.raises(DataError, match="K=2"):
        render(*scene.params[:4], torch.zeros(5, 2, 3), *scene.camera)
    with pytest.raises(ConfigError, match="unknown render backend"):
        render(*scene.params, *scene.camera, backend="vulkan")
    with pytest.raises(ConfigError, match="sh_degree"):
        render(*scene.params, *scene.camera, sh_degree=2)
    if not gsplat_available():
        with pytest.raises(ConfigError, match="CUDA"):
            render(*scene.params, *scene.camera, backend="gsplat")


def test_auto_picks_cpu_without_cuda():
    if gsplat_available():
        pytest.skip("CUDA and gsplat present: auto picks gsplat")
    scene = random_scene(5, 16, 16)
    assert render(*scene.params, *scene.camera).backend is Backend.CPU


# -- independent truth ------------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("sh_degree", [0, 1, 3])
def test_matches_brute_force(backend, sh_degree):
    """Images to 1e-4 against the float64 per-pixel oracle (float32 renders: ~1e-6 rounding per composite)."""
    scene = random_scene(80, 40, 30, seed=10 + sh_degree, sh_degree=sh_degree, opacity=(0.3, 0.99))
    res = _render(scene, backend, background=BG)
    colour, alpha, depth = render_brute_force(
        *[p.double().numpy() for p in scene.params],
        scene.viewmat.double().numpy(),
        scene.K.double().numpy(),
        scene.width,
        scene.height,
        background=BG.double().numpy(),
    )
    assert alpha.mean() > 0.3  # the scene covers the image
    # gsplat cuts a footprint by its opacity-aware extent, not 3σ: up to 0.0123 in colour on these scenes (H200)
    tol = 2e-2 if backend == "gsplat" else 1e-4
    np.testing.assert_allclose(_cpu(res.colour), colour, atol=tol)
    np.testing.assert_allclose(_cpu(res.alpha), alpha, atol=tol)
    # Expected depth divides by alpha: compare where alpha is not tiny, relative to depth (2-6 m).
    covered = alpha > 1e-2
    np.testing.assert_allclose(_cpu(res.depth)[covered], depth[covered], rtol=tol)


def test_cpu_equals_reference_images_and_gradients():
    """cpu vs reference at 2k Gaussians: images to 1e-4, every parameter's gradient to 1e-3 (norm-relative).

    Both run in float32; they differ by summation order, the cpu kernel's polynomial exp (rel. error < 3e-6) and
    its float32 'colour still behind' bookkeeping, so per-element differences of ~1e-6 of the gradient scale
    are expected; 1e-3 relative to each gradient tensor's norm leaves ample margin while catching any
    wrong term (which shows up at O(1)).
    """
    scene = random_scene(2000, 96, 64, seed=7, sh_degree=2)
    weights = torch.rand(64, 96, 3, generator=torch.Generator().manual_seed(0))
    out = {}
    for backend in ("reference", "cpu"):
        params = [p.clone().requires_grad_(True) for p in scene.params]
        res = render(*params, *scene.camera, background=BG, backend=backend)
        res.means2d.retain_grad()
        loss = (res.colour * weights).sum() + 0.1 * res.depth.sum() + res.alpha.sum()
        loss.backward()
        out[backend] = (res, [p.grad for p in params], res.means2d.grad)
    (ref, ref_grads, ref_m2), (cpu, cpu_grads, cpu_m2) = out["reference"], out["cpu"]
    np.testing.assert_allclose(_cpu(cpu.colour), _cpu(ref.colour), atol=1e-4)
    np.testing.assert_allclose(_cpu(cpu.alpha), _cpu(ref.alpha), atol=1e-4)
    covered = _cpu(ref.alpha) > 1e-2
    np.testing.assert_allclose(_cpu(cpu.depth)[covered], _cpu(ref.depth)[covered], rtol=1e-4)
    names = ["means", "quats", "log_scales", "logit_opacities", "sh_coeffs", "means2d"]
    for name, a, b in zip(names, ref_grads + [ref_m2], cpu_grads + [cpu_m2], strict=True):
        rel = float((a - b).norm() / a.norm())
        assert rel < 1e-3, f"{name}: relative gradient difference {rel:.2e}"


@pytest.mark.gpu
@pytest.mark.skipif(not gsplat_available(), reason="gsplat backend needs CUDA and the gsplat package")
def test_gsplat_agrees_with_cpu_above_40db():
    """Same scene through gsplat (CUDA) and cpu: PSNR ≥ 40 dB (gsplat cuts at its tile/3.33σ box, we at 3σ)."""
    scene = random_scene(50_000, 256, 192, seed=0, sh_degree=1)
    a = _cpu(_render(scene, "cpu", background=BG).colour)
    b = _cpu(_render(scene, "gsplat", background=BG).colour)
    psnr = 10 * np.log10(1.0 / np.mean((a - b) ** 2))
    assert psnr >= 40.0, f"PSNR {psnr:.1f} dB"
