"""Appearance refinement of the survey layer (issue 29): the MVS Gaussians' colour, opacity, scales and rotations
fitted to photos with positions frozen bit for bit, one Gaussian per point, σ within its spacing bound; and the
survey products given back the converted attributes."""

from __future__ import annotations

import numpy as np
import pytest

from core.cameras import Camera, Cameras, View
from core.errors import ConfigError, DataError
from core.gaussians import SH_C0, GaussianSet
from fusion.appearance import (
    AppearanceOptions,
    refine_survey_appearance,
    scale_bounds,
    step_budget,
    with_converted_survey,
)
from fusion.convert_options import Source
from fusion.train.options import TrainOptions
from fusion.train.strategy import DefaultStrategy


def _ring(n: int = 8, distance: float = 1.0) -> Cameras:
    """``n`` cameras on a horizontal circle around the origin, looking at it; 48 × 36 px."""
    cam = Camera.pinhole(40.0, 40.0, 24.0, 18.0, 48, 36)
    views = {}
    for i in range(n):
        a = 2 * np.pi * i / n
        centre = distance * np.array([np.cos(a), np.sin(a), 0.0])
        forward = -centre / np.linalg.norm(centre)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        rotation = np.stack([right, np.cross(forward, right), forward])  # rows: camera axes in world coordinates
        views[i + 1] = View.from_matrix(i + 1, f"v{i}.png", 1, np.c_[rotation, -rotation @ centre])
    return Cameras({1: cam}, views)


def _ball(n: int = 600, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    return 0.2 * d / np.linalg.norm(d, axis=1, keepdims=True) + np.array([1e-7, 0.0, 0.0])  # not exactly float32


def _set(points: np.ndarray, rgb: np.ndarray, sigma: float, opacity_logit: float) -> GaussianSet:
    n = len(points)
    return GaussianSet(points, np.full((n, 3), np.log(sigma)), np.tile([1.0, 0, 0, 0], (n, 1)),
                       np.full(n, opacity_logit), (rgb - 0.5) / SH_C0)  # fmt: skip


def test_bounds_are_a_multiple_of_the_spacing_and_never_shrink_a_gaussian():
    h = 0.01
    grid = np.stack(np.meshgrid(np.arange(12), np.arange(12), indexing="ij"), -1).reshape(-1, 2) * h
    points = np.c_[grid, np.zeros(len(grid))]
    small = np.full((len(points), 3), np.log(0.1 * h))
    bounds = scale_bounds(points, small, 1.5, 4)  # the 4 nearest of an interior grid point are all at h
    interior = (grid[:, 0] > 0) & (grid[:, 0] < 11 * h) & (grid[:, 1] > 0) & (grid[:, 1] < 11 * h)
    np.testing.assert_allclose(bounds[interior], 1.5 * h, rtol=1e-9)
    large = np.full((len(points), 3), np.log(3 * h))
    np.testing.assert_allclose(scale_bounds(points, large, 1.5, 4), 3 * h, rtol=1e-6)  # never below the σ it has


def test_refinement_fits_the_colours_and_leaves_every_position_bit_for_bit():
    from fusion.render.scene import render_gaussian_set

    cameras, points = _ring(), _ball()
    rgb = np.where(points[:, 2:3] > 0, [0.9, 0.2, 0.1], [0.1, 0.3, 0.9])  # the truth: red top, blue bottom
    truth = _set(points, rgb, 0.03, 4.0)
    images = {v.name: render_gaussian_set(truth, cameras.camera_of(v), v).colour.detach().numpy() for v in cameras}
    converted = _set(points, np.full_like(rgb, 0.5), 0.012, 0.0)  # grey, half transparent, too small
    training = TrainOptions(iterations=200, lr_means=0.0, sh_degree=1, sh_degree_interval=50, min_iterations=200,
                            lr_sh_dc=0.02, lr_log_scales=0.02,
                            strategy=DefaultStrategy(refine_start=0, refine_stop=0, reset_every=0))  # fmt: skip
    options = AppearanceOptions(max_image_size=48, max_scale_spacings=1.0, training=training)
    result = refine_survey_appearance(cameras, images, converted, None, options, seed=0)
    refined = result.gaussians
    assert len(refined) == len(converted) and refined.means.dtype == np.float64
    assert np.array_equal(refined.means, converted.means)  # bit for bit, not the float32 training copy
    bounds = scale_bounds(points, converted.log_scales, 1.0, 8)
    assert (np.exp(refined.log_scales.astype(np.float64)).max(axis=1) <= bounds * (1 + 1e-5)).all()
    assert result.counts["at_scale_bound"] > 0  # the bound was reached, so it did bind

    def error(gs: GaussianSet) -> float:
        return float(np.mean([np.abs(render_gaussian_set(gs, cameras.camera_of(v), v).colour.detach().numpy()
                                     - images[v.name]).mean() for v in cameras]))  # fmt: skip

    before, after = error(converted), error(refined)
    assert after < 0.35 * before, (before, after)


def test_options_refuse_moving_positions_or_densifying():
    with pytest.raises(ConfigError, match="lr_means"):
        AppearanceOptions(training=TrainOptions(lr_means=1e-4, strategy=DefaultStrategy(refine_start=0,
                                                                                        refine_stop=0)))  # fmt: skip
    with pytest.raises(ConfigError, match="never refines"):
        AppearanceOptions(training=TrainOptions(lr_means=0.0))
    with pytest.raises(ConfigError):
        AppearanceOptions(max_scale_spacings=0.0)


def test_the_step_budget_is_capped_in_passes_over_the_photos():
    default = AppearanceOptions()
    assert default.training.iterations == 2000 and default.max_passes == 84
    assert step_budget(default, 24) == 2000  # the demo's 24 photos: the budget it was chosen with
    assert step_budget(default, 10) == 840 and step_budget(default, 1) == 84
    assert step_budget(AppearanceOptions(max_passes=0), 10) == 2000  # 0: no cap
    assert step_budget(AppearanceOptions(max_passes=0.1), 2) == 1  # at least one step
    with pytest.raises(ConfigError, match="max_passes"):
        AppearanceOptions(max_passes=-1)
    cameras, points = _ring(n=3), _ball(n=40)
    gs = _set(points, np.full((40, 3), 0.5), 0.02, 0.0)
    images = {v.name: np.full((36, 48, 3), 0.4, np.float32) for v in cameras}
    fixed = DefaultStrategy(refine_start=0, refine_stop=0, reset_every=0)
    training = TrainOptions(iterations=50, lr_means=0.0, sh_degree=0, min_iterations=50, strategy=fixed)
    result = refine_survey_appearance(cameras, images, gs, None, AppearanceOptions(max_passes=4, training=training), 0)
    assert result.counts["iterations"] == result.counts["step_budget"] == 12  # 4 passes over 3 photos


def test_the_trainer_refuses_a_scale_bound_on_a_set_that_may_grow():
    from fusion.train.trainer import train_splats

    cameras, points = _ring(n=2), _ball(n=50)
    gs = _set(points, np.full((50, 3), 0.5), 0.01, 0.0)
    images = {v.name: np.full((36, 48, 3), 0.5) for v in cameras}
    with pytest.raises(ConfigError, match="fixed set"):
        train_splats(cameras, images, None, gs, None, TrainOptions(iterations=400), max_scales=np.full(50, 0.02))
    with pytest.raises(ConfigError, match="one σ > 0"):
        train_splats(cameras, images, None, gs, None, TrainOptions(iterations=5), max_scales=np.full(49, 0.02))


def test_survey_rows_get_the_converted_attributes_back():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(40, 3))
    converted = _set(points, rng.uniform(size=(40, 3)), 0.01, 1.0)
    converted.quats[:] = rng.normal(size=(40, 4)).astype(np.float32)
    refined = converted.with_sh_degree(2)
    refined.log_scales += 0.3
    refined.logit_opacities -= 1.0
    refined.sh_dc += 0.2
    refined.sh_rest[:] = 0.1
    refined.quats[:] = rng.normal(size=(40, 4)).astype(np.float32)
    keep = np.flatnonzero(rng.uniform(size=40) < 0.7)
    fill = _set(rng.normal(size=(7, 3)), rng.uniform(size=(7, 3)), 0.02, 0.5).with_sh_degree(2)
    merged = GaussianSet.concatenate([refined.subset(keep[::-1]), fill])  # any order: rows are found by position
    merged.fields["source"] = np.r_[np.full(len(keep), Source.MVS), np.full(7, Source.SPLAT)].astype(np.uint8)
    restored = with_converted_survey(merged, converted)
    expected = converted.with_sh_degree(2).subset(keep[::-1])
    for name in ("means", "log_scales", "quats", "logit_opacities", "sh_dc", "sh_rest"):
        np.testing.assert_array_equal(getattr(restored, name)[: len(keep)], getattr(expected, name))
        np.testing.assert_array_equal(getattr(restored, name)[len(keep) :], getattr(fill, name))
    moved = merged.subset(np.arange(len(merged)))
    moved.means[0, 0] += 1e-9
    with pytest.raises(DataError, match="no converted MVS Gaussian does"):
        with_converted_survey(moved, converted, "merged.ply")


def test_no_survey_gaussian_is_made_invisible():
    from fusion.appearance import MIN_OPACITY

    cameras, points = _ring(n=4), _ball(n=200)
    images = {v.name: np.zeros((36, 48, 3)) for v in cameras}  # black photos: the fit wants every α at 0
    converted = _set(points, np.full((200, 3), 0.5), 0.02, 2.0)
    training = TrainOptions(iterations=100, lr_means=0.0, sh_degree=0, min_iterations=100, lr_opacities=0.2,
                            strategy=DefaultStrategy(refine_start=0, refine_stop=0, reset_every=0))  # fmt: skip
    context = _set(1.5 * _ball(n=100, seed=2), np.full((100, 3), 0.5), 0.05, 2.0)
    context.logit_opacities[:10] = -8.0  # α 3e-4: invisible as trained, and stays so
    result = refine_survey_appearance(cameras, images, converted, context, AppearanceOptions(training=training), 0)
    alpha = 1 / (1 + np.exp(-result.gaussians.logit_opacities.astype(np.float64)))
    assert result.counts["at_least_opacity"] > 0 and alpha.min() >= MIN_OPACITY * (1 - 1e-5)
    assert result.context is not None
    context_alpha = 1 / (1 + np.exp(-result.context.logit_opacities.astype(np.float64)))
    assert context_alpha[10:].min() >= MIN_OPACITY * (1 - 1e-5)  # the fit wants them at 0: none made invisible
    assert context_alpha[:10].max() < 1e-3


def _two_layers(cameras: Cameras) -> tuple[GaussianSet, GaussianSet, dict[str, np.ndarray]]:
    """The truth: a red/blue survey ball inside a green shell of context Gaussians; returns (survey truth, context
    truth, photos)."""
    from fusion.render.scene import render_gaussian_set

    points, shell = _ball(), 2.0 * _ball(n=300, seed=1)
    rgb = np.where(points[:, 2:3] > 0, [0.9, 0.2, 0.1], [0.1, 0.3, 0.9])
    survey, context = _set(points, rgb, 0.03, 4.0), _set(shell, np.tile([0.1, 0.8, 0.2], (300, 1)), 0.06, 4.0)
    both = GaussianSet.concatenate([survey, context])
    images = {v.name: render_gaussian_set(both, cameras.camera_of(v), v).colour.detach().numpy() for v in cameras}
    return survey, context, images


def test_the_context_is_refined_beside_the_survey_layer_positions_bit_for_bit():
    cameras = _ring(distance=3.0)
    survey_truth, context_truth, images = _two_layers(cameras)
    grey = np.full((len(survey_truth), 3), 0.5)
    survey = _set(survey_truth.means, grey, 0.012, 0.0)
    context = _set(context_truth.means, np.full((len(context_truth), 3), 0.5), 0.06, 0.0)
    context.fields["classification"] = np.arange(len(context), dtype=np.uint8)
    training = TrainOptions(iterations=150, lr_means=0.0, sh_degree=0, min_iterations=150, lr_sh_dc=0.02,
                            strategy=DefaultStrategy(refine_start=0, refine_stop=0, reset_every=0))  # fmt: skip
    frozen = refine_survey_appearance(cameras, images, survey, context,
                                      AppearanceOptions(refine_context=False, training=training), 0)  # fmt: skip
    joint = refine_survey_appearance(cameras, images, survey, context, AppearanceOptions(training=training), 0)
    assert frozen.context is None and frozen.counts["context_refined"] == 0
    refined = joint.context
    assert refined is not None and joint.counts["context_refined"] == len(context)
    assert np.array_equal(refined.means, context.means) and np.array_equal(refined.origin, context.origin)
    assert np.array_equal(refined.fields["classification"], context.fields["classification"])
    assert np.array_equal(joint.gaussians.means, survey.means)

    def colour_error(gs: GaussianSet, truth: GaussianSet) -> float:
        return float(np.abs(gs.sh_dc - truth.sh_dc).mean())

    assert colour_error(refined, context_truth) < 0.5 * colour_error(context, context_truth)
    from fusion.render.scene import render_gaussian_set

    def image_error(survey_layer: GaussianSet, context_layer: GaussianSet) -> float:
        both = GaussianSet.concatenate([survey_layer, context_layer])
        return float(np.mean([np.abs(render_gaussian_set(both, cameras.camera_of(v), v).colour.detach().numpy()
                                     - images[v.name]).mean() for v in cameras]))  # fmt: skip

    assert image_error(joint.gaussians, refined) < 0.5 * image_error(frozen.gaussians, context)


def test_every_layer_gets_its_attributes_back_by_position():
    rng = np.random.default_rng(5)
    converted = _set(rng.normal(size=(30, 3)), rng.uniform(size=(30, 3)), 0.01, 1.0)
    fill = _set(rng.normal(size=(12, 3)), rng.uniform(size=(12, 3)), 0.02, 0.5)
    background = _set(50 + rng.normal(size=(9, 3)), rng.uniform(size=(9, 3)), 0.5, 0.5)
    fill.origin = np.array([0.25, -1.0, 3.0])  # another origin: rows are matched where the merge brings them
    refined = [g.with_sh_degree(1) for g in (converted, fill, background)]
    for g in refined:
        g.sh_dc += 0.3
        g.logit_opacities -= 2.0
        g.log_scales += 0.1
    merged = GaussianSet.concatenate([refined[0], refined[1].subset(np.arange(12)[::-2]), refined[2]])
    sources = [Source.MVS] * 30 + [Source.SPLAT] * 6 + [Source.BACKGROUND] * 9
    merged.fields["source"] = np.array(sources, np.uint8)
    survey_only = with_converted_survey(merged, converted)
    np.testing.assert_array_equal(survey_only.sh_dc[30:], merged.sh_dc[30:])  # without references: refined
    restored = with_converted_survey(merged, converted, fill=fill, background=background)
    np.testing.assert_array_equal(restored.sh_dc[:30], converted.sh_dc)
    np.testing.assert_array_equal(restored.logit_opacities[30:36], fill.logit_opacities[::-2])
    np.testing.assert_array_equal(restored.log_scales[36:], background.log_scales)
    np.testing.assert_array_equal(restored.means, merged.means)
    with pytest.raises(DataError, match="no fill splat does"):
        with_converted_survey(merged, converted, fill=fill.subset(np.arange(11)))  # row 11 is merged


def test_gaussians_that_share_a_position_keep_their_own_attributes():
    """A clone that moved with its parent: two fill splats at one position, bit for bit, with different colours
    and opacities. Each merged row gets back its own as-trained attributes (the k-th at a position the k-th),
    also when one of them was dropped before it (then the one left takes the first)."""
    rng = np.random.default_rng(8)
    converted = _set(rng.normal(size=(5, 3)), rng.uniform(size=(5, 3)), 0.01, 1.0)
    fill = _set(rng.normal(size=(6, 3)), rng.uniform(size=(6, 3)), 0.02, 0.5)
    fill.means[4] = fill.means[1]
    fill.logit_opacities[4] = -1.5
    refined = fill.subset(np.arange(6))
    refined.sh_dc += 0.3
    merged = GaussianSet.concatenate([converted, refined])
    merged.fields["source"] = np.array([Source.MVS] * 5 + [Source.SPLAT] * 6, np.uint8)
    restored = with_converted_survey(merged, converted, fill=fill)
    np.testing.assert_array_equal(restored.sh_dc[5:], fill.sh_dc)
    np.testing.assert_array_equal(restored.logit_opacities[5:], fill.logit_opacities)
    assert not np.array_equal(fill.sh_dc[1], fill.sh_dc[4])
    one_left = GaussianSet.concatenate([converted, refined.subset(np.array([0, 2, 3, 4, 5]))])
    one_left.fields["source"] = merged.fields["source"][:10]
    np.testing.assert_array_equal(with_converted_survey(one_left, converted, fill=fill).sh_dc[8], fill.sh_dc[1])


def test_a_merged_file_rebased_on_reading_still_finds_its_layers(tmp_path):
    from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply

    rng = np.random.default_rng(8)
    converted = _set(rng.normal(size=(20, 3)), rng.uniform(size=(20, 3)), 0.01, 1.0)
    background = _set(6e4 + rng.normal(size=(5, 3)), rng.uniform(size=(5, 3)), 50.0, 0.5)  # a far shell: 60 km
    write_gaussian_ply(tmp_path / "mvs.ply", converted)
    write_gaussian_ply(tmp_path / "background.ply", background)
    refined = [converted.subset(np.arange(20)), background.subset(np.arange(5))]
    for g in refined:
        g.sh_dc += 0.3
    merged = GaussianSet.concatenate(refined)
    merged.fields["source"] = np.array([Source.MVS] * 20 + [Source.BACKGROUND] * 5, np.uint8)
    write_gaussian_ply(tmp_path / "merged.ply", merged, extra_fields=True)
    read = read_gaussian_ply(tmp_path / "merged.ply")
    assert not np.array_equal(read.origin, merged.origin)  # the reader moved it to a local origin
    reference = read_gaussian_ply(tmp_path / "mvs.ply")
    restored = with_converted_survey(read, reference, background=read_gaussian_ply(tmp_path / "background.ply"))
    np.testing.assert_array_equal(restored.origin, reference.origin)
    np.testing.assert_array_equal(restored.means[:20], reference.means)  # bit for bit, in the survey's frame
    np.testing.assert_array_equal(restored.sh_dc[:20], reference.sh_dc)
    np.testing.assert_allclose(restored.sh_dc[20:], background.sh_dc, atol=1e-6)


def test_trained_scales_and_colours_stay_inside_what_the_viewer_formats_hold(tmp_path):
    """A fit that pushes colours past SPZ's code (white photos) from a set that starts outside both ranges ends
    inside them — log σ in [−10, 5.94], |f_dc| ≤ 3.33 — and its SPZ file clips nothing (no warning)."""
    import warnings

    from fusion.spz_format import SPZ_F_DC_LIMIT, SPZ_LOG_SCALE_RANGE, write_spz
    from fusion.train.trainer import train_splats

    cameras, points = _ring(n=3), _ball(n=60)
    gs = _set(points, np.full((60, 3), 0.5), 0.02, 2.0)
    gs.log_scales[:20] = -12.0  # 6 µm: under SPZ's least σ
    gs.log_scales[20:25] = 7.0  # 1.1 km: over its largest
    gs.sh_dc[25:40] = 5.0  # colour 1.9: over its largest code
    images = {v.name: np.full((36, 48, 3), 1.0, np.float32) for v in cameras}
    fixed = DefaultStrategy(refine_start=0, refine_stop=0, reset_every=0)
    training = TrainOptions(iterations=30, min_iterations=30, sh_degree=0, strategy=fixed, lr_sh_dc=0.05)
    trained = train_splats(cameras, images, None, gs, None, training).splats
    lo, hi = SPZ_LOG_SCALE_RANGE
    assert lo == -10.0 and abs(hi - 5.9375) < 1e-12 and abs(SPZ_F_DC_LIMIT - 127.5 / 38.25) < 1e-12
    assert trained.log_scales.min() >= lo and trained.log_scales.max() <= hi
    assert np.abs(trained.sh_dc).max() <= SPZ_F_DC_LIMIT
    assert np.isclose(trained.log_scales.min(), lo)  # the 6 µm Gaussians were held at the bound, not left under it
    assert np.isclose(trained.sh_dc.max(), SPZ_F_DC_LIMIT, atol=1e-4)  # the white photos pushed colours to it
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_spz(tmp_path / "trained.spz", trained)
