"""The masked splat trainer against a scene whose truth is a known Gaussian set rendered by the same renderer."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from core.cameras import Camera, Cameras, View
from core.errors import ConfigError, DataError
from core.gaussians import SH_C0, GaussianSet
from fusion.render import render_gaussian_set
from fusion.train import DefaultStrategy, TrainOptions, train_splats
from fusion.train.params import make_optimizer, make_parameters, tensors_from_set


def ring_cameras(n: int, width: int = 64, height: int = 48, radius: float = 2.0) -> Cameras:
    """n cameras on a ring at 30° elevation looking at the origin (COLMAP world-to-camera poses)."""
    cam = Camera.pinhole(0.9 * width, 0.9 * width, width / 2, height / 2, width, height)
    views = {}
    for i in range(n):
        az = 2 * math.pi * i / n
        c = radius * np.array([math.cos(az) * math.cos(0.5), math.sin(az) * math.cos(0.5), math.sin(0.5)])
        z = -c / np.linalg.norm(c)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        views[i + 1] = View.from_matrix(i + 1, f"v{i:02d}.png", 1, np.concatenate([R, (-R @ c)[:, None]], axis=1))
    return Cameras({1: cam}, views)


def blob_set(n: int, seed: int, centre=(0.0, 0.0, 0.0), radius: float = 0.35) -> GaussianSet:
    """n opaque, coloured Gaussians on a sphere (σ 3 cm)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    colours = rng.uniform(0.1, 0.9, (n, 3))
    return GaussianSet(
        np.asarray(centre) + radius * d,
        np.full((n, 3), math.log(0.03)),
        np.tile([1.0, 0, 0, 0], (n, 1)),
        np.full(n, 3.0),
        (colours - 0.5) / SH_C0,
    )


def render_all(gs: GaussianSet, cameras: Cameras) -> dict[str, np.ndarray]:
    return {v.name: render_gaussian_set(gs, cameras.camera_of(v), v, backend="cpu").to_numpy().colour for v in cameras}


def alpha_masks(gs: GaussianSet, cameras: Cameras, threshold: float) -> dict[str, np.ndarray]:
    return {
        v.name: render_gaussian_set(gs, cameras.camera_of(v), v, backend="cpu").to_numpy().alpha > threshold
        for v in cameras
    }


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    d = (a - b) ** 2
    d = d[mask] if mask is not None else d
    return -10 * math.log10(float(d.mean()))


def perturbed(gs: GaussianSet, seed: int) -> GaussianSet:
    """The same Gaussians moved by ~1 cm, all grey, half as opaque: training must recover colour and opacity."""
    rng = np.random.default_rng(seed)
    out = gs.subset(slice(None))
    out.means = out.means + rng.normal(0, 0.01, out.means.shape)
    out.sh_dc = np.zeros_like(out.sh_dc)
    out.logit_opacities = np.zeros_like(out.logit_opacities)
    return out


def test_whole_image_training_recovers_a_known_scene() -> None:
    cams = ring_cameras(8)
    truth = blob_set(250, 0)
    photos = render_all(truth, cams)
    init = perturbed(truth, 1)
    drawn = alpha_masks(truth, cams, 0.05)  # score where the object is, not the black background
    before = np.mean([psnr(render_all(init, cams)[k], photos[k], drawn[k]) for k in photos])
    opts = TrainOptions(iterations=160, sh_degree=0, eval_every=8, min_iterations=1000, seed=3, lr_sh_dc=0.02,
                        strategy=DefaultStrategy(refine_start=10_000))  # fmt: skip
    result = train_splats(cams, photos, None, init, options=opts)
    after = np.mean([psnr(render_all(result.splats, cams)[k], photos[k], drawn[k]) for k in photos])
    assert len(result.splats) == len(init) and result.iterations == 160
    assert after > before + 8.0, (before, after)
    # the hold-out pixels never entered the loss, yet their PSNR rose with training
    assert result.history[-1].holdout_psnr > result.history[0].holdout_psnr + 3.0
    # normals are unit vectors
    n = np.stack([result.splats.fields[k] for k in ("nx", "ny", "nz")], axis=1)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)


def test_masked_training_leaves_frozen_context_and_fits_the_region() -> None:
    """Context = the truth's left half, exact and frozen; the right half is trained from a perturbed start, with
    masks = pixels where the right half is drawn. The frozen set is returned untouched by construction (it is not
    part of the result); the region must be fitted and nothing outside the masks may enter the loss."""
    cams = ring_cameras(8)
    truth = blob_set(300, 0)
    right = truth.means[:, 0] > 0
    context, target = truth.subset(~right), truth.subset(right)
    photos = render_all(truth, cams)
    masks = alpha_masks(target, cams, 0.5)
    assert sum(m.sum() for m in masks.values()) > 0
    init = perturbed(target, 2)
    opts = TrainOptions(iterations=160, sh_degree=0, eval_every=8, min_iterations=1000, seed=0, lr_sh_dc=0.02,
                        strategy=DefaultStrategy(refine_start=10_000))  # fmt: skip
    merged_before = GaussianSet.concatenate([context, init])
    before = np.mean([psnr(render_all(merged_before, cams)[k], photos[k], masks[k]) for k in photos])
    result = train_splats(cams, photos, masks, init, context, opts)
    merged = GaussianSet.concatenate([context, result.splats])
    after = np.mean([psnr(render_all(merged, cams)[k], photos[k], masks[k]) for k in photos])
    assert after > before + 6.0, (before, after)
    assert result.context_total == len(context)
    assert result.views_used == sum(1 for m in masks.values() if m.any())


def test_pixels_outside_the_mask_do_not_steer_training() -> None:
    """Changing the photo beyond the SSIM window's reach (5 px) of the mask must not change the trained splats."""
    cams = ring_cameras(6)
    truth = blob_set(120, 4)
    photos = render_all(truth, cams)
    masks = {k: np.zeros(p.shape[:2], bool) for k, p in photos.items()}
    for m in masks.values():
        m[10:30, 20:44] = True
    near = np.zeros_like(masks["v00.png"])
    near[10 - 5 : 30 + 5, 20 - 5 : 44 + 5] = True
    noisy = {k: np.where(near[..., None], p, 1.0 - p) for k, p in photos.items()}
    init = perturbed(truth, 5)
    opts = TrainOptions(iterations=30, sh_degree=0, seed=1, strategy=DefaultStrategy(refine_start=10_000))
    a = train_splats(cams, photos, masks, init, options=opts).splats
    b = train_splats(cams, noisy, masks, init, options=opts).splats
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.sh_dc, b.sh_dc)


def test_training_is_deterministic_with_a_seed() -> None:
    cams = ring_cameras(6)
    truth = blob_set(150, 7)
    photos = render_all(truth, cams)
    grow = DefaultStrategy(refine_start=20, refine_every=20, grow_grad2d=1e-6, cap=400)
    opts = TrainOptions(iterations=60, sh_degree=1, sh_degree_interval=20, seed=5, strategy=grow)
    a = train_splats(cams, photos, None, perturbed(truth, 8), options=opts)
    b = train_splats(cams, photos, None, perturbed(truth, 8), options=opts)
    assert len(a.splats) == len(b.splats)
    np.testing.assert_array_equal(a.splats.means, b.splats.means)
    np.testing.assert_array_equal(a.splats.sh_rest, b.splats.sh_rest)


def test_a_snapshot_is_the_set_as_it_was_at_its_step() -> None:
    # the optimiser updates the parameters in place: a snapshot that aliased them carried the run's last attributes
    # (positions excepted); with no schedule tied to the run's length, the snapshot at step k is the k-step run's set
    cams = ring_cameras(4)
    truth = blob_set(80, 3)
    photos = render_all(truth, cams)
    fixed = DefaultStrategy(refine_start=0, refine_stop=0, reset_every=0)
    opts = TrainOptions(iterations=12, sh_degree=1, sh_degree_interval=4, lr_means=0.0, seed=2, strategy=fixed)
    long = train_splats(cams, photos, None, perturbed(truth, 4), options=replace(opts, snapshot_iterations=(6,)))
    short = train_splats(cams, photos, None, perturbed(truth, 4), options=replace(opts, iterations=6))
    snapshot = long.snapshots[6]
    for field in ("means", "log_scales", "quats", "logit_opacities", "sh_dc", "sh_rest"):
        np.testing.assert_array_equal(getattr(snapshot, field), getattr(short.splats, field), err_msg=field)
    assert not np.array_equal(snapshot.sh_dc, long.splats.sh_dc)  # the run went on after it


def test_no_mask_pixels_is_a_data_error() -> None:
    cams = ring_cameras(4)
    truth = blob_set(50, 1)
    photos = render_all(truth, cams)
    masks = {k: np.zeros(p.shape[:2], bool) for k, p in photos.items()}
    with pytest.raises(DataError, match="no training view has mask pixels"):
        train_splats(cams, photos, masks, truth)


def test_adam_groups_follow_parameters() -> None:
    gs = blob_set(10, 0)
    params = make_parameters(tensors_from_set(gs, np.zeros(3), 1))
    opt = make_optimizer(params, {k: 0.1 for k in params})
    assert [g["name"] for g in opt.param_groups] == list(params)
    assert all(g["params"][0] is params[g["name"]] for g in opt.param_groups)
    assert params["sh_rest"].shape == (10, 3, 3) and params["sh_dc"].shape == (10, 1, 3)
    assert torch.equal(params["means"], torch.from_numpy(gs.means.astype(np.float32)))


def test_splat_normals_are_the_rotated_smallest_axis_and_come_with_the_trained_splats() -> None:
    from fusion.train import splat_normals

    # identity rotation, smallest σ along z; 90° about z (w, x, y, z = cos 45°, 0, 0, sin 45°), smallest along x
    c = math.sqrt(0.5)
    gs = GaussianSet(np.zeros((2, 3)), np.log([[0.2, 0.1, 0.01], [0.01, 0.2, 0.1]]),
                     np.array([[1.0, 0, 0, 0], [c, 0, 0, c]]), np.zeros(2), np.zeros((2, 3)))  # fmt: skip
    n = splat_normals(gs)
    np.testing.assert_allclose(np.abs(n), [[0, 0, 1], [0, 1, 0]], atol=1e-6)  # ẑ; R_z(90°) x̂ = ŷ
    cams = ring_cameras(6)
    truth = blob_set(40, 9)
    opts = TrainOptions(iterations=6, sh_degree=0, seed=2, strategy=DefaultStrategy(refine_start=10_000))
    trained = train_splats(cams, render_all(truth, cams), None, truth, options=opts).splats
    written = np.stack([trained.fields[k] for k in ("nx", "ny", "nz")], axis=1)
    np.testing.assert_allclose(written, splat_normals(trained), atol=1e-6)


def test_densification_stops_at_refine_until_share_of_the_run() -> None:
    """Gaussians added late are never fitted: with refine_until 0.5 the count is frozen over the second half (with
    1.0 it still grows there), and early stopping cannot end a run before densification has ended."""
    cams = ring_cameras(6)
    truth = blob_set(60, 3)
    photos = render_all(truth, cams)
    grow = DefaultStrategy(refine_start=12, refine_every=12, grow_grad2d=1e-12, cap=10_000, budget_ramp=0.01)

    def history(**kw):
        opts = TrainOptions(iterations=60, sh_degree=0, seed=2, strategy=grow, eval_every=6, **kw)
        return [
            (c.step, c.gaussians) for c in train_splats(cams, photos, None, perturbed(truth, 4), options=opts).history
        ]

    half = history(refine_until=0.5)
    whole = history(refine_until=1.0)
    assert [n for s, n in half if s >= 30] == [half[-1][1]] * 6 and half[-1][1] > half[0][1]
    assert dict(whole)[48] > dict(whole)[30]  # still growing in the second half
    stopped = history(refine_until=0.5, patience=1, min_improvement_db=1e9, min_iterations=0)
    assert stopped[-1][0] == 30  # no window can improve by 1e9 dB: stops as soon as densification has ended


def test_refine_until_must_be_a_share() -> None:
    with pytest.raises(ConfigError, match="refine_until"):
        TrainOptions(refine_until=0.0)
