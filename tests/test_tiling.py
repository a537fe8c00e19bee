"""recon.tiling: tile plans over a constructed 100 m × 60 m survey, photo assignment, stitching by core ownership,
the seam check and the plan file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.cameras import Camera, CameraModel, Cameras, View
from core.errors import ConfigError, DataError, FormatError, InputFileError
from data_synth.rig import look_at
from recon.tiling import (
    Rect,
    TileGrid,
    TileOptions,
    TilePoints,
    auto_grid,
    parse_tiles,
    plan_tiles,
    points_seen_per_tile,
    read_tile_plan,
    seam_check,
    stitch_by_core,
    write_tile_plan,
)

HEIGHT_M = 20.0  # flying height above the ground (z = 0)
F_PX, W_PX, H_PX = 100.0, 200, 150  # nadir footprint from 20 m: 40 m × 30 m
# camera centres chosen so that no footprint side falls on a core edge of the grids tested (0, 25, 33.3, 50, ...)
CENTRES_X = np.arange(-7.0, 110.0, 12.5)  # 10 columns
CENTRES_Y = np.arange(-6.5, 70.0, 11.0)  # 7 rows


def _ground_points(spacing: float = 1.0) -> np.ndarray:
    """(N, 3) float64 grid of ground points over [0, 100] × [0, 60] m at z = 0."""
    x, y = np.meshgrid(np.arange(0.0, 100.0 + 1e-9, spacing), np.arange(0.0, 60.0 + 1e-9, spacing))
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def _nadir(image_id: int, centre: np.ndarray) -> View:
    """A photo looking straight down: camera x = world x, camera y = -world y, camera z = -world z."""
    R = np.diag([1.0, -1.0, -1.0])
    return View.from_matrix(image_id, f"img_{image_id:03d}.jpg", 1, np.c_[R, -R @ centre])


def _survey() -> Cameras:
    """70 nadir photos over the block, one far outside it and one looking up at the sky above it."""
    camera = Camera.pinhole(F_PX, F_PX, W_PX / 2, H_PX / 2, W_PX, H_PX)
    views = {}
    for cy in CENTRES_Y:
        for cx in CENTRES_X:
            i = len(views) + 1
            views[i] = _nadir(i, np.array([cx, cy, HEIGHT_M]))
    outside = len(views) + 1
    views[outside] = _nadir(outside, np.array([200.0, 30.0, HEIGHT_M]))
    sky = len(views) + 1
    views[sky] = View.from_matrix(sky, "sky.jpg", 1, np.c_[np.eye(3), -np.array([50.0, 30.0, HEIGHT_M])])
    return Cameras({1: camera}, views)


def _footprint_rect(view: View) -> Rect:
    """The exact ground footprint of a nadir photo (pinhole, principal point at the centre)."""
    cx, cy, cz = view.center
    half_u, half_v = cz * (W_PX / 2) / F_PX, cz * (H_PX / 2) / F_PX
    return Rect(cx - half_u, cx + half_u, cy - half_v, cy + half_v)


def _overlap_area(a: Rect, b: Rect) -> float:
    return max(0.0, min(a.u1, b.u1) - max(a.u0, b.u0)) * max(0.0, min(a.v1, b.v1) - max(a.v0, b.v0))


def _truth(cameras: Cameras, core: Rect) -> set[int]:
    """Photos that see the core: a nadir view whose footprint shares area with it (the sky view sees nothing)."""
    return {v.image_id for v in cameras if v.name != "sky.jpg" and _overlap_area(_footprint_rect(v), core) > 0}


EXACT = dict(extent_quantile=0.0)  # the region = the points' bounding box (the tests' points have no outliers)


@pytest.mark.parametrize("columns,rows", [(1, 1), (2, 2), (3, 2), (4, 3)], ids=["1x1", "2x2", "3x2", "4x3"])
def test_grid_plans_cover_the_region_exactly_with_the_stated_overlap(columns, rows):
    points = _ground_points()
    plan = plan_tiles(_survey(), points, TileOptions(grid=TileGrid(columns, rows), overlap_m=4.0, **EXACT))
    assert (plan.columns, plan.rows, len(plan.tiles)) == (columns, rows, columns * rows)
    assert plan.region == Rect(0.0, 100.0, 0.0, 60.0)
    assert plan.u_edges[0] == 0.0 and plan.u_edges[-1] == 100.0 and plan.v_edges[0] == 0.0 and plan.v_edges[-1] == 60.0
    assert np.allclose(np.diff(plan.u_edges), 100.0 / columns) and np.allclose(np.diff(plan.v_edges), 60.0 / rows)
    area = 0.0
    for tile in plan.tiles:
        assert tile.index == tile.row * columns + tile.column
        if tile.column + 1 < columns:  # neighbours share an edge exactly: no gap, no overlap of cores
            assert tile.core.u1 == plan.tiles[tile.index + 1].core.u0
        if tile.row + 1 < rows:
            assert tile.core.v1 == plan.tiles[tile.index + columns].core.v0
        assert tile.bounds == tile.core.grown(4.0) and plan.overlap_m == 4.0
        area += (tile.core.u1 - tile.core.u0) * (tile.core.v1 - tile.core.v0)
        # the tile's sparse points: inside core ± 4 m, the region's outer sides open
        u, v = points[:, 0], points[:, 1]
        lo_u = -np.inf if tile.column == 0 else tile.core.u0 - 4.0
        hi_u = np.inf if tile.column == columns - 1 else tile.core.u1 + 4.0
        lo_v = -np.inf if tile.row == 0 else tile.core.v0 - 4.0
        hi_v = np.inf if tile.row == rows - 1 else tile.core.v1 + 4.0
        expected = (u >= lo_u) & (u <= hi_u) & (v >= lo_v) & (v <= hi_v)
        assert np.array_equal(plan.in_bounds(points, tile.index), expected)
        assert tile.n_points == int(expected.sum())
    assert area == pytest.approx(100.0 * 60.0, rel=1e-12)
    owners = plan.owner(points)  # every point has exactly one owner, and it is inside that tile's bounds
    assert owners.min() == 0 and owners.max() == columns * rows - 1
    assert all(plan.in_bounds(points[owners == t.index], t.index).all() for t in plan.tiles)


def test_the_region_is_the_robust_extent_and_the_default_overlap_follows_the_documented_rule():
    points = _ground_points()
    outliers = np.array([[-500.0, 10.0, 0.0], [70.0, 400.0, 0.0]])
    cloud = np.concatenate([points, outliers])
    plan = plan_tiles(_survey(), cloud, TileOptions(grid=TileGrid(2, 2)))
    lo, hi = np.quantile(cloud[:, :2], 0.005, axis=0), np.quantile(cloud[:, :2], 0.995, axis=0)
    assert plan.region == Rect(lo[0], hi[0], lo[1], hi[1])
    # 2x2 cores of ~50 m × ~30 m: max(10 % of 30 m, 5 × 1 m spacing) = 5 m
    assert plan.overlap_m == pytest.approx(5.0, rel=1e-9)
    assert plan.owner(outliers).tolist() == [0, 3]  # beyond the region: the border tiles own them
    one = plan_tiles(_survey(), points, TileOptions(grid=TileGrid(1, 1), **EXACT))
    assert one.overlap_m == pytest.approx(6.0)  # 10 % of the 60 m short side beats 5 spacings


@pytest.mark.parametrize(
    "photos_per_tile,points_per_tile,expected",
    [(1000, 10**9, (1, 1)), (18, 10**9, (2, 2)), (14, 10**9, (3, 2)), (1000, 1000, (4, 2))],
    ids=["one", "four-by-photos", "five-by-photos", "seven-by-points"],
)
def test_auto_gives_the_documented_counts(photos_per_tile, points_per_tile, expected):
    cameras, points = _survey(), _ground_points()  # 72 photos, 6161 points, 100 m × 60 m
    options = TileOptions(photos_per_tile=photos_per_tile, points_per_tile=points_per_tile, **EXACT)
    plan = plan_tiles(cameras, points, options)
    assert plan.auto and (plan.columns, plan.rows) == expected
    assert auto_grid(72, 6161, 100.0, 60.0, options) == expected


@pytest.mark.parametrize("grid", [(2, 2), (3, 2), (4, 3)], ids=["2x2", "3x2", "4x3"])
@pytest.mark.parametrize("visibility", [False, True], ids=["projected", "tracks"])
def test_every_photo_that_sees_a_core_is_assigned_and_none_that_does_not(grid, visibility):
    cameras, points = _survey(), _ground_points()
    vis = None
    if visibility:  # tracks: the nadir photos whose footprint holds the point (what SfM would have matched)
        rects = {v.image_id: _footprint_rect(v) for v in cameras if v.name != "sky.jpg"}
        vis = [np.array([i for i, r in rects.items() if r.u0 <= p[0] <= r.u1 and r.v0 <= p[1] <= r.v1]) for p in points]
    plan = plan_tiles(cameras, points, TileOptions(grid=TileGrid(*grid), **EXACT), visibility=vis)
    outside = {v.image_id for v in cameras if v.name in ("sky.jpg",) or v.center[0] > 150}
    assigned_somewhere = set()
    for tile in plan.tiles:
        assert set(tile.photo_ids) == _truth(cameras, tile.core), tile.name
        assert list(tile.photo_names) == [cameras.views[i].name for i in tile.photo_ids]
        assigned_somewhere |= set(tile.photo_ids)
    assert not outside & assigned_somewhere
    assert assigned_somewhere == {v.image_id for v in cameras} - outside


def test_points_alone_assign_only_photos_that_see_enough_of_the_core():
    cameras, points = _survey(), _ground_points()
    options = TileOptions(grid=TileGrid(2, 2), use_footprint=False, min_points_seen=20, **EXACT)
    plan = plan_tiles(cameras, points, options)
    for tile in plan.tiles:
        truth = _truth(cameras, tile.core)
        assert set(tile.photo_ids) <= truth
        # a photo seeing ≥ 3 m × 8 m of the core sees well over 20 of its 1 m grid points
        big = {i for i in truth if _overlap_area(_footprint_rect(cameras.views[i]), tile.core) >= 40.0}
        assert big <= set(tile.photo_ids)


def test_counts_from_tracks_equal_counts_from_projection_when_the_tracks_are_the_projections():
    cameras, points = _survey(), _ground_points(2.0)
    plan = plan_tiles(cameras, points, TileOptions(grid=TileGrid(3, 2), **EXACT))
    tracks = [[] for _ in points]
    for view in cameras:  # tracks one point at a time, counted by the vectorised track counter
        camera = cameras.cameras[view.camera_id]
        cam = view.world_to_camera(points)
        pix = camera.project(cam)
        for k in range(len(points)):
            if cam[k, 2] > 0 and 0 <= pix[k, 0] < camera.width and 0 <= pix[k, 1] < camera.height:
                tracks[k].append(view.image_id)
    tracks[0].append(999)  # a photo the model does not hold is ignored
    by_tracks = points_seen_per_tile(plan, cameras, points, tracks)
    by_projection = points_seen_per_tile(plan, cameras, points)
    assert by_tracks.keys() == by_projection.keys()
    assert all(np.array_equal(by_tracks[i], by_projection[i]) for i in by_tracks)
    assert sum(int(c.sum()) for c in by_tracks.values()) > 0


def test_projected_counts_see_every_point_of_oblique_distorted_photos():
    """The projection path projects only the points under a box of each frustum: against projecting them all."""
    points = _ground_points(2.0)
    points[:, 2] = np.random.default_rng(3).uniform(-3.0, 8.0, len(points))  # relief and roofs
    lens = Camera(CameraModel.OPENCV, 300, 200, [180.0, 180.0, 150.0, 100.0, -0.25, 0.05, 0.001, -0.002], 2)
    cameras = _survey()
    views = dict(cameras.views)
    for k, (centre, target) in enumerate(
        [
            ((-30, 30, 25), (20, 30, 0)),
            ((130, -20, 40), (60, 40, 0)),
            ((50, 90, 15), (50, 40, 0)),
            ((50, 30, 5), (99, 59, 0)),
        ]
    ):
        views[100 + k] = View.from_matrix(100 + k, f"oblique_{k}.jpg", 2, look_at(np.array(centre, float), target))
    cameras = Cameras({**cameras.cameras, 2: lens}, views)
    plan = plan_tiles(cameras, points, TileOptions(grid=TileGrid(3, 2), **EXACT))
    counts = points_seen_per_tile(plan, cameras, points)
    core = plan.owner(points)
    for view in cameras:
        camera = cameras.cameras[view.camera_id]
        cam = view.world_to_camera(points)
        pix = camera.project(cam)
        seen = (cam[:, 2] > 0) & (pix[:, 0] >= 0) & (pix[:, 0] < camera.width)
        seen &= (pix[:, 1] >= 0) & (pix[:, 1] < camera.height)
        assert np.array_equal(counts[view.image_id], np.bincount(core[seen], minlength=6)), view.name
    assert all(counts[100 + k].sum() > 100 for k in range(4))


def test_an_object_scan_that_is_not_z_up_is_tiled_on_the_pca_plane_of_the_cameras():
    cameras, points = _survey(), _ground_points()
    z_up = plan_tiles(cameras, points, TileOptions(grid=TileGrid(2, 2), **EXACT))
    # the same block turned on its side (a façade): world z becomes -x, world x becomes z
    turn = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    offset = np.array([1000.0, -200.0, 35.0])
    views = {}
    for v in cameras:
        R = v.rotation @ turn.T  # x_cam = R x + t = R turnᵀ (x' - offset) + t
        views[v.image_id] = View.from_matrix(v.image_id, v.name, 1, np.c_[R, v.translation - R @ offset])
    turned = Cameras(cameras.cameras, views)
    plan = plan_tiles(turned, points @ turn.T + offset, TileOptions(grid=TileGrid(2, 2), up="pca", **EXACT))
    assert plan.frame.axes[2] == pytest.approx(turn @ [0.0, 0.0, 1.0], abs=1e-9)  # h points to the cameras
    sizes = sorted([plan.region.u1 - plan.region.u0, plan.region.v1 - plan.region.v0])
    assert sizes == pytest.approx([60.0, 100.0], abs=1e-9)
    assert sorted(t.photo_ids for t in plan.tiles) == sorted(t.photo_ids for t in z_up.tiles)


def _stitch_case(plan, rng: np.random.Generator) -> np.ndarray:
    """Ground points, random float64 positions, points exactly on core edges and corners, outliers."""
    random = np.column_stack([rng.uniform(-2, 102, 3000), rng.uniform(-2, 62, 3000), rng.normal(0, 0.3, 3000)])
    on_edges = [[u, v, 0.1] for u in plan.u_edges for v in np.linspace(0.0, 60.0, 13)]
    on_edges += [[u, v, 0.2] for v in plan.v_edges for u in np.linspace(0.0, 100.0, 21)]
    on_edges += [[u, v, 0.3] for u in plan.u_edges for v in plan.v_edges]  # corners
    on_edges += [[plan.tiles[0].bounds.u1, 10.0, 0.0]]  # exactly on an overlap boundary
    outliers = [[-40.0, -40.0, 5.0], [140.0, 90.0, -5.0]]
    return np.concatenate([_ground_points(), random, np.array(on_edges), np.array(outliers)])


@pytest.mark.parametrize("grid", [(2, 2), (3, 2), (4, 3)], ids=["2x2", "3x2", "4x3"])
def test_stitching_per_tile_copies_returns_exactly_the_original_points(grid):
    rng = np.random.default_rng(34)
    plan = plan_tiles(_survey(), _ground_points(), TileOptions(grid=TileGrid(*grid), **EXACT))
    points = _stitch_case(plan, rng)
    ids = np.arange(len(points), dtype=np.int64)
    colours = rng.integers(0, 256, (len(points), 3), dtype=np.uint8)
    parts = []
    for tile in plan.tiles:  # each tile holds its core and overlap, in its own order
        picked = rng.permutation(np.flatnonzero(plan.in_bounds(points, tile.index)))
        parts.append(TilePoints(tile.index, points[picked].copy(), {"id": ids[picked], "rgb": colours[picked]}))
    assert sum(len(p.positions) for p in parts) > len(points)  # the overlaps do hold copies
    out = stitch_by_core(plan, parts[::-1])
    assert len(out.positions) == len(points)
    assert np.array_equal(np.sort(out.arrays["id"]), ids)  # no duplicate, no loss
    order = np.argsort(out.arrays["id"])
    assert out.positions.dtype == np.float64
    assert np.array_equal(out.positions[order].view(np.uint64), points.view(np.uint64))  # bit-identical
    assert np.array_equal(out.arrays["rgb"][order], colours)
    assert np.array_equal(out.tile[order], plan.owner(points))
    assert sum(out.dropped) == sum(len(p.positions) for p in parts) - len(points)


def test_stitching_refuses_parts_it_cannot_stitch_without_loss():
    plan = plan_tiles(_survey(), _ground_points(), TileOptions(grid=TileGrid(2, 2), **EXACT))
    ok = TilePoints(0, np.zeros((2, 3)), {"id": np.arange(2)})
    with pytest.raises(DataError, match="NaN"):
        stitch_by_core(plan, [ok, TilePoints(1, np.full((1, 3), np.nan), {"id": np.arange(1)})])
    with pytest.raises(DataError, match="differ"):
        stitch_by_core(plan, [ok, TilePoints(1, np.zeros((1, 3)))])
    with pytest.raises(DataError, match="rows"):
        stitch_by_core(plan, [TilePoints(0, np.zeros((2, 3)), {"id": np.arange(3)})])
    with pytest.raises(DataError, match="not in the plan"):
        stitch_by_core(plan, [TilePoints(4, np.zeros((2, 3)), {"id": np.arange(2)})])


def test_a_point_on_a_shared_edge_goes_to_exactly_one_tile_half_open():
    plan = plan_tiles(_survey(), _ground_points(), TileOptions(grid=TileGrid(2, 2), **EXACT))
    edge = np.array([[50.0, 10.0, 0.0], [10.0, 30.0, 0.0], [50.0, 30.0, 0.0], [np.nextafter(50.0, 0), 10.0, 0.0]])
    assert plan.owner(edge).tolist() == [1, 2, 3, 0]  # [lo, hi): the edge belongs to the upper tile


def test_the_seam_check_sees_no_seam_after_stitching_and_flags_gaps_and_duplicates():
    points = _ground_points()
    plan = plan_tiles(_survey(), points, TileOptions(grid=TileGrid(2, 2), **EXACT))
    parts = [TilePoints(t.index, points[plan.in_bounds(points, t.index)]) for t in plan.tiles]
    stitched = stitch_by_core(plan, parts).positions
    good = seam_check(plan, stitched)
    assert good.ok() and good.ratio == pytest.approx(1.0) and good.n_border > 0
    duplicated = np.concatenate([p.positions for p in parts])  # overlaps kept twice, each copy from its tile
    labels = np.concatenate([np.full(len(p.positions), p.tile) for p in parts])
    twice = seam_check(plan, duplicated, tile=labels)
    assert twice.spacing_across == 0.0 and not twice.ok()
    gap = stitched[stitched[:, 0] != 50.0]  # the column on the u = 50 m edge lost
    assert seam_check(plan, gap).ratio == pytest.approx(2.0) and not seam_check(plan, gap).ok()


def test_the_plan_file_round_trips(tmp_path):
    plan = plan_tiles(_survey(), _ground_points(), TileOptions(grid=TileGrid(3, 2), **EXACT))
    path = write_tile_plan(tmp_path / "tiles.json", plan)
    back = read_tile_plan(path)
    assert back.tiles == plan.tiles and back.region == plan.region and back.overlap_m == plan.overlap_m
    assert np.array_equal(back.u_edges, plan.u_edges) and np.array_equal(back.v_edges, plan.v_edges)
    assert np.array_equal(back.frame.axes, plan.frame.axes) and back.frame.up == plan.frame.up
    assert (back.n_photos, back.n_points, back.auto, back.height_range) == (
        plan.n_photos, plan.n_points, plan.auto, plan.height_range,
    )  # fmt: skip
    assert not list(tmp_path.glob("*.tmp*"))  # nothing half-written left behind


@pytest.mark.parametrize(
    "corrupt,words",
    [
        (lambda text, data: text[: len(text) // 2], "not valid JSON"),
        (lambda text, data: json.dumps({**data, "version": 99}), "version"),
        (lambda text, data: json.dumps({k: v for k, v in data.items() if k != "tiles"}), "'tiles'"),
        (lambda text, data: json.dumps({**data, "u_edges": data["u_edges"][::-1]}), "increase"),
        (lambda text, data: json.dumps({**data, "tiles": data["tiles"][:-1]}), "expected 6 tiles"),
        (lambda text, data: json.dumps({**data, "overlap_m": "5"}), "overlap_m"),
        (
            lambda text, data: json.dumps(
                {**data, "tiles": [{**data["tiles"][0], "photos": [{"name": 3}]}] + data["tiles"][1:]}
            ),
            "tiles[0].photos[0]",
        ),
    ],
    ids=["truncated", "version", "missing-key", "edges", "tile-count", "type", "photo"],
)
def test_a_corrupted_plan_file_raises_an_error_naming_the_file(tmp_path, corrupt, words):
    plan = plan_tiles(_survey(), _ground_points(), TileOptions(grid=TileGrid(3, 2), **EXACT))
    path = write_tile_plan(tmp_path / "tiles.json", plan)
    text = path.read_text()
    path.write_text(corrupt(text, json.loads(text)))
    with pytest.raises(FormatError) as err:
        read_tile_plan(path)
    assert str(path) in str(err.value) and words in str(err.value)


def test_a_missing_plan_file_is_named():
    with pytest.raises(InputFileError, match="nowhere.json"):
        read_tile_plan("/nonexistent/nowhere.json")


@pytest.mark.parametrize(
    "text,expected",
    [("off", None), ("auto", TileGrid()), ("3x2", TileGrid(3, 2)), ("1X1", TileGrid(1, 1))],
)
def test_parse_tiles(text, expected):
    assert parse_tiles(text) == expected


@pytest.mark.parametrize("text", ["", "3", "0x2", "3x", "axb", "2x2x2"])
def test_parse_tiles_refuses_other_values(text):
    with pytest.raises(ConfigError, match="NxM"):
        parse_tiles(text)
