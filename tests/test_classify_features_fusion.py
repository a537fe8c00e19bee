"""Fusion evidence features against independent truth: depth maps that disagree by known amounts (back-projected
with ``Cameras.unproject`` and reprojected with ``Cameras.project``, not the feature's closed form) and points
displaced by a known offset off a plane (intersection of the ray with the plane)."""

from __future__ import annotations

import numpy as np
import pytest

from classify.features import FeatureGroup, FeatureOptions, ViewData, compute_features
from classify.features.fusion_evidence import DIST_CAP, REPROJ_CAP, fusion_features, plane_offset
from core.cameras import Camera, Cameras, View
from core.errors import ConfigError
from core.pointcloud import PointCloud

F, W, H = 50.0, 64, 48
DOWN = np.diag([1.0, -1.0, -1.0])  # camera z axis = world −z


def _rig(centres, depth_of):
    """Pinhole views (f = 50 px, 64 × 48) at ``centres`` looking straight down; ``depth_of(i)``: view i's constant
    depth map (metres, ≤ 0 invalid) or None (no map)."""
    cam = Camera.pinhole(F, F, W / 2, H / 2, W, H)
    views = {
        i + 1: View.from_matrix(i + 1, f"v{i}.png", 1, np.c_[DOWN, -DOWN @ np.asarray(c, float)])
        for i, c in enumerate(centres)
    }
    cams = Cameras({1: cam}, views)

    def depth(name: str):
        d = depth_of(int(name[1:-4]))
        return None if d is None else np.full((H, W), d, dtype=np.float32)

    return cams, ViewData(cams, lambda name: np.full((H, W, 3), 128, np.uint8), depth)


def _truth(cams: Cameras, views: ViewData, p: np.ndarray, spacing: float) -> tuple[float, float]:
    """Mean back-projection distance (spacings) and exact RMS pair reprojection error (px) of one point."""
    backs = []
    for v in cams:
        uv, _ = cams.project(v, p[None])
        d = views.depth(v.name)[int(uv[0, 1]), int(uv[0, 0])]
        backs.append(cams.unproject(v, uv, np.array([d], dtype=np.float64))[0])
    dist = np.mean([np.linalg.norm(x - p) for x in backs]) / spacing
    sq = []
    for i, x in enumerate(backs):
        for j, v in enumerate(cams):
            if i != j:
                sq.append(np.sum((cams.project(v, x[None])[0] - cams.project(v, p[None])[0]) ** 2))
    return float(dist), float(np.sqrt(np.mean(sq)))


def test_depth_maps_disagreeing_by_known_amounts():
    deltas = {0: 0.01, 1: -0.02, 2: 0.005}
    cams, views = _rig([(-0.1, 0.0, 1.0), (0.1, 0.0, 1.0), (0.0, 0.1, 1.0)], lambda i: 1.0 + deltas[i])
    p = np.array([0.02, -0.01, 0.0])
    pts = np.r_[p[None], np.array([[5.0, 0.0, 0.0]])]  # the second point is in no frustum
    spacing = 0.004
    f = fusion_features(pts, [np.array([1, 2, 3]), np.array([1, 2, 3])], views, spacing, np.array([[1], [0]]))
    dist, rms = _truth(cams, views, p, spacing)
    # Distance: exact (same ray, same depth sample). RMS: the feature linearises the projection at the point; the
    # back-projected points are ≤ 2 cm off at 1 m, so the linearisation's relative error is ~2 %.
    assert f["fusion_backproj_dist"][0] == pytest.approx(dist, rel=1e-5)
    assert f["fusion_reproj_px"][0] == pytest.approx(rms, rel=0.03)
    # Straight below a camera the depth error is the distance: |P − C| · |δ| / z ≈ |δ| for these near-vertical rays.
    assert dist * spacing == pytest.approx(np.mean(np.abs(list(deltas.values()))), rel=0.02)
    # Outside every frustum: no evidence, the caps.
    assert f["fusion_backproj_dist"][1] == DIST_CAP and f["fusion_reproj_px"][1] == REPROJ_CAP


def test_consistent_depth_maps_give_zero_and_missing_evidence_the_caps():
    # Depth maps invalid in view 3, missing in view 2: only view 1 has a depth; pairs (1, 2) and (1, 3) remain.
    cams, views = _rig([(-0.1, 0.0, 1.0), (0.1, 0.0, 1.0), (0.0, 0.1, 1.0)], lambda i: (1.0, None, 0.0)[i])
    pts = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0]])
    vis = [np.array([1, 2, 3]), np.array([2, 3]), np.array([1])]
    f = fusion_features(pts, vis, views, 0.01, np.array([[1, 2], [0, 2], [0, 1]]))
    assert f["fusion_backproj_dist"][0] == pytest.approx(0.0, abs=1e-9)
    assert f["fusion_reproj_px"][0] == pytest.approx(0.0, abs=1e-9)
    # Point 1: fused by views without a valid depth; point 2: one view, no pair of views.
    assert f["fusion_backproj_dist"][1] == DIST_CAP and f["fusion_reproj_px"][1] == REPROJ_CAP
    assert f["fusion_backproj_dist"][2] == pytest.approx(0.0, abs=1e-9) and f["fusion_reproj_px"][2] == REPROJ_CAP
    assert all(np.isfinite(c).all() for c in f.values())


def _grid(n: int = 21, step: float = 0.01) -> np.ndarray:
    g = (np.arange(n) - n // 2) * step
    x, y = np.meshgrid(g, g, indexing="ij")
    return np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]


@pytest.mark.parametrize("h", [0.03, -0.02, 0.0])
@pytest.mark.parametrize("centres", [[(-0.1, 0.0, 1.0), (0.1, 0.0, 1.0)], [(0.5, 0.2, 1.0)]], ids=["pair", "oblique"])
def test_point_displaced_off_a_plane_gives_its_offset_along_the_ray(h, centres):
    cams, views = _rig(centres, lambda i: 1.0)
    pts = _grid()
    centre = len(pts) // 2
    pts[centre, 2] = h  # the middle point moved off the plane z = 0 (towards the cameras when h > 0)
    vis = [np.arange(1, len(centres) + 1)] * len(pts)
    spacing = 0.01
    f = fusion_features(pts, vis, views, spacing, neighbours=None, k=16)
    # Truth: the mean unit ray (camera → point) and where it meets z = 0.
    rays = [(pts[centre] - v.center) / np.linalg.norm(pts[centre] - v.center) for v in cams]
    r = np.mean(rays, axis=0)
    r /= np.linalg.norm(r)
    t = -pts[centre, 2] / r[2]
    assert f["fusion_plane_offset"][centre] == pytest.approx(t / spacing, abs=1e-6)
    assert np.sign(f["fusion_plane_offset"][centre]) == np.sign(h)
    others = np.delete(np.arange(len(pts)), centre)
    # Others whose neighbourhood holds the moved point see a slightly tilted plane; the far ones see z = 0 exactly.
    far = others[np.linalg.norm(pts[others, :2], axis=1) > 0.04]
    assert np.abs(f["fusion_plane_offset"][far]).max() < 1e-6


def test_plane_offset_grazing_rays_are_bounded_and_no_ray_is_neutral():
    pts = _grid(5)
    nb = np.array([np.delete(np.arange(25), i) for i in range(25)])
    p = pts[:2] + [0.0, 0.0, 0.01]
    grazing = np.array([[1.0, 0.0, -1e-9], [0.0, 0.0, 0.0]])
    off = plane_offset(pts, nb[:2], p, grazing)
    assert off[0] == pytest.approx(0.01 / 0.1) and off[1] == 0.0  # |cos| floored at 0.1; no ray → 0


def test_compute_features_selects_the_fusion_group_and_reuses_the_neighbours():
    cams, views = _rig([(-0.1, 0.0, 1.0), (0.1, 0.0, 1.0)], lambda i: 1.0)
    pts = _grid()
    pts[len(pts) // 2, 2] = 0.02
    cloud = PointCloud(pts, visibility=[np.array([1, 2])] * len(pts))
    t = compute_features(cloud, FeatureOptions(names=("fusion",)), views)
    assert t.names == ("fusion_backproj_dist", "fusion_reproj_px", "fusion_plane_offset")
    direct = fusion_features(pts, cloud.visibility, views, t.spacing, t.neighbours)
    for name in t.names:
        np.testing.assert_allclose(t.column(name), direct[name], rtol=1e-6, atol=1e-6)
    assert t.column("fusion_plane_offset")[len(pts) // 2] == pytest.approx(2.0, rel=1e-3)  # 2 cm, 1 cm spacing
    with pytest.raises(ConfigError, match="fusion"):
        compute_features(cloud, FeatureOptions(groups=(FeatureGroup.FUSION,)))


def test_without_visibility_the_agreeing_depth_maps_fuse_and_absurd_depths_stay_finite():
    # View 3's depth map disagrees by 50 %: without visibility lists it does not count as fusing.
    cams, views = _rig([(-0.1, 0.0, 1.0), (0.1, 0.0, 1.0), (0.0, 0.1, 1.0)], lambda i: (1.0, 1.005, 1.5)[i])
    pts = _grid(9)
    nb = np.array([np.delete(np.arange(len(pts)), i)[:15] for i in range(len(pts))])
    implicit = fusion_features(pts, None, views, 0.01, nb)
    explicit = fusion_features(pts, [np.array([1, 2])] * len(pts), views, 0.01, nb)
    for name in implicit:
        np.testing.assert_allclose(implicit[name], explicit[name], rtol=1e-12)
    for bad in (np.inf, np.nan, 3e38):
        _, broken = _rig([(-0.1, 0.0, 1.0), (0.1, 0.0, 1.0)], lambda i, b=bad: (1.0, b)[i])
        f = fusion_features(pts, [np.array([1, 2])] * len(pts), broken, 0.01, nb)
        assert all(np.isfinite(c).all() for c in f.values())
        assert f["fusion_reproj_px"].max() <= REPROJ_CAP and f["fusion_backproj_dist"].max() <= DIST_CAP


def test_visibility_ids_of_photos_outside_the_reconstruction_are_ignored_by_every_view_group():
    """A .vis entry naming a photo that is not a view of the dense reconstruction (held out, or dropped) belongs to
    no view: every view-based feature is as if it were not listed (it once fell to the view listed before it)."""
    cams, views = _rig([(-0.1, 0.0, 1.0), (0.1, 0.0, 1.0), (0.0, 0.1, 1.0)], lambda i: 1.0 + 0.01 * i)
    kept = Cameras(cams.cameras, {i: cams.views[i] for i in (1, 3)})
    rng = np.random.default_rng(0)
    photos = {name: rng.integers(0, 255, (H, W, 3)).astype(np.uint8) for name in ("v0.png", "v2.png")}
    partial = ViewData(kept, photos.__getitem__, views.depth)
    pts = _grid(9)
    opts = FeatureOptions(names=("multiview", "fusion", "view_dependent", "image_boundaries"))
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    with_2 = compute_features(
        PointCloud(pts, normals=normals, visibility=[np.array([1, 2, 3])] * len(pts)), opts, partial
    )
    without = compute_features(
        PointCloud(pts, normals=normals, visibility=[np.array([1, 3])] * len(pts)), opts, partial
    )
    names = tuple(n for n in with_2.names if n != "n_views")  # n_views counts the .vis list as it is, by definition
    np.testing.assert_array_equal(with_2.select(names).values, without.select(names).values)
