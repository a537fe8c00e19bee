"""The survey region (classify.survey_region) and the masks' ``hole_area="region"`` on constructed scenes whose
answer is known exactly: analytic ray casts of a floor, a tower on a table against the sky, and a wall."""

from __future__ import annotations

import numpy as np
import pytest

from classify.masks import MaskOptions, photo_mask, region_masks
from classify.survey_region import rays_meeting_region, survey_region, up_frame
from core.cameras import Camera, Cameras, View
from core.errors import DataError


def _grid(x0: float, x1: float, y0: float, y1: float, step: float = 0.01) -> np.ndarray:
    x, y = np.meshgrid(np.arange(x0, x1 + 1e-9, step), np.arange(y0, y1 + 1e-9, step), indexing="ij")
    return np.c_[x.ravel(), y.ravel()]


def _nadir() -> tuple[Cameras, View]:
    """1 m above z = 0 looking down, f = 100 px, 80 × 60: pixel (c, r) sees x = (c + 0.5 - 40) / 100,
    y = -(r + 0.5 - 30) / 100 on the plane z = 0."""
    cam = Camera.pinhole(100.0, 100.0, 40.0, 30.0, 80, 60)
    down = np.diag([1.0, -1.0, -1.0])
    view = View.from_matrix(1, "a.png", 1, np.c_[down, -down @ np.array([0.0, 0.0, 1.0])])
    return Cameras({1: cam}, {1: view}), view


def _look_at(centre: np.ndarray, target: np.ndarray, width: int = 120, height: int = 90) -> tuple[Cameras, View]:
    """An upright pinhole camera (world up +z) at ``centre`` looking at ``target``; f = 100 px."""
    fwd = (target - centre) / np.linalg.norm(target - centre)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    rot = np.stack([right, down, fwd])
    cam = Camera.pinhole(100.0, 100.0, width / 2, height / 2, width, height)
    view = View.from_matrix(1, "a.png", 1, np.c_[rot, -rot @ centre])
    return Cameras({1: cam}, {1: view}), view


def _rays(cams: Cameras, view: View) -> tuple[np.ndarray, np.ndarray]:
    cam = cams.camera_of(view)
    rows, cols = np.mgrid[0 : cam.height, 0 : cam.width]
    pix = np.c_[cols.ravel() + 0.5, rows.ravel() + 0.5]
    d = cam.unproject(pix, 1.0) @ view.rotation
    return view.center, d / np.linalg.norm(d, axis=1, keepdims=True)


def _hits_box(o: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(M,) bool: rays from ``o`` along ``d`` (M, 3) that meet the axis-aligned box [lo, hi] (slab method)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - o) / d, (hi - o) / d
    t0 = np.nanmax(np.minimum(ta, tb), axis=1)
    t1 = np.nanmin(np.maximum(ta, tb), axis=1)
    return (t1 >= np.maximum(t0, 0.0)) & np.isfinite(t0)


def test_up_frame_is_orthonormal_with_up_last():
    for up in ([0, 0, 1], [0.3, -0.2, 0.9], [1, 0, 0]):
        f = up_frame(np.asarray(up, float))
        np.testing.assert_allclose(f @ f.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(f[2], np.asarray(up) / np.linalg.norm(up), atol=1e-12)
    with pytest.raises(DataError, match="up axis"):
        up_frame(np.zeros(3))


def test_height_field_keeps_the_top_and_the_gaps_inside_the_hull():
    """An L-shaped floor (a 0.5 m square less its upper right quarter) with a gap inside and a lone outlier far
    away: the footprint is the L's convex hull (the gap and the triangle between the L's arms in, the outlier's
    cell and the corner beyond the hull out)."""
    floor = _grid(0.0, 0.5, 0.0, 0.5)
    gap = (np.abs(floor[:, 0] - 0.15) < 0.05) & (np.abs(floor[:, 1] - 0.15) < 0.05)
    notch = (floor[:, 0] > 0.3) & (floor[:, 1] > 0.3)
    keep = ~gap & ~notch
    pts = np.c_[floor[keep], np.zeros(keep.sum())]
    post = np.array([[0.41, 0.11, 0.3], [0.41, 0.11, 0.2]])
    outlier = np.array([[1.0, 1.0, 0.0]])
    region = survey_region(np.r_[pts, post, outlier], np.array([0.0, 0.0, 1.0]), cell=0.02)

    def cell(x: float, y: float) -> tuple[int, int]:
        i, j = np.floor((np.array([x, y]) - region.corner[:2]) / region.cell).astype(int)
        return int(i), int(j)

    assert region.footprint[cell(0.15, 0.15)] and not region.occupied[cell(0.15, 0.15)]  # the gap
    assert region.footprint[cell(0.35, 0.35)]  # between the L's arms, inside the hull
    assert not region.footprint[cell(0.48, 0.48)]  # the notch's far corner, beyond the hull
    assert region.occupied[cell(1.0, 1.0)] and not region.footprint[cell(0.7, 0.7)]  # the outlier spans nothing
    assert region.heights[cell(0.15, 0.15)] == pytest.approx(0.0)  # the nearest occupied cell's height
    assert region.heights[cell(0.41, 0.11)] == pytest.approx(0.3)  # the highest point of the cell
    with pytest.raises(DataError, match="cell"):
        survey_region(pts, np.array([0.0, 0.0, 1.0]), cell=0.0)


def test_nadir_floor_gap_is_region_and_beyond_the_floor_is_not():
    """A floor over |x|, |y| <= 0.3 with a gap inside; nadir rays: the gap (enclosed) meets the region, rays past
    the floor's edge (|x| > 0.3) do not, whatever lies below."""
    cams, view = _nadir()
    floor = _grid(-0.3, 0.3, -0.3, 0.3)
    gap = (np.abs(floor[:, 0] - 0.05) < 0.06) & (np.abs(floor[:, 1]) < 0.06)
    pts = np.c_[floor[~gap], np.zeros((~gap).sum())]
    region = survey_region(pts, np.array([0.0, 0.0, 1.0]), cell=0.01)
    meets = rays_meeting_region(cams, view, region)
    cols = np.arange(80)
    x = (cols + 0.5 - 40) / 100
    inside = np.abs(x) <= 0.3 - 0.011  # a cell of slack at the edge
    outside = np.abs(x) >= 0.3 + 0.011
    assert meets[:, inside].all() and not meets[:, outside].any()
    opts = MaskOptions(hole_area="region", close_px=0, dilate_px=0, dilate_spacings=0, hole_gsd=0, hole_footprint=1.0)
    pm = photo_mask(cams, view, pts, np.zeros(len(pts), bool), 0.01, opts)
    gap_px = (np.abs(x - 0.05) < 0.04)[None, :] & (np.abs(-(np.arange(60) + 0.5 - 30) / 100) < 0.04)[:, None]
    assert pm.mask[gap_px].all()
    assert not pm.mask[:, outside].any()  # hull_below counts that band as holes (a nadir photo sees no sky)
    nadir = photo_mask(cams, view, pts, np.zeros(len(pts), bool), 0.01,
                       MaskOptions(close_px=0, dilate_px=0, dilate_spacings=0, hole_area="hull_below"))  # fmt: skip
    assert nadir.mask[:, outside].mean() > 0.5  # most of the band


def _tower_scene() -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """A 0.6 m table (z = 0) with a 0.1 × 0.1 × 0.5 m tower on it, sampled every 5 mm on every visible face; a
    0.1 m patch of the table in front of the tower is missing (a mirror MVS could not match). Returns the points,
    the missing patch's points and the tower's box."""
    table = _grid(-0.3, 0.3, -0.3, 0.3, 0.005)
    patch = (np.abs(table[:, 0] + 0.15) < 0.05) & (np.abs(table[:, 1] + 0.15) < 0.05)
    lo, hi = np.array([-0.05, -0.05, 0.0]), np.array([0.05, 0.05, 0.5])
    faces = []
    for axis in range(3):
        u, v = [k for k in range(3) if k != axis]
        a, b = np.meshgrid(np.arange(lo[u], hi[u] + 1e-9, 0.005), np.arange(lo[v], hi[v] + 1e-9, 0.005), indexing="ij")
        for side in (lo, hi):
            p = np.empty((a.size, 3))
            p[:, axis], p[:, u], p[:, v] = side[axis], a.ravel(), b.ravel()
            faces.append(p)
    pts = np.concatenate([np.c_[table[~patch], np.zeros((~patch).sum())], *faces])
    return pts, np.c_[table[patch], np.zeros(patch.sum())], (lo, hi)


def test_tower_against_the_sky_is_no_hole_but_the_missing_patch_is():
    """Seen from a low oblique camera, the tower's top rises above the table's far edge: the pixels beside it show
    the sky. Analytic truth: a ray meets the region exactly when it meets the table's slab or the tower's box;
    rays that meet neither are background (allowed to differ only within 2 px of the true outline)."""
    pts, missing, (lo, hi) = _tower_scene()
    cams, view = _look_at(np.array([0.0, -1.2, 0.35]), np.array([0.0, 0.0, 0.15]))
    region = survey_region(pts, np.array([0.0, 0.0, 1.0]), cell=0.01)
    meets = rays_meeting_region(cams, view, region)
    o, d = _rays(cams, view)
    truth = _hits_box(o, d, np.array([-0.3, -0.3, -1e-3]), np.array([0.3, 0.3, 1e-3])) | _hits_box(o, d, lo, hi)
    truth = truth.reshape(meets.shape)
    from scipy import ndimage

    edge = ndimage.binary_dilation(truth, iterations=2) & ~ndimage.binary_erosion(truth, iterations=2)
    assert truth.any() and (~truth).any()
    assert not (meets ^ truth)[~edge].any()
    # Through the masks: the patch is a hole, the sky beside the tower is not; hull_below masks a band there.
    base = dict(close_px=0, dilate_px=0, dilate_spacings=0, hole_gsd=0, hole_footprint=1.0, min_hole_px=1)
    flags = np.zeros(len(pts), bool)
    pm = photo_mask(cams, view, pts, flags, 0.005, MaskOptions(hole_area="region", **base))
    uv, _ = cams.project(view, missing)
    inner = missing[(np.abs(missing[:, 0] + 0.15) < 0.03) & (np.abs(missing[:, 1] + 0.15) < 0.03)]
    uv, _ = cams.project(view, inner)
    assert pm.mask[uv[:, 1].astype(int), uv[:, 0].astype(int)].all()
    sky = ~ndimage.binary_dilation(truth, iterations=3)
    assert not pm.mask[sky].any()
    hull = photo_mask(cams, view, pts, flags, 0.005, MaskOptions(hole_area="hull", **base))
    assert hull.mask[sky].any()  # what the rule removes: the convex hull spans the sky beside the tower


def test_wall_with_a_missing_window_seen_level():
    """A vertical wall (y = 1, |x| <= 0.4, 0 <= z <= 0.6) with a missing window, seen by a level camera: the window
    meets the region (the rays pass under the wall's top inside its footprint), the sky above and the sides do not."""
    wall = _grid(-0.4, 0.4, 0.0, 0.6)
    window = (np.abs(wall[:, 0]) < 0.1) & (np.abs(wall[:, 1] - 0.3) < 0.1)
    pts = np.c_[wall[~window, 0], np.ones((~window).sum()), wall[~window, 1]]
    cams, view = _look_at(np.array([0.0, 0.0, 0.3]), np.array([0.0, 1.0, 0.3]))
    region = survey_region(pts, np.array([0.0, 0.0, 1.0]), cell=0.01)
    meets = rays_meeting_region(cams, view, region)
    o, d = _rays(cams, view)
    truth = _hits_box(o, d, np.array([-0.4, 0.99, 0.0]), np.array([0.4, 1.01, 0.6])).reshape(meets.shape)
    from scipy import ndimage

    edge = ndimage.binary_dilation(truth, iterations=2) & ~ndimage.binary_erosion(truth, iterations=2)
    assert not (meets ^ truth)[~edge].any()
    opts = MaskOptions(hole_area="region", close_px=0, dilate_px=0, dilate_spacings=0, hole_gsd=0, hole_footprint=1.0)
    pm = region_masks(cams, pts, np.zeros(len(pts), bool), 0.01, opts)[0]
    assert pm.mask[45, 60] and pm.holes_px > 0  # the window's centre
    assert not pm.mask[0].any() and not pm.mask[:, :5].any()


def test_collaborative_only_scene_needs_no_splats_under_the_region_rule():
    """Every visible surface reconstructed (the tower scene without its missing patch): no hole and no
    non-collaborative point, so every mask is empty and training is skipped; the 2D hull rule masks the sky
    beside the tower instead."""
    pts, missing, _ = _tower_scene()
    pts = np.r_[pts, missing]
    cams, view = _look_at(np.array([0.0, -1.2, 0.35]), np.array([0.0, 0.0, 0.15]))
    base = dict(close_px=0, dilate_px=0, dilate_spacings=0, hole_gsd=0, hole_footprint=1.0)
    flags = np.zeros(len(pts), bool)
    assert region_masks(cams, pts, flags, 0.005, MaskOptions(hole_area="region", **base))[0].empty
    assert not region_masks(cams, pts, flags, 0.005, MaskOptions(hole_area="hull", **base))[0].empty
