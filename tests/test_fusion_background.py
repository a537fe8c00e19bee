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
    fill_unseen_directions,
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


def _ball_before_the_sky(cameras: Cameras, ball: GaussianSet) -> dict[str, np.ndarray]:
    """Every camera's photo of the ball (grey) in front of a uniform sky."""
    from fusion.render.scene import render_gaussian_set

    images = {}
    for view in cameras:
        rendered = render_gaussian_set(ball, cameras.camera_of(view), view, background=tuple(SKY))
        images[view.name] = rendered.colour.detach().numpy()
    return images


def _short_training(iterations: int) -> TrainOptions:
    """A few background steps at SH degree 0, positions frozen, densifying every 40 steps."""
    return TrainOptions(iterations=iterations, lr_means=0.0, sh_degree=0, min_iterations=iterations,
                        strategy=DefaultStrategy(cap=4000, refine_start=40, refine_every=40))  # fmt: skip


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
    images = _ball_before_the_sky(cameras, ball)
    options = BackgroundOptions(max_image_size=48, seed_stride_px=2, training=_short_training(120))
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


def _looking_up(cameras: Cameras) -> Cameras:
    """``cameras`` with one more view: at (1, 0, 0) looking straight up, where no camera of the ring looks."""
    rotation = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # rows: right, down, forward
    up = View.from_matrix(99, "up.png", 1, np.c_[rotation, -rotation @ np.array([1.0, 0.0, 0.0])])
    return Cameras(dict(cameras.cameras), {**cameras.views, 99: up})


@pytest.mark.parametrize("step_deg", [0.0, 3.0])
def test_a_view_turned_past_every_photo_sees_the_sky_continued_not_black(step_deg):
    from fusion.render.scene import render_gaussian_set

    cameras, ball = _ring(n=8), _ball()
    images = _ball_before_the_sky(cameras, ball)
    options = BackgroundOptions(max_image_size=48, seed_stride_px=2, unseen_step_deg=step_deg,
                                training=_short_training(60))  # fmt: skip
    result = train_background(cameras, images, ball, options, seed=0)
    assert not isinstance(result, str)
    # the ring's photos see up to ~24° above the horizon; the zenith view 59°–90°: no photo shows it
    both = _looking_up(cameras)
    up = both.views[99]
    drawn = render_gaussian_set(GaussianSet.concatenate([ball, result.gaussians]), both.camera_of(up), up)
    colour = drawn.colour.detach().numpy().reshape(-1, 3)
    if step_deg == 0:
        assert result.counts["unseen_gaussians"] == 0 and colour.max() < 0.05  # black: nothing drawn there
    else:
        assert result.counts["unseen_gaussians"] > 0
        assert np.abs(colour - SKY).max(axis=1).mean() < 0.05  # the sky's colour, continued


def _cap(centre: np.ndarray, radius: float, rgb: tuple[float, float, float], polar_max_deg: float, n: int = 3000):
    """``n`` small Gaussians of colour ``rgb`` on the sphere of ``radius`` around ``centre``, within
    ``polar_max_deg`` of its north pole (+z), with a ``source`` field of 3."""
    rng = np.random.default_rng(3)
    z = rng.uniform(np.cos(np.radians(polar_max_deg)), 1.0, n)
    azimuth = rng.uniform(0, 2 * np.pi, n)
    ring = np.sqrt(1 - z * z)
    directions = np.stack([ring * np.cos(azimuth), ring * np.sin(azimuth), z], 1)
    return GaussianSet(centre + radius * directions, np.full((n, 3), np.log(0.01 * radius)),
                       np.tile([1.0, 0, 0, 0], (n, 1)), np.full(n, 3.0),
                       np.tile((np.array(rgb) - 0.5) / SH_C0, (n, 1)), np.zeros((n, 3, 3)),
                       origin=np.array([1e5, 2e5, 10.0]), fields={"source": np.full(n, 3, np.uint8)})  # fmt: skip


def test_unseen_directions_are_filled_on_the_shell_with_the_nearest_colours():
    centre, radius = np.array([2.0, -1.0, 0.5]), 50.0
    north = _cap(centre, radius, (0.9, 0.1, 0.1), 60.0)
    south = _cap(centre, radius, (0.1, 0.1, 0.9), 60.0)
    south.means = centre + (south.means - centre) * np.array([1.0, 1.0, -1.0])  # mirrored: around the south pole
    trained = GaussianSet.concatenate([north, south])
    filled = fill_unseen_directions(trained, centre, radius, 4.0)
    offsets = filled.means - centre
    np.testing.assert_allclose(np.linalg.norm(offsets, axis=1), radius, rtol=1e-9)  # on the shell
    polar = np.degrees(np.arccos(offsets[:, 2] / radius))
    # only the band the caps leave open (60°–120° from the north pole), less a margin of twice the step
    assert polar.min() > 60.0 + 4.0 and polar.max() < 120.0 - 4.0
    lattice_in_band = 4 * np.pi / np.radians(4.0) ** 2 * (np.cos(np.radians(68)) - np.cos(np.radians(112))) / 2
    assert 0.6 * lattice_in_band < len(filled) < 1.3 * lattice_in_band
    colours = filled.base_colors
    upper, lower = polar < 80.0, polar > 100.0
    assert (colours[upper, 0] > colours[upper, 2]).all() and (colours[lower, 2] > colours[lower, 0]).all()
    assert np.allclose(colours[:, 1], 0.1, atol=1e-3)  # never a colour outside its neighbours'
    assert filled.sh_degree == 1 and not filled.sh_rest.any()  # no view-dependent colour invented
    np.testing.assert_array_equal(filled.origin, trained.origin)
    assert set(filled.fields) == {"source"} and len(filled.fields["source"]) == len(filled)
    whole = _cap(centre, radius, (0.5, 0.5, 0.5), 180.0, n=40000)
    assert len(fill_unseen_directions(whole, centre, radius, 4.0)) == 0  # every direction covered: nothing to add
    with pytest.raises(ConfigError):
        BackgroundOptions(unseen_step_deg=-1.0)


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
