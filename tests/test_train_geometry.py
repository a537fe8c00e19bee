"""The geometric losses in masked training (issue 31): options and schedule, the geometry of the trainable + frozen
render, off = the run without them bit for bit, and runs with them on against constructed scenes whose truth is
a layer of flat Gaussians on a plane."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from test_train_trainer import alpha_masks, render_all, ring_cameras

from core.errors import ConfigError
from core.gaussians import SH_C0, GaussianSet
from fusion.render import render
from fusion.train import DefaultStrategy, GeometryOptions, TrainOptions, train_splats
from fusion.train.params import context_from_set, make_parameters, tensors_from_set
from fusion.train.render import project_context, render_step
from fusion.train.schedule import TrainSchedule
from fusion.train.state import initial_state, prepare_scene
from fusion.train.step import geometric_loss, train_step


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def plane_set(n_side: int = 14, half: float = 0.4, seed: int = 0, grey: bool = False) -> GaussianSet:
    """n_side² opaque flat Gaussians (σ 3.5 cm × 3.5 cm × 1 mm) on a grid over the plane z = 0, random colours."""
    rng = np.random.default_rng(seed)
    g = np.linspace(-half, half, n_side)
    x, y = np.meshgrid(g, g)
    means = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    n = len(means)
    colours = np.full((n, 3), 0.5) if grey else rng.uniform(0.1, 0.9, (n, 3))
    return GaussianSet(means, np.tile(np.log([0.035, 0.035, 0.001]), (n, 1)), np.tile([1.0, 0, 0, 0], (n, 1)),
                       np.full(n, 3.0), (colours - 0.5) / SH_C0)  # fmt: skip


def scrambled(gs: GaussianSet, seed: int, offset: float = 0.02) -> GaussianSet:
    """The same Gaussians moved by ~2 cm, round (σ 3 cm) and randomly rotated: their normals mean nothing yet."""
    rng = np.random.default_rng(seed)
    out = gs.subset(slice(None))
    out.means = out.means + rng.normal(0, offset, out.means.shape)
    out.log_scales = math.log(0.03) + rng.normal(0, 0.05, out.log_scales.shape)
    q = rng.normal(size=(len(out), 4))
    out.quats = q / np.linalg.norm(q, axis=1, keepdims=True)
    return out


def inconsistency(splats: GaussianSet, cameras, photos, masks) -> float:
    """Mean over the views of the depth–normal inconsistency (1 − cos, plane depth) of ``splats`` on the masks."""
    scene = prepare_scene(cameras, photos, masks, None, TrainOptions())
    params = make_parameters(tensors_from_set(splats, scene.centre, 0))
    with torch.no_grad():
        values = [
            float(
                geometric_loss(render_step(params, v, None, 0, scene.background, geometry=True), v, GeometryOptions())
            )
            for v in scene.views
        ]
    return float(np.mean(values))


# -- options and schedule -----------------------------------------------------------------------------------------
def test_geometry_options_and_schedule() -> None:
    assert TrainOptions().geometric is None and TrainOptions().geometry is None
    assert TrainOptions(geometry=GeometryOptions(normal_consistency_weight=0.0)).geometric is None  # nothing on
    on = GeometryOptions(start=0.25, every=3)
    assert TrainOptions(geometry=on).geometric is on and on.depth == "plane" and on.normal_consistency_weight == 0.05
    s = TrainSchedule.from_options(TrainOptions(iterations=20, geometry=on), 1.0, 3, 64)
    assert [t for t in range(20) if s.geometry_on(t)] == [5, 8, 11, 14, 17]
    off = TrainSchedule.from_options(TrainOptions(iterations=20), 1.0, 3, 64)
    assert not any(off.geometry_on(t) for t in range(20))
    assert GeometryOptions(depth="median").depth == "median"
    for bad in ({"normal_consistency_weight": -1.0}, {"start": 1.5}, {"every": 0}, {"depth": "mean"}):
        with pytest.raises(ConfigError):
            GeometryOptions(**bad)


# -- the render -----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_geometry_render_of_trainable_and_frozen_context_is_the_renderers(backend: str) -> None:
    """Colour and its gradients do not change when the geometry is composited too, and the geometry of the
    trainable + cached frozen rows is :func:`fusion.render.render`'s of the whole set."""
    cams = ring_cameras(3)
    trainable = scrambled(plane_set(6, 0.2, seed=1), 2, offset=0.01)
    context = plane_set(8, 0.45, seed=3)
    context.means = context.means + np.array([0.0, 0.0, -0.05])
    photos = render_all(trainable, cams)
    scene = prepare_scene(cams, photos, None, None, TrainOptions())
    view = scene.views[1]
    frozen = context_from_set(context, scene.centre, 0)
    cache = project_context(frozen, view, geometry=True)
    assert cache.normals.shape == (len(cache), 3) and not cache.normals.requires_grad
    out = {}
    for geometry in (False, True):
        params = make_parameters(tensors_from_set(trainable, scene.centre, 0))
        res = render_step(params, view, cache, 0, scene.background, backend, geometry=geometry)
        (res.colour * torch.linspace(0, 1, 3)).sum().backward()
        out[geometry] = (res, {k: p.grad.clone() for k, p in params.items() if p.grad is not None})
    (plain, g_plain), (geo, g_geo) = out[False], out[True]
    assert plain.geometry is None and geo.geometry is not None
    torch.testing.assert_close(geo.colour, plain.colour, atol=1e-6, rtol=0)
    for k in g_plain:
        torch.testing.assert_close(g_geo[k], g_plain[k], atol=1e-6, rtol=1e-5)
    # the renderer on the concatenated set (context appended after the trainable rows, as the step composites)
    t_ctx = tensors_from_set(context, scene.centre, 0)
    t_tr = tensors_from_set(trainable, scene.centre, 0)
    cat = {k: torch.cat([t_tr[k], t_ctx[k]]) for k in t_tr}
    ref = render(cat["means"], cat["quats"], cat["log_scales"], cat["logit_opacities"], cat["sh_dc"], view.viewmat,
                 view.K, view.width, view.height, backend=backend, render_geometry=True).geometry  # fmt: skip
    both = geo.geometry.plane_valid & ref.plane_valid
    assert both.sum() > 100 and torch.equal(geo.geometry.plane_valid, ref.plane_valid)
    torch.testing.assert_close(geo.geometry.plane_depth[both], ref.plane_depth[both], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(geo.geometry.normal, ref.normal, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(geo.geometry.median_depth, ref.median_depth, atol=1e-5, rtol=1e-5)


# -- off = before ---------------------------------------------------------------------------------------------------
def test_off_renders_no_geometry_and_weight_zero_is_the_same_run_bit_for_bit() -> None:
    cams = ring_cameras(4)
    truth = plane_set(8, 0.3)
    photos = render_all(truth, cams)
    masks = alpha_masks(truth, cams, 0.5)
    base = {"iterations": 12, "sh_degree": 0, "seed": 3, "flat": True, "strategy": DefaultStrategy(refine_start=4,
            refine_every=4)}  # fmt: skip
    runs = [
        train_splats(cams, photos, masks, scrambled(truth, 1), options=TrainOptions(**base, geometry=geometry))
        for geometry in (None, GeometryOptions(normal_consistency_weight=0.0, every=1))
    ]
    for k in ("means", "log_scales", "quats", "logit_opacities", "sh_dc"):
        np.testing.assert_array_equal(getattr(runs[0].splats, k), getattr(runs[1].splats, k))
    assert all(math.isnan(c.normal_consistency) for r in runs for c in r.history)


def test_geometric_steps_follow_the_cadence() -> None:
    cams = ring_cameras(3)
    truth = plane_set(6, 0.3)
    photos = render_all(truth, cams)
    opts = TrainOptions(iterations=8, sh_degree=0, geometry=GeometryOptions(start=0.25, every=3), flat=True)
    scene = prepare_scene(cams, photos, None, None, opts)
    schedule = TrainSchedule.from_options(opts, scene.scale, len(scene.views), 48)
    state = initial_state(scrambled(truth, 0), scene, schedule, opts)
    outcomes = [train_step(state, scene, schedule, opts, step % 3) for step in range(8)]
    assert [o.render.geometry is not None for o in outcomes] == [t in (2, 5) for t in range(8)]
    assert [o.consistency is not None for o in outcomes] == [t in (2, 5) for t in range(8)]


# -- on -------------------------------------------------------------------------------------------------------------
def test_depth_normal_consistency_makes_the_layer_flat_and_still_fits_the_photos() -> None:
    """Scrambled round splats of a textured plane (inconsistency 0.46): 120 steps with the flatness term only leave
    0.11 of 1 − cos between rendered normals and the normals of the rendered plane depth; with the consistency term
    (weight 0.2, every step) it falls below 0.05 while the photometric loss keeps falling."""
    cams = ring_cameras(6)
    truth = plane_set()
    photos = render_all(truth, cams)
    masks = alpha_masks(truth, cams, 0.5)
    init = scrambled(truth, 1)
    assert inconsistency(truth, cams, photos, masks) < 1e-6 < 0.3 < inconsistency(init, cams, photos, masks)
    result = {}
    for geometry in (None, GeometryOptions(normal_consistency_weight=0.2, every=1)):
        opts = TrainOptions(iterations=120, sh_degree=0, seed=0, flat=True, lr_quats=0.01, eval_every=24,
                            strategy=DefaultStrategy(refine_start=10_000), geometry=geometry)  # fmt: skip
        result[geometry is not None] = train_splats(cams, photos, masks, init, options=opts)
    without = inconsistency(result[False].splats, cams, photos, masks)
    with_term = inconsistency(result[True].splats, cams, photos, masks)
    assert with_term < 0.05 and with_term < 0.5 * without, (without, with_term)
    history = result[True].history
    assert history[-1].loss < 0.6 * history[0].loss and history[-1].holdout_psnr > history[0].holdout_psnr + 2
    assert history[-1].normal_consistency < 0.3 * history[0].normal_consistency


def test_geometry_options_are_a_config_table() -> None:
    """``[train.training.geometry]`` reads and writes like the other option tables (absent = ``"none"`` = off)."""
    from fusion.train.masked import MaskedTrainingOptions
    from hybridsplat.options import options_from_table, options_to_data, options_with

    default = options_to_data(MaskedTrainingOptions())
    assert default["training"]["geometry"] == "none"
    opts = options_with(MaskedTrainingOptions, {"training.geometry": {"every": 3, "depth": "median"}})
    assert opts.training.geometry == GeometryOptions(every=3, depth="median")
    assert options_from_table(MaskedTrainingOptions, options_to_data(opts), "test") == opts
