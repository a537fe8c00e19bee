"""The background layer (issue 29): the far shell's geometry, which pixels are background, and a layer trained behind
a frozen foreground that draws a sky the foreground alone leaves black, its Gaussians all far outside the region."""

from __future__ import annotations

import numpy as np
import pytest

from core.cameras import Camera, Cameras, View
from core.errors import ConfigError
from core.gaussians import SH_C0, GaussianSet
from fusion.background import (
    MAX_SHELL_M,
    BackgroundOptions,
    SurveyRegion,
    _sphere_exit,
    background_masks,
    choose_shell_radius,
    shell_disagreement,
    shell_radius,
    survey_region,
    train_background,
)
from fusion.train.options import TrainOptions
from fusion.train.strategy import DefaultStrategy

SKY = np.array([0.3, 0.5, 0.9])


def _ring(n: int = 8, distance: float = 1.0) -> Cameras:
    """``n`` cameras on a horizontal circle of radius ``distance`` around the origin, looking at it; 48 × 36 px."""
    cam = Camera.pinhole(40.0, 40.0, 24.0, 18.0, 48, 36)
    views = {}
    for i in range(n):
        a = 2 * np.pi * i / n
        centre = distance * np.array([np.cos(a), np.sin(a), 0.0])
        forward = -centre / np.linalg.norm(centre)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        rotation = np.stack([right, down, forward])  # rows: camera axes in world coordinates
        views[i + 1] = View.from_matrix(i + 1, f"v{i}.png", 1, np.c_[rotation, -rotation @ centre])
    return Cameras({1: cam}, views)


def _ball(radius: float = 0.15, n: int = 400, seed: int = 0) -> GaussianSet:
    """An opaque grey ball of small Gaussians at the origin (the survey region)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    points = radius * d / np.linalg.norm(d, axis=1, keepdims=True)
    return GaussianSet(points, np.full((n, 3), np.log(0.04)), np.tile([1.0, 0, 0, 0], (n, 1)), np.full(n, 6.0),
                       np.full((n, 3), (0.5 - 0.5) / SH_C0))  # fmt: skip


def test_rays_leave_the_sphere_where_the_geometry_says():
    rng = np.random.default_rng(1)
    centre, radius = np.array([1.0, -2.0, 0.5]), 3.0
    start = centre + np.array([0.5, 0.2, -0.3])
    directions = rng.normal(size=(200, 3))
    hits = _sphere_exit(start, directions, centre, radius)
    np.testing.assert_allclose(np.linalg.norm(hits - centre, axis=1), radius, rtol=1e-12)
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    along = np.einsum("ij,ij->i", hits - start, unit)
    assert (along > 0).all()  # ahead of the camera, never behind it
    np.testing.assert_allclose(hits - start, along[:, None] * unit, atol=1e-12)  # on the ray


def test_the_region_ignores_outliers_and_the_shell_holds_every_camera():
    rng = np.random.default_rng(2)
    means = np.concatenate([rng.uniform(-1, 1, size=(5000, 3)), [[100.0, 0, 0]]])
    region = survey_region(means)
    assert np.allclose(region.centre, 0, atol=0.05) and region.radius == pytest.approx(np.sqrt(3), rel=0.05)
    cameras = _ring(distance=20.0)
    farthest = max(np.linalg.norm(v.center - region.centre) for v in cameras)
    assert farthest == pytest.approx(20.0, abs=0.05)
    assert shell_radius(cameras, region, 8.0) == pytest.approx(2 * farthest, rel=1e-12)  # beyond every camera
    assert shell_radius(_ring(distance=1.0), region, 8.0) == pytest.approx(8 * region.radius)
    assert shell_radius(_ring(distance=1.0), region, 1e5) == MAX_SHELL_M  # SPZ's and the readers' local range
    assert shell_radius(_ring(distance=2e3), region, 1e5) == pytest.approx(4e3)  # but beyond every camera
    with pytest.raises(ConfigError):
        BackgroundOptions(shell_radius=0.5)


def test_background_pixels_are_those_the_foreground_leaves_transparent():
    cameras = _ring(n=1)
    masks = background_masks(cameras, _ball(), 1.0, 0.5)
    mask = masks["v0.png"]
    assert mask.shape == (36, 48)
    assert not mask[18, 24] and mask[0, 0] and mask[-1, -1]  # the ball in the middle, the sky at the corners
    # the ball's silhouette: radius 0.15 m at 1 m with f = 40 px is ~6 px (plus the Gaussians' own extent)
    assert 0.03 < 1 - mask.mean() < 0.25


def test_a_trained_background_draws_the_sky_behind_a_frozen_foreground():
    from fusion.render.scene import render_gaussian_set

    cameras, ball = _ring(n=8), _ball()
    images = {}
    for view in cameras:  # the ball (grey) in front of a uniform sky
        rendered = render_gaussian_set(ball, cameras.camera_of(view), view, background=tuple(SKY))
        images[view.name] = rendered.colour.detach().numpy()
    training = TrainOptions(iterations=120, lr_means=0.0, sh_degree=0, min_iterations=120,
                            strategy=DefaultStrategy(cap=4000, refine_start=40, refine_every=40))  # fmt: skip
    options = BackgroundOptions(max_image_size=48, seed_stride_px=2, training=training)
    result = train_background(cameras, images, ball, options, seed=0)
    assert not isinstance(result, str)
    region = survey_region(ball.means)
    distance = np.linalg.norm(result.gaussians.means - region.centre, axis=1)
    assert distance.min() > 0.5 * result.counts["shell_radius_m"] > 3 * region.radius  # far outside the region
    view = next(iter(cameras))
    alone = render_gaussian_set(ball, cameras.camera_of(view), view).colour.detach().numpy()
    both = GaussianSet.concatenate([ball, result.gaussians])
    drawn = render_gaussian_set(both, cameras.camera_of(view), view).colour.detach().numpy()
    target = images[view.name]
    error_alone, error_both = np.abs(alone - target).mean(), np.abs(drawn - target).mean()
    assert error_both < 0.2 * error_alone, (error_alone, error_both)


def test_nothing_beyond_the_region_trains_nothing():
    cameras = _ring(n=2)
    wall = _ball(radius=0.9, n=6000)  # a shell that fills every view: no background pixel
    wall.log_scales[:] = np.log(0.08)
    images = {v.name: np.full((36, 48, 3), 0.5) for v in cameras}
    result = train_background(cameras, images, wall, BackgroundOptions(max_image_size=48), seed=0)
    assert isinstance(result, str) and "see nothing beyond the survey region" in result


def _pattern(directions: np.ndarray) -> np.ndarray:
    """A smooth colour (N, 3) in [0.1, 0.9] of unit vectors (N, 3): a few cycles per radian."""
    return 0.5 + 0.4 * np.sin(np.stack([7 * directions[:, 0], 5 * directions[:, 1] + 1, 6 * directions[:, 2] + 2], 1))


def _photos_of(cameras: Cameras, backdrop: float | None) -> dict[str, np.ndarray]:
    """Every camera's photo of a pattern drawn on a sphere of radius ``backdrop`` around the origin (the
    pattern a function of the point's direction from the origin), or at infinity (of the ray's direction)."""
    images = {}
    for view in cameras:
        camera = cameras.camera_of(view)
        cols, rows = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
        pixels = np.stack([cols.ravel(), rows.ravel()], axis=1)
        rays = cameras.unproject(view, pixels, 1.0) - view.center
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        if backdrop is not None:
            hits = _sphere_exit(view.center, rays, np.zeros(3), backdrop)
            rays = hits / np.linalg.norm(hits, axis=1, keepdims=True)
        images[view.name] = _pattern(rays).reshape(camera.height, camera.width, 3)
    return images


@pytest.mark.parametrize("backdrop, expected", [(None, 40.0), (5.0, 5.0)])
def test_the_shell_is_chosen_where_the_photos_agree(backdrop, expected):
    cameras = _ring(n=8, distance=1.0)
    images = _photos_of(cameras, backdrop)
    masks = {name: np.ones((18, 24), bool) for name in images}  # nothing of a survey region in front
    region = SurveyRegion(np.zeros(3), 1.0)
    options = BackgroundOptions(shell_radius=(2.5, 5.0, 10.0, 40.0), seed_stride_px=1, min_pairs=50)
    choice = choose_shell_radius(cameras, images, masks, region, options)
    assert choice.decided and choice.multiple == expected and choice.radius == pytest.approx(expected)
    scores = {m: d for m, (d, _) in choice.scores.items()}
    if backdrop is None:  # an environment at infinity: the farther the shell, the better it agrees
        assert scores[2.5] > scores[5.0] > scores[10.0] > scores[40.0]
    else:  # a backdrop at 5 m agrees (up to the nearest-pixel sampling) on a shell of its radius only
        assert 3 * scores[5.0] < min(scores[2.5], scores[10.0], scores[40.0])


def test_too_few_shared_background_pixels_keep_the_first_shell():
    cameras = _ring(n=8, distance=1.0)
    images = _photos_of(cameras, None)
    masks = {name: np.zeros((18, 24), bool) for name in images}
    for mask in masks.values():
        mask[0, 0] = True  # one background pixel a photo: no other photo sees its direction
    region = SurveyRegion(np.zeros(3), 1.0)
    options = BackgroundOptions(shell_radius=(2.5, 40.0), seed_stride_px=1, min_pairs=50)
    choice = choose_shell_radius(cameras, images, masks, region, options)
    assert not choice.decided and choice.multiple == 2.5
    assert shell_disagreement(cameras, images, masks, region, 40.0, 1)[1] < 50
    single = choose_shell_radius(cameras, images, masks, region, BackgroundOptions(shell_radius=8.0))
    assert single.multiple == 8.0 and single.scores == {} and single.radius == pytest.approx(8.0)


def test_a_single_shell_radius_in_a_config_is_still_read():
    from hybridsplat.options import options_from_table

    assert options_from_table(BackgroundOptions, {"shell_radius": 8.0}, "config.toml").radii == (8.0,)
    assert options_from_table(BackgroundOptions, {"shell_radius": [8, 64]}, "config.toml").radii == (8.0, 64.0)
    with pytest.raises(ConfigError):
        BackgroundOptions(shell_radius=(8.0, 0.5))
