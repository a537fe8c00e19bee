"""hybridsplat.tile_surface: splat-surface points found tile by tile are kept from the tile whose core holds them,
their reference views re-indexed to the parent's, their pixel counts summed; the inputs a tile gets are its
bounds' share."""

from __future__ import annotations

import json

import numpy as np

from core.cameras import Camera, Cameras, View
from core.gaussians import GaussianSet
from core.io.gaussian_ply import read_gaussian_ply
from fusion.splat_surface import SplatSurfaceOptions
from hybridsplat.layout import ProjectLayout
from hybridsplat.tile_surface import prepare_tile_surface, stitch_tile_surface
from recon.tiling import TileGrid, TileOptions, plan_tiles


def _plan():
    """2 × 1 tiles over a 100 m × 60 m block: core edge at x = 50 m, 4 m overlap."""
    camera = Camera.pinhole(100.0, 100.0, 100.0, 75.0, 200, 150)
    R = np.diag([1.0, -1.0, -1.0])
    centres = [np.array([x, y, 20.0]) for x in np.arange(-7.0, 110.0, 12.5) for y in np.arange(-6.5, 70.0, 11.0)]
    views = {i + 1: View.from_matrix(i + 1, f"v{i + 1}.jpg", 1, np.c_[R, -R @ c]) for i, c in enumerate(centres)}
    x, y = np.meshgrid(np.arange(0.0, 100.1, 1.0), np.arange(0.0, 60.1, 1.0))
    ground = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    return plan_tiles(Cameras({1: camera}, views), ground, TileOptions(grid=TileGrid(2, 1), overlap_m=4.0,
                                                                       extent_quantile=0.0))  # fmt: skip


def _found(files, positions: np.ndarray, views: list[str], reference: np.ndarray, counts: dict) -> None:
    n = len(positions)
    np.savez(files.found, positions=positions, normals=np.tile([0.0, 0.0, 1.0], (n, 1)),
             colours=np.zeros((n, 3), np.float32), sigma=np.full(n, 0.01), confidence=np.full(n, 0.5),
             n_views=np.full(n, 3, np.int32), reference=reference.astype(np.int32), spread=np.zeros(n),
             footprint=np.zeros(n), views=np.array(views))  # fmt: skip
    files.record.parent.mkdir(parents=True, exist_ok=True)
    files.record.write_text(json.dumps({"counts": counts}))


def test_points_are_kept_from_their_cores_tile_with_the_parents_view_indices(tmp_path):
    plan, rng = _plan(), np.random.default_rng(0)
    parent = ProjectLayout(tmp_path / "project")
    parent_views = ["a.jpg", "b.jpg", "c.jpg", "d.jpg"]
    tile_views = {0: ["a.jpg", "b.jpg", "c.jpg"], 1: ["b.jpg", "c.jpg", "d.jpg"]}
    expected = []
    for t in (0, 1):
        files = ProjectLayout(parent.tile_project(plan.tiles[t].name)).tile_surface_files()
        files.found.parent.mkdir(parents=True, exist_ok=True)
        lo, hi = (0.0, 54.0) if t == 0 else (46.0, 100.0)  # the tile's bounds: its core and the overlap
        positions = np.c_[rng.uniform(lo, hi, 50), rng.uniform(0, 60, 50), np.zeros(50)]
        reference = rng.integers(0, 3, 50)
        _found(files, positions, tile_views[t], reference, {"candidates": 100 + t, "kept": 50})
        own = (positions[:, 0] < 50.0) == (t == 0)
        names = [tile_views[t][r] for r in reference[own]]
        expected.append((positions[own], [parent_views.index(n) for n in names]))
    stitched = stitch_tile_surface(parent, plan, [0, 1], parent_views)
    np.testing.assert_array_equal(stitched.positions, np.concatenate([p for p, _ in expected]))
    np.testing.assert_array_equal(stitched.reference, np.concatenate([r for _, r in expected]))
    assert stitched.counts == {"candidates": 201, "kept": 100}
    assert stitched.normals.shape == (len(stitched), 3)
    empty = stitch_tile_surface(parent, plan, [], parent_views)
    assert len(empty) == 0 and empty.positions.shape == (0, 3)


def test_a_tile_is_given_the_splats_and_points_in_its_bounds(tmp_path):
    plan, rng = _plan(), np.random.default_rng(1)
    parent = ProjectLayout(tmp_path / "project")
    n = 300
    means = np.c_[rng.uniform(0, 100, n), rng.uniform(0, 60, n), np.zeros(n)]
    splats = GaussianSet(means, np.full((n, 3), -2.0, np.float32), np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
                         np.zeros(n, np.float32), np.zeros((n, 3), np.float32), np.zeros((n, 0, 3), np.float32),
                         np.zeros(3))  # fmt: skip
    trusted = np.c_[rng.uniform(0, 100, 80), rng.uniform(0, 60, 80), np.zeros(80)]
    job = prepare_tile_surface(parent, plan, 1, splats, trusted, means, ["b.jpg"], SplatSurfaceOptions())
    files = ProjectLayout(job.root).tile_surface_files()
    inside = means[:, 0] >= 46.0  # tile 1's bounds: its core (x ≥ 50 m) and 4 m of overlap
    np.testing.assert_allclose(read_gaussian_ply(files.splats).means, means[inside], atol=1e-5)
    with np.load(files.points) as points:
        np.testing.assert_array_equal(points["trusted"], trusted[trusted[:, 0] >= 46.0])
        np.testing.assert_array_equal(points["anchors"], means[inside])
    assert job.views == ("b.jpg",) and job.name == plan.tiles[1].name
