"""Region masks: footprints, occlusion, holes, user masks, empty masks, on an analytic down-looking camera."""

from __future__ import annotations

import numpy as np

from classify.masks import MaskOptions, photo_mask, region_masks, splat_footprints
from core.cameras import Camera, Cameras, View


def _rig() -> tuple[Cameras, View]:
    """One camera 1 m above z = 0, looking down; f = 100 px: 1 cm on the plane = 1 px; image 80 × 60."""
    cam = Camera.pinhole(100.0, 100.0, 40.0, 30.0, 80, 60)
    down = np.diag([1.0, -1.0, -1.0])
    view = View.from_matrix(1, "a.png", 1, np.c_[down, -down @ np.array([0.0, 0.0, 1.0])])
    return Cameras({1: cam}, {1: view}), view


def _grid(spacing: float = 0.01, half: float = 0.6) -> np.ndarray:
    g = np.arange(-half, half + 1e-9, spacing)
    x, y = np.meshgrid(g, g, indexing="ij")
    return np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]


def test_splat_footprints_brute_force():
    col, row, rad = np.array([10.0, 30.0]), np.array([10.0, 5.0]), np.array([3.0, 0.0])
    m = splat_footprints((20, 40), col, row, rad, max_radius=5)
    rr, cc = np.mgrid[0:20, 0:40]
    ref = ((rr - 10) ** 2 + (cc - 10) ** 2 <= 9) | ((rr == 5) & (cc == 30))
    # OpenCV's discrete ellipse differs from the Euclidean disk only on its rim.
    assert np.sum(m ^ ref) <= 8 and m[10, 10] and m[5, 30] and not m[0, 0]


def test_non_collaborative_square_is_masked_and_nothing_else():
    cams, view = _rig()
    pts = _grid()
    bad = (np.abs(pts[:, 0]) < 0.1) & (np.abs(pts[:, 1]) < 0.1)  # a 20 × 20 px square in the image centre
    pm = photo_mask(cams, view, pts, bad, spacing=0.01, options=MaskOptions(dilate_px=0, close_px=0, dilate_spacings=0))
    rows, cols = np.nonzero(pm.mask)
    assert 8 <= rows.min() <= 20 and 40 <= rows.max() <= 52 and 18 <= cols.min() <= 30 and 50 <= cols.max() <= 62
    # Footprint 1.5 px: the square grows by at most 2 px on each side.
    assert 400 <= pm.mask.sum() <= 24 * 24 and pm.holes_px == 0 and not pm.empty
    assert pm.coverage == pm.mask.mean()


def test_hidden_non_collaborative_points_do_not_mask():
    cams, view = _rig()
    pts = _grid()
    behind = pts.copy()
    behind[:, 2] = -0.5  # a non-collaborative layer under a collaborative floor
    allp = np.r_[pts, behind]
    flags = np.r_[np.zeros(len(pts), bool), np.ones(len(behind), bool)]
    pm = photo_mask(cams, view, allp, flags, 0.01, MaskOptions(holes=False))
    assert pm.empty and pm.coverage == 0.0


def test_holes_inside_the_cloud_but_not_at_the_border():
    cams, view = _rig()
    pts = _grid()
    hole = (np.abs(pts[:, 0] - 0.05) < 0.06) & (np.abs(pts[:, 1]) < 0.06)
    pts = pts[~hole]
    # Remove a band at the image's left edge too: uncovered and touching the border = background.
    pts = pts[~(pts[:, 0] < -0.3)]
    opts = MaskOptions(close_px=0, dilate_px=0, hole_area="hull", dilate_spacings=0)
    pm = photo_mask(cams, view, pts, np.zeros(len(pts), bool), 0.01, opts)
    assert pm.points_px == 0 and pm.holes_px > 0
    rows, cols = np.nonzero(pm.mask)
    assert cols.min() >= 30 and cols.max() <= 60 and rows.min() >= 20 and rows.max() <= 40
    assert not pm.mask[:, :5].any()
    # hull_below: a nadir photo sees no sky, so the uncovered band at the border is a hole too.
    nadir = photo_mask(
        cams,
        view,
        pts,
        np.zeros(len(pts), bool),
        0.01,
        MaskOptions(close_px=0, dilate_px=0, dilate_spacings=0, hole_area="hull_below"),
    )
    assert nadir.mask[:, :5].all() and nadir.mask[30, 45] and not nadir.mask[10, 70]


def test_hull_below_keeps_the_sky_out():
    """An upright camera looking horizontally at a wall (top edge at image row 20) with a gap: the gap below the
    cloud's upper envelope is a hole, the sky above the wall's top edge is never masked."""
    cam = Camera.pinhole(100.0, 100.0, 40.0, 30.0, 80, 60)
    # Camera at y = -1 looking along +y, image x = world x, image y = -world z (z up).
    r = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    view = View.from_matrix(1, "a.png", 1, np.c_[r, -r @ np.array([0.0, -1.0, 0.0])])
    cams = Cameras({1: cam}, {1: view})
    g = np.arange(-0.6, 0.6 + 1e-9, 0.01)
    x, z = np.meshgrid(g, np.arange(-0.4, 0.1 + 1e-9, 0.01), indexing="ij")
    wall = np.c_[x.ravel(), np.zeros(x.size), z.ravel()]  # top edge at z = 0.1: image row 20
    gap = (np.abs(wall[:, 0]) < 0.05) & (np.abs(wall[:, 2] + 0.15) < 0.05)
    pm = photo_mask(
        cams, view, wall[~gap], np.zeros(int((~gap).sum()), bool), 0.01, MaskOptions(dilate_px=0, dilate_spacings=0)
    )
    assert pm.mask[45, 40] and not pm.mask[:15].any()  # the gap (row 45) yes, the sky (rows < 20) no


def test_points_hidden_behind_a_missed_surface_do_not_explain_it():
    """The floor is fully reconstructed, but the photo shows an unreconstructed bright box over a 20 × 20 px
    square: the floor points there do not match the photo's colour, so the square is a hole ("seen"); with
    "all" every point explains its pixels and the mask stays empty. Fused-by-this-view points always explain."""
    from classify.masks import SeenInView

    cams, view = _rig()
    pts = _grid()
    colors = np.full((len(pts), 3), 100, np.uint8)
    photo = np.full((60, 80, 3), 100, np.uint8)
    photo[20:40, 30:50] = 220
    seen = SeenInView(None, colors, lambda name: photo)
    flags = np.zeros(len(pts), bool)
    opts = MaskOptions(close_px=0, dilate_px=0, dilate_spacings=0)
    pm = photo_mask(cams, view, pts, flags, 0.01, opts, seen=seen)
    rows, cols = np.nonzero(pm.mask)
    assert pm.mask[25:35, 35:45].all() and 18 <= rows.min() and rows.max() <= 41 and 28 <= cols.min()
    assert cols.max() <= 51
    assert photo_mask(cams, view, pts, flags, 0.01, MaskOptions(explained_by="all"), seen=seen).empty
    vis = [np.array([1])] * len(pts)  # every point fused by this photo
    assert photo_mask(cams, view, pts, flags, 0.01, opts, seen=SeenInView(vis, colors, lambda n: photo)).empty


def test_user_masks_are_united_and_empty_masks_reported():
    cams, view = _rig()
    pts = _grid()
    user = np.zeros((60, 80), np.uint8)
    user[:5, :5] = 255
    masks = region_masks(
        cams, pts, np.zeros(len(pts), bool), 0.01, MaskOptions(dilate_px=0, dilate_spacings=0), {"a.png": user}
    )
    assert masks[0].user_px == 25 / 4800 and masks[0].mask[:5, :5].all()
    none = region_masks(cams, pts, np.zeros(len(pts), bool), 0.01)
    assert none[0].empty and none[0].coverage == 0.0


def test_dilation_in_spacings():
    """f = 100 px at 1 m and 1 cm spacing: 1 px per spacing, so 3 spacings dilate the 20 × 20 square by 3 px."""
    cams, view = _rig()
    pts = _grid()
    bad = (np.abs(pts[:, 0]) < 0.1) & (np.abs(pts[:, 1]) < 0.1)
    base = MaskOptions(dilate_px=0, close_px=0, dilate_spacings=0, holes=False)
    a = photo_mask(cams, view, pts, bad, 0.01, base).mask
    b = photo_mask(cams, view, pts, bad, 0.01, MaskOptions(dilate_px=0, close_px=0, holes=False)).mask
    rows_a, rows_b = np.nonzero(a)[0], np.nonzero(b)[0]
    assert rows_b.min() == rows_a.min() - 3 and rows_b.max() == rows_a.max() + 3


def test_ground_sample_distance_and_hole_radius_in_gsd():
    """Camera 1 m above the plane, f = 100 px: GSD = 1 cm. A grid of 4 cm spacing leaves 4 px between points: with
    holes explained within 3 GSD (3 px) the grid covers everything; within 1 GSD the gaps between points are holes."""
    from classify.masks import ground_sample_distance

    cams, view = _rig()
    pts = _grid(spacing=0.04, half=0.8)
    assert abs(ground_sample_distance(cams, pts) - 0.01) < 1e-12
    flags = np.zeros(len(pts), bool)
    base = dict(close_px=0, dilate_px=0, dilate_spacings=0, min_hole_px=1)
    wide = region_masks(cams, pts, flags, 0.04, MaskOptions(hole_gsd=3.0, **base))[0]
    narrow = region_masks(cams, pts, flags, 0.04, MaskOptions(hole_gsd=1.0, **base))[0]
    assert wide.empty
    # 1 px disks (5 px each) on a 4 × 4 px lattice leave 11 of 16 pixels uncovered.
    assert 0.6 < narrow.holes_px < 0.75


def test_hole_radius_is_in_the_clouds_gsd_when_the_cloud_came_from_smaller_images():
    """The same 4 cm grid seen by photos of 1 cm GSD, but reconstructed from images 3× smaller (a 3 cm GSD): 1 GSD
    of the cloud is 3 px of the photo, which covers the lattice as 3 GSD of the photo does (no false holes)."""
    import pytest

    from core.errors import DataError

    cams, _ = _rig()
    pts = _grid(spacing=0.04, half=0.8)
    flags = np.zeros(len(pts), bool)
    opts = MaskOptions(hole_gsd=1.0, close_px=0, dilate_px=0, dilate_spacings=0, min_hole_px=1)
    same = region_masks(cams, pts, flags, 0.04, opts)[0]
    coarse = region_masks(cams, pts, flags, 0.04, opts, cloud_downscale=3.0)[0]
    assert same.holes_px > 0.6 and coarse.empty
    with pytest.raises(DataError, match="cloud_downscale"):
        region_masks(cams, pts, flags, 0.04, opts, cloud_downscale=0.5)


def test_area_grows_over_unreconstructed_surface_that_looks_like_the_scene():
    """An upright camera looks at a brown wall (image rows 20-59) under a grey sky (rows 0-19); MVS reconstructed
    only the wall's lower part (rows 40-59). Without growth the unreconstructed upper part lies above the cloud's
    envelope (read as sky); GrabCut's colour models put it back into the valid area, so it becomes a hole, and the
    sky stays out."""
    from classify.masks import SeenInView

    cam = Camera.pinhole(100.0, 100.0, 40.0, 30.0, 80, 60)
    r = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # camera at y = -1 looking along +y, z up
    view = View.from_matrix(1, "a.png", 1, np.c_[r, -r @ np.array([0.0, -1.0, 0.0])])
    cams = Cameras({1: cam}, {1: view})
    g = np.arange(-0.6, 0.6 + 1e-9, 0.01)
    x, z = np.meshgrid(g, np.arange(-0.4, -0.1 + 1e-9, 0.01), indexing="ij")
    wall = np.c_[x.ravel(), np.zeros(x.size), z.ravel()]  # z = -0.1 is image row 40
    rng = np.random.default_rng(0)
    photo = np.empty((60, 80, 3), np.uint8)
    photo[:20] = (150, 150, 160) + rng.integers(-8, 8, (20, 80, 3))
    photo[20:] = (140, 90, 40) + rng.integers(-8, 8, (40, 80, 3))
    colors = np.tile(np.array([140, 90, 40], np.uint8), (len(wall), 1))
    seen = SeenInView(None, colors, lambda name: photo)
    flags = np.zeros(len(wall), bool)
    base = dict(close_px=0, dilate_px=0, dilate_spacings=0, hole_area="hull_below")
    grown = photo_mask(cams, view, wall, flags, 0.01, MaskOptions(**base), seen=seen)
    plain = photo_mask(cams, view, wall, flags, 0.01, MaskOptions(grow_area=0, **base), seen=seen)
    assert grown.mask[22:37, 5:75].all() and not grown.mask[:19].any() and not grown.mask[42:].any()
    assert not plain.mask[:37].any()


def test_training_margin_is_recorded_in_pixels_and_leaves_the_region_mask_alone():
    """1 px per spacing at this rig: a margin of 5 spacings is 5 px; the region mask does not change with it."""
    cams, view = _rig()
    pts = _grid()
    bad = (np.abs(pts[:, 0]) < 0.1) & (np.abs(pts[:, 1]) < 0.1)
    a = photo_mask(cams, view, pts, bad, 0.01, MaskOptions(holes=False, train_margin_spacings=0))
    b = photo_mask(cams, view, pts, bad, 0.01, MaskOptions(holes=False, train_margin_spacings=5))
    c = photo_mask(cams, view, pts, bad, 0.02, MaskOptions(holes=False, train_margin_spacings=5))
    assert (a.train_margin_px, b.train_margin_px, c.train_margin_px) == (0, 5, 10)
    np.testing.assert_array_equal(a.mask, b.mask)
