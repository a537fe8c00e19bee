"""hybridsplat.tile_appearance: the appearance stage's tile-by-tile fit — each Gaussian takes what the tile whose
core holds it refined, the covered-pixel masks, and the fit's masks and fixed layer (what a tile's fit relies on)."""

from __future__ import annotations

import numpy as np
import pytest

from core.cameras import Camera, Cameras, View
from core.errors import DataError
from core.gaussians import GaussianSet
from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply
from fusion.appearance import AppearanceOptions, refine_survey_appearance
from hybridsplat.layout import ProjectLayout
from hybridsplat.tile_appearance import (
    covered_pixels,
    prepare_tile_appearance,
    rows_in_tile,
    stitch_tile_appearance,
)
from recon.tiling import TileGrid, TileOptions, plan_tiles


def _nadir(image_id: int, centre: np.ndarray) -> View:
    R = np.diag([1.0, -1.0, -1.0])  # looking straight down
    return View.from_matrix(image_id, f"img_{image_id:03d}.jpg", 1, np.c_[R, -R @ centre])


def _block_plan():
    """A 2 × 1 plan over a 100 m × 60 m block (core edge at x = 50 m, 4 m overlap), nadir photos over it."""
    camera = Camera.pinhole(100.0, 100.0, 100.0, 75.0, 200, 150)
    centres = [np.array([x, y, 20.0]) for x in np.arange(-7.0, 110.0, 12.5) for y in np.arange(-6.5, 70.0, 11.0)]
    cameras = Cameras({1: camera}, {i + 1: _nadir(i + 1, c) for i, c in enumerate(centres)})
    x, y = np.meshgrid(np.arange(0.0, 100.1, 1.0), np.arange(0.0, 60.1, 1.0))
    ground = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    return plan_tiles(cameras, ground, TileOptions(grid=TileGrid(2, 1), overlap_m=4.0, extent_quantile=0.0))


def _gaussians(n: int, rng: np.random.Generator, degree: int = 0) -> GaussianSet:
    means = np.c_[rng.uniform(0, 100, n), rng.uniform(0, 60, n), rng.uniform(-0.5, 0.5, n)]
    rest = np.zeros((n, (degree + 1) ** 2 - 1, 3), np.float32)
    return GaussianSet(means, np.full((n, 3), -2.0, np.float32), np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
                       np.zeros(n, np.float32), rng.uniform(-1, 1, (n, 3)).astype(np.float32), rest,
                       np.array([500_000.0, 5_000_000.0, 100.0]))  # fmt: skip


def _refine_as_tile(layout: ProjectLayout, tile: int, drop_last: bool = False) -> None:
    """What a tile's fit would write, marked: opacity logit = 10 + tile, SH degree 1 with its first band = tile."""
    files = layout.tile_appearance_files()
    for source, target in ((files.survey, files.survey_refined), (files.fill, files.fill_refined)):
        part = read_gaussian_ply(source).with_sh_degree(1)
        part.logit_opacities[:] = 10.0 + tile
        part.sh_rest[:] = float(tile)
        if drop_last:
            part = part.subset(np.arange(len(part) - 1))
        write_gaussian_ply(target, part)


def test_each_gaussian_takes_what_the_tile_whose_core_holds_it_refined(tmp_path):
    plan, rng = _block_plan(), np.random.default_rng(3)
    parent = ProjectLayout(tmp_path / "project")
    survey, fill = _gaussians(400, rng), _gaussians(150, rng, degree=1)
    for t in range(2):
        prepare_tile_appearance(parent, plan, t, survey, fill, ["a.jpg", "b.jpg"], AppearanceOptions(), 0, False)
        layout = ProjectLayout(parent.tile_project(plan.tiles[t].name))
        given = read_gaussian_ply(layout.tile_appearance_files().survey)
        inside = plan.in_bounds(survey.means, t)
        assert 0 < len(given) == inside.sum() < len(survey)  # the tile's bounds, not the block
        np.testing.assert_allclose(given.with_origin(survey.origin).means, survey.means[inside], atol=1e-5)
        _refine_as_tile(layout, t)
    stitched = stitch_tile_appearance(parent, plan, [0, 1], survey, fill, degree=1)
    for name, layer, out in (("survey", survey, stitched.survey), ("fill", fill, stitched.fill)):
        owner = np.where(layer.means[:, 0] < 50.0, 0, 1)  # the core edge, independent of the plan's code
        np.testing.assert_array_equal(out.logit_opacities, 10.0 + owner, err_msg=name)
        np.testing.assert_array_equal(out.sh_rest[:, :, 0], np.repeat(owner[:, None], 3, axis=1), err_msg=name)
        np.testing.assert_array_equal(out.means, layer.means, err_msg=name)  # positions bit for bit
        np.testing.assert_array_equal(out.sh_dc, layer.sh_dc, err_msg=name)
        assert getattr(stitched, f"{name}_unrefined") == 0
    # a tile that did not finish: its core's Gaussians keep their own attributes, and are counted
    only_first = stitch_tile_appearance(parent, plan, [0], survey, fill, degree=1)
    right = survey.means[:, 0] >= 50.0
    np.testing.assert_array_equal(only_first.survey.logit_opacities[right], 0.0)
    assert only_first.survey_unrefined == int(right.sum())


def test_a_refined_file_without_its_inputs_rows_is_refused_naming_it(tmp_path):
    plan, rng = _block_plan(), np.random.default_rng(4)
    parent = ProjectLayout(tmp_path / "project")
    survey = _gaussians(200, rng)
    prepare_tile_appearance(parent, plan, 0, survey, None, ["a.jpg"], AppearanceOptions(), 0, False)
    layout = ProjectLayout(parent.tile_project(plan.tiles[0].name))
    files = layout.tile_appearance_files()
    assert not files.fill.exists()
    part = read_gaussian_ply(files.survey)
    write_gaussian_ply(files.survey_refined, part.subset(np.arange(len(part) - 1)))
    with pytest.raises(DataError, match="tile_survey_refined.ply"):
        stitch_tile_appearance(parent, plan, [0], survey, None, degree=0)
    assert len(rows_in_tile(plan, 0, None)) == 0


def _one_view(width: int = 40, height: int = 30) -> Cameras:
    camera = Camera.pinhole(40.0, 40.0, width / 2, height / 2, width, height)
    return Cameras({1: camera}, {1: View.from_matrix(1, "v.png", 1, np.c_[np.eye(3), np.zeros(3)])})


def _splats(means: np.ndarray, sigma: float, opacity: float) -> GaussianSet:
    n = len(means)
    logit = np.float32(np.log(opacity / (1 - opacity)))
    return GaussianSet(np.asarray(means, np.float64), np.full((n, 3), np.log(sigma), np.float32),
                       np.tile(np.float32([1, 0, 0, 0]), (n, 1)), np.full(n, logit, np.float32),
                       np.zeros((n, 3), np.float32), np.zeros((n, 0, 3), np.float32), np.zeros(3))  # fmt: skip


def test_covered_pixels_are_where_the_content_is_nearly_opaque():
    cameras = _one_view()
    # an opaque splat 1 m ahead, σ 0.05 m: 2 px at f = 40 px; its 3σ disc covers the image centre, not the corners
    masks = covered_pixels(cameras, _splats(np.array([[0.0, 0.0, 1.0]]), 0.05, 0.99))
    mask = masks["v.png"]
    assert mask.shape == (30, 40) and mask[15, 20] and not mask[0, 0] and not mask[29, 39]
    assert mask.sum() < 0.1 * mask.size
    faint = covered_pixels(cameras, _splats(np.array([[0.0, 0.0, 1.0]]), 0.05, 0.3))["v.png"]
    assert not faint.any()  # α 0.3 < 0.5 everywhere


def test_the_fit_changes_nothing_outside_its_masks_and_keeps_the_fixed_layer_frozen():
    cameras = _one_view()
    left, right = np.array([[-0.3, 0.0, 1.0]]), np.array([[0.3, 0.0, 1.0]])  # 12 px either side of the centre
    survey = GaussianSet.concatenate([_splats(left, 0.05, 0.9), _splats(right, 0.05, 0.9)])
    fixed = _splats(np.array([[0.0, 0.0, 5.0]]), 1.0, 0.9)  # far behind both, over the whole image
    image = np.zeros((30, 40, 3), np.float32)
    image[..., 0] = 1.0  # red: the fit changes the colours it sees
    mask = np.zeros((30, 40), bool)
    mask[:, :20] = True  # the left half: the left splat only (its 3σ = 6 px stays inside)
    from dataclasses import replace

    options = AppearanceOptions(max_image_size=0, max_passes=0)
    options = replace(options, training=replace(options.training, iterations=20, min_iterations=20, sh_degree=0))
    result = refine_survey_appearance(cameras, {"v.png": image}, survey, None, options, seed=0,
                                      masks={"v.png": mask}, fixed=fixed)  # fmt: skip
    out = result.gaussians
    assert len(out) == 2 and result.context is None
    assert not np.allclose(out.sh_dc[0], survey.sh_dc[0])  # fitted to red
    for attr in ("sh_dc", "logit_opacities", "log_scales", "quats"):
        np.testing.assert_array_equal(getattr(out, attr)[1], getattr(survey, attr)[1], err_msg=attr)
    np.testing.assert_array_equal(out.means, survey.means)


def test_a_tile_gets_the_untiled_fits_steps_in_its_share_of_the_photos():
    from hybridsplat.tile_appearance import tile_budget

    options = AppearanceOptions()  # 2 000 steps, at most 84 passes over the photos
    assert options.training.iterations == 2000 and options.max_passes == 84
    tile = tile_budget(options, 88, 120)  # the block: 120 training photos, 2 000 steps untiled
    assert tile.training.iterations == round(2000 * 88 / 120) and tile.max_passes == 0
    few = tile_budget(options, 4, 10)  # 10 photos: 840 steps untiled (84 passes), 4 of them in the tile
    assert few.training.iterations == 336 and few.training.min_iterations == 336
    assert tile_budget(options, 1, 10_000).training.iterations == 1
