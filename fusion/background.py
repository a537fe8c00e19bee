"""The background layer: what the photos see beyond the survey region (sky, a backdrop, distant surroundings).

A training pixel is *background* when its ray leaves the survey region without meeting the cloud: the survey and
fill Gaussians, rendered from its photo, leave it (nearly) transparent (accumulated opacity below
``alpha_threshold``). Background Gaussians are seeded where those rays meet a far sphere around the survey region
(``shell_radius`` × the region's radius, centred on it; among several candidate radii the one on which the photos'
background pixels agree best, :func:`choose_shell_radius`) and trained at reduced resolution on the background pixels
only, with the survey and fill Gaussians frozen in front of them. Their positions stay on the shell (learning rate
0), so no background Gaussian ever enters the survey region; an environment at infinity (a sky) is drawn without
parallax error from any viewpoint well inside the shell. They are never part of a survey product (C2C, LAS and
point exports, mesh, measurement): the ``source`` field marks them ``Source.BACKGROUND``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from core.cameras import Cameras
from core.constraints import AnyOf, Constrained, Constraints, Interval, SequenceOf
from core.errors import ConfigError
from core.gaussians import SH_C0, GaussianSet, logit
from fusion.train.options import TrainOptions
from fusion.train.strategy import DefaultStrategy


def _background_training() -> TrainOptions:
    return TrainOptions(
        iterations=300,
        sh_degree=1,
        sh_degree_interval=100,
        lr_means=0.0,
        min_iterations=300,
        refine_until=0.5,
        strategy=DefaultStrategy(cap=20_000, refine_start=50, refine_every=50),
    )


@dataclass(frozen=True)
class BackgroundOptions(Constrained):
    """Options of :func:`train_background` (the ``background`` stage's options).

    enabled: train a background layer when the photos see beyond the survey region. shell_radius: radius of the
    seeding sphere in multiples of the survey region's radius (half the diagonal of the 1st–99th percentile box of
    the survey Gaussians), never nearer than twice the farthest camera, nor farther than :data:`MAX_SHELL_M` unless
    the cameras are; several values are candidates, of which the one whose shell points agree best in colour
    across the training photos is taken (:func:`choose_shell_radius`: a far environment, a sky, is drawn without
    parallax only on a far shell; a nearer backdrop agrees at its own depth), the first when fewer than
    ``min_pairs`` photo pairs decide. max_image_size: longer side of the training
    photos (px): the background is smooth and far, a reduced resolution suffices. seed_stride_px: one seed per this
    many pixels in each direction of the background pixels (at training resolution). max_seeds: at most this many
    seeds (an even random subset).
    alpha_threshold: a pixel whose survey + fill accumulated opacity is below this is background. min_share: no
    background layer when the background pixels are less than this share of every training pixel. min_pairs: the
    fewest (background pixel, other photo) pairs that choose among several shell radii. unseen_step_deg: after
    training, directions of the shell that no background Gaussian covers (beyond every photo's frame, or hidden
    behind the survey region in every photo that frames them) get Gaussians this many degrees apart, coloured from
    the nearest trained ones (:func:`fill_unseen_directions`), so that a viewer turned past the photos shows a
    continuation of the surroundings instead of black; 0 leaves them empty.
    training: the trainer's options (positions frozen: ``lr_means`` 0; the cap grows from the seeds).

    The defaults were not tuned on any view a figure is scored on: 160 px (the background is smooth), 300 steps (a
    tenth of the fill's budget), SH degree 1 (a sky's gradient) set before any measurement; the shell's candidate
    radii (8 – the radius before the choice – to 512, at which a camera baseline of the region's size moves a far
    environment by about 0.1°) and ``min_pairs`` were chosen on the tuning layouts random-object 0 and random-aerial
    0–2 (docs/experiments/2026-11-28-background-shell.md); ``unseen_step_deg`` 2° was set before any measurement (about
    twice the seeds' spacing: every 3rd pixel at 160 px, ~1.1° across a 60° view) and checked on those tuning layouts
    only (docs/experiments/2026-11-28-unseen-directions.md §3).
    """

    enabled: bool = True
    shell_radius: float | tuple[float, ...] = (8.0, 32.0, 128.0, 512.0)
    max_image_size: int = 160
    seed_stride_px: int = 3
    max_seeds: int = 20_000
    alpha_threshold: float = 0.5
    min_share: float = 0.002
    min_pairs: int = 200
    unseen_step_deg: float = 2.0
    training: TrainOptions = field(default_factory=_background_training)

    constraints: ClassVar[Constraints] = {
        "shell_radius": AnyOf(
            Interval(float, 1, math.inf, closed="right"),
            SequenceOf(Interval(float, 1, math.inf, closed="right"), min_length=1),
        ),
        "max_image_size": Interval(int, 16, None),
        "seed_stride_px": Interval(int, 1, None),
        "max_seeds": Interval(int, 1, None),
        "alpha_threshold": Interval(float, 0, 1, closed="neither"),
        "min_share": Interval(float, 0, 1, closed="left"),
        "min_pairs": Interval(int, 1, None),
        "unseen_step_deg": Interval(float, 0, 30),
    }

    @property
    def radii(self) -> tuple[float, ...]:
        """The candidate shell radii (multiples of the region's radius), in the order given."""
        return tuple(self.shell_radius) if isinstance(self.shell_radius, tuple) else (float(self.shell_radius),)


@dataclass(frozen=True)
class SurveyRegion:
    """The sphere that bounds the survey region: centre (local frame, metres) and radius (metres)."""

    centre: np.ndarray
    radius: float


def survey_region(means: np.ndarray) -> SurveyRegion:
    """The region of the survey Gaussians ``means`` (N, 3): the box of their 1st–99th percentiles per axis (a few
    outliers far out do not inflate it), its centre and half its diagonal."""
    if len(means) == 0:
        raise ConfigError("no survey Gaussians: the survey region is undefined")
    low, high = np.percentile(means, 1, axis=0), np.percentile(means, 99, axis=0)
    return SurveyRegion((low + high) / 2, max(float(np.linalg.norm(high - low)) / 2, 1e-6))


def background_masks(
    cameras: Cameras, foreground: GaussianSet, scale: float, alpha_threshold: float
) -> dict[str, np.ndarray]:
    """Per view (name → (H, W) bool at ``scale`` × the camera's size): pixels the ``foreground`` Gaussians (survey +
    fill, in the cameras' local frame) leave with accumulated opacity below ``alpha_threshold``."""
    from fusion.render.scene import render_gaussian_set

    masks = {}
    for view in cameras:
        camera = cameras.camera_of(view).scaled(scale)
        result = render_gaussian_set(foreground, camera, view, cameras_origin=cameras.origin, background=(0, 0, 0))
        masks[view.name] = result.alpha.detach().cpu().numpy() < alpha_threshold
    return masks


def shell_seeds(
    cameras: Cameras,
    images: Mapping[str, np.ndarray],
    masks: Mapping[str, np.ndarray],
    region: SurveyRegion,
    radius: float,
    options: BackgroundOptions,
    seed: int,
) -> GaussianSet:
    """Degree-0 Gaussians where the rays of background pixels (every ``seed_stride_px``-th, at the masks' scale)
    meet the sphere of ``radius`` (metres) around ``region.centre``, coloured by their pixel; at most
    ``max_seeds`` (an even random subset, ``seed``)."""
    from fusion.train.init import gaussians_from_points

    points, colours = [], []
    for view in cameras:
        if view.name not in images:
            continue
        pixels, hits = _shell_points(cameras, view, masks.get(view.name), options.seed_stride_px, region, radius)
        if len(pixels):
            points.append(hits)
            colours.append(_colours_at(images[view.name], pixels))
    if not points:
        raise ConfigError("no background pixel in any training photo: nothing to seed")
    points_all, colours_all = np.concatenate(points), np.concatenate(colours)
    if len(points_all) > options.max_seeds:
        keep = np.sort(np.random.default_rng(seed).choice(len(points_all), options.max_seeds, replace=False))
        points_all, colours_all = points_all[keep], colours_all[keep]
    return gaussians_from_points(points_all, colours_all, None, cameras.origin)


def _shell_points(
    cameras: Cameras, view: Any, mask: np.ndarray | None, stride: int, region: SurveyRegion, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres (N, 2; the camera's full-size pixels) of every ``stride``-th background pixel of ``mask`` (at
    its own, reduced scale) and where their rays leave the sphere of ``radius`` around ``region.centre`` (N, 3);
    none when the view has no mask."""
    if mask is None or not mask.any():
        return np.zeros((0, 2)), np.zeros((0, 3))
    camera = cameras.camera_of(view)
    rows, cols = np.nonzero(mask[::stride, ::stride])
    sy, sx = mask.shape[0] / camera.height, mask.shape[1] / camera.width
    pixels = np.stack([(cols * stride + 0.5) / sx, (rows * stride + 0.5) / sy], axis=1)
    ends = cameras.unproject(view, pixels, 1.0)
    return pixels, _sphere_exit(view.center, ends - view.center, region.centre, radius)


def _colours_at(image: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """RGB in [0, 1] (N, 3) of ``image`` at ``pixels`` (N, 2; x, y in the image's own pixels; nearest pixel)."""
    iy = np.clip(pixels[:, 1].astype(int), 0, image.shape[0] - 1)
    ix = np.clip(pixels[:, 0].astype(int), 0, image.shape[1] - 1)
    return _as_unit(np.asarray(image)[iy, ix][:, :3])


def shell_disagreement(
    cameras: Cameras,
    small_images: Mapping[str, np.ndarray],
    masks: Mapping[str, np.ndarray],
    region: SurveyRegion,
    radius: float,
    stride: int,
) -> tuple[float, int]:
    """How badly a shell of ``radius`` (metres) draws the background: the mean absolute colour difference (RGB in
    [0, 1], averaged over channels) between every ``stride``-th background pixel of each photo and the pixel its
    point on the shell projects to in every other photo, where that projection lies ahead of the photo, inside it
    and on its background pixels; and the number of such pairs. ``small_images``: the photos at their masks' size.

    Hand-written: MVS's photo-consistency scores surfaces; this scores a candidate depth for pixels that see no
    surface of the survey region, against the other photos' background pixels only."""
    total, pairs = 0.0, 0
    views = [v for v in cameras if v.name in masks and v.name in small_images]
    for view in views:
        pixels, points = _shell_points(cameras, view, masks[view.name], stride, region, radius)
        if not len(pixels):
            continue
        colours = _colours_at(small_images[view.name], pixels * _mask_scale(cameras, view, masks[view.name]))
        for other in views:
            if other.name == view.name:
                continue
            mask = masks[other.name]
            uv, depth = cameras.project(other, points)
            at = np.nan_to_num(uv * _mask_scale(cameras, other, mask), nan=-1.0, posinf=-1.0, neginf=-1.0)
            inside = (depth > 0) & (at >= 0).all(axis=1) & (at[:, 0] < mask.shape[1]) & (at[:, 1] < mask.shape[0])
            inside[inside] = mask[at[inside, 1].astype(int), at[inside, 0].astype(int)]
            if inside.any():
                total += float(np.abs(_colours_at(small_images[other.name], at[inside]) - colours[inside]).sum()) / 3
                pairs += int(inside.sum())
    return (total / pairs if pairs else float("inf")), pairs


def _mask_scale(cameras: Cameras, view: Any, mask: np.ndarray) -> np.ndarray:
    camera = cameras.camera_of(view)
    return np.array([mask.shape[1] / camera.width, mask.shape[0] / camera.height])


@dataclass(frozen=True)
class ShellChoice:
    """The shell the background is seeded on: its ``multiple`` of the region's radius and ``radius`` (metres);
    ``scores``: per candidate multiple, (disagreement, pairs) of :func:`shell_disagreement` (empty for one
    candidate); ``decided``: whether the pairs sufficed (else the first candidate)."""

    multiple: float
    radius: float
    scores: dict[float, tuple[float, int]]
    decided: bool


def choose_shell_radius(
    cameras: Cameras,
    images: Mapping[str, np.ndarray],
    masks: Mapping[str, np.ndarray],
    region: SurveyRegion,
    options: BackgroundOptions,
) -> ShellChoice:
    """Among ``options.radii``, the shell whose points agree best in colour across the training photos (``images``:
    full size; ``masks``: their background pixels at reduced size); the first candidate when any candidate has
    fewer than ``options.min_pairs`` pairs (too few background pixels that two photos share to choose)."""
    import cv2

    radii = options.radii
    if len(radii) == 1:
        return ShellChoice(radii[0], shell_radius(cameras, region, radii[0]), {}, False)
    small = {name: cv2.resize(_as_unit(images[name]).astype(np.float32), mask.shape[::-1], interpolation=cv2.INTER_AREA)
             for name, mask in masks.items() if name in images}  # fmt: skip
    by_metres: dict[float, tuple[float, int]] = {}
    scores = {}
    for multiple in radii:
        metres = shell_radius(cameras, region, multiple)
        if metres not in by_metres:
            by_metres[metres] = shell_disagreement(cameras, small, masks, region, metres, options.seed_stride_px)
        scores[multiple] = by_metres[metres]
    decided = min(pairs for _, pairs in scores.values()) >= options.min_pairs
    best = min(radii, key=lambda m: scores[m][0]) if decided else radii[0]
    return ShellChoice(best, shell_radius(cameras, region, best), scores, decided)


MAX_SHELL_M = 2000.0
"""The farthest a shell is put from the region's centre (metres) unless the cameras are farther: SPZ keeps its
0.24 mm position step within ±2 048 m of the local origin, and the PLY readers re-base local coordinates beyond
10 km; a shell at 2 km moves a far environment by 0.3° for a 10 m camera baseline."""


def shell_radius(cameras: Cameras, region: SurveyRegion, multiple: float) -> float:
    """Radius (metres) of the seeding sphere: ``multiple`` × the region's radius, at most :data:`MAX_SHELL_M`, and
    at least twice the distance of the farthest camera from the region's centre (every camera inside the shell, far
    from it)."""
    farthest = max(float(np.linalg.norm(view.center - region.centre)) for view in cameras)
    return max(min(multiple * region.radius, MAX_SHELL_M), 2.0 * farthest)


def _as_unit(pixels: np.ndarray) -> np.ndarray:
    values = np.asarray(pixels, dtype=np.float64)
    return values / 255.0 if np.issubdtype(np.asarray(pixels).dtype, np.integer) else values


def _sphere_exit(start: np.ndarray, directions: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Where rays from ``start`` (3,) along ``directions`` (N, 3) leave the sphere (``start`` lies inside it)."""
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    offset = start - centre
    b = d @ offset
    c = float(offset @ offset) - radius**2
    t = -b + np.sqrt(np.maximum(b * b - c, 0.0))
    return start + t[:, None] * d


def fill_unseen_directions(
    trained: GaussianSet, centre: np.ndarray, radius: float, step_deg: float, neighbours: int = 8
) -> GaussianSet:
    """Gaussians on the sphere of ``radius`` (metres) around ``centre`` (the local frame of ``trained``) at the
    directions of a near-uniform lattice ``step_deg`` apart that no Gaussian of ``trained`` covers (its nearest one,
    as seen from ``centre``, farther than twice the step and three of that one's σ). Each is isotropic with σ =
    0.6 step (neighbours overlap) and opacity 0.95, its colour the inverse-square-distance mean of the base colours
    of its ``neighbours`` nearest trained Gaussians, without view-dependent colour; ``trained``'s SH degree, origin
    and fields (zero). An extrapolation: no photo shows these directions, so their Gaussians only stand in for black.
    """
    from scipy.spatial import cKDTree

    from fusion.sphere_lattice import fibonacci_sphere

    k = min(neighbours, len(trained))
    if k == 0:
        return trained.subset(np.zeros(0, dtype=int))
    offsets = trained.means - centre
    distances = np.maximum(np.linalg.norm(offsets, axis=1), 1e-9)
    lattice = fibonacci_sphere(max(int(4.0 * np.pi / np.radians(step_deg) ** 2), 1))
    gaps, nearest = cKDTree(offsets / distances[:, None]).query(lattice, k=k)
    gaps, nearest = gaps.reshape(len(lattice), k), nearest.reshape(len(lattice), k)
    angular_sigma = trained.scales.max(axis=1) / distances  # radians; chords ≈ angles at these sizes
    step = np.radians(step_deg)
    uncovered = gaps[:, 0] > np.maximum(2.0 * step, 3.0 * angular_sigma[nearest[:, 0]])
    weights = 1.0 / np.maximum(gaps[uncovered], 1e-9) ** 2
    colours = np.einsum("nk,nkc->nc", weights, trained.base_colors[nearest[uncovered]]) / weights.sum(1)[:, None]
    n = int(uncovered.sum())
    return GaussianSet(
        centre + radius * lattice[uncovered],
        np.full((n, 3), np.log(0.6 * step * radius)),
        np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
        np.full(n, float(logit(np.array(0.95)))),
        (colours - 0.5) / SH_C0,
        np.zeros((n, trained.sh_rest.shape[1], 3)),  # type: ignore[union-attr]
        trained.origin.copy(),
        {name: np.zeros(n, dtype=values.dtype) for name, values in trained.fields.items()},
    )


@dataclass
class BackgroundResult:
    """The trained background Gaussians (local frame of the cameras), the trainer's result and counts."""

    gaussians: GaussianSet
    training: Any
    counts: dict[str, Any]


def train_background(
    cameras: Cameras,
    images: Mapping[str, np.ndarray],
    foreground: GaussianSet,
    options: BackgroundOptions,
    seed: int,
    progress: Callable[[Any], None] | None = None,
) -> BackgroundResult | str:
    """Train the background layer of ``images`` (name → (H, W, 3) photo at its camera's size) behind the frozen
    ``foreground`` (survey + fill Gaussians, cameras' local frame); the reason when there is none to train."""
    from fusion.train.masked import training_downscale
    from fusion.train.trainer import train_splats

    downscale = training_downscale(cameras, 1, options.max_image_size)
    masks = background_masks(cameras, foreground, 1.0 / downscale, options.alpha_threshold)
    share = sum(int(m.sum()) for m in masks.values()) / max(sum(m.size for m in masks.values()), 1)
    if share < options.min_share:
        return f"the photos see nothing beyond the survey region ({100 * share:.2f} % of the pixels)"
    region = survey_region(foreground.with_origin(cameras.origin).means)
    shell = choose_shell_radius(cameras, images, masks, region, options)
    seeds = shell_seeds(cameras, images, masks, region, shell.radius, options, seed)
    full = {name: _upsample(mask, images[name].shape[:2]) for name, mask in masks.items() if name in images}
    training = options.training
    cap = max(training.strategy.cap, 2 * len(seeds)) if isinstance(training.strategy, DefaultStrategy) else None
    strategy = replace(training.strategy, cap=cap) if cap is not None else training.strategy
    train_opts = replace(training, downscale=downscale, seed=seed, strategy=strategy)
    result = train_splats(cameras, images, full, seeds, foreground, train_opts, progress)
    trained = result.splats
    unseen = trained.subset(np.zeros(0, dtype=int))
    if options.unseen_step_deg > 0:
        unseen = fill_unseen_directions(trained, region.centre, shell.radius, options.unseen_step_deg)
    counts = {"share": share, "seeds": len(seeds), "gaussians": len(trained) + len(unseen), "downscale": downscale,
              "shell_radius_m": shell.radius, "shell_multiple": shell.multiple, "shell_decided": shell.decided,
              "shell_scores": {f"{m:g}": {"disagreement": d, "pairs": n} for m, (d, n) in shell.scores.items()},
              "region_radius_m": region.radius, "unseen_gaussians": len(unseen),
              "iterations": result.iterations, "stopped_early": result.stopped_early,
              "holdout_psnr_db": result.history[-1].holdout_psnr if result.history else None}  # fmt: skip
    return BackgroundResult(GaussianSet.concatenate([trained, unseen]), result, counts)


def _upsample(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A mask at reduced size, at ``shape`` (nearest pixel)."""
    rows = np.minimum((np.arange(shape[0]) + 0.5) * mask.shape[0] / shape[0], mask.shape[0] - 1).astype(int)
    cols = np.minimum((np.arange(shape[1]) + 0.5) * mask.shape[1] / shape[1], mask.shape[1] - 1).astype(int)
    return mask[np.ix_(rows, cols)]
