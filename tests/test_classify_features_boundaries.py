"""Image-boundary features against edges drawn at known pixels: a step edge on a plane seen by two views (its
distance in pixels and in point spacings), a ramp's gradient, photos at twice the camera's resolution, and the
neutral values."""

from __future__ import annotations

import numpy as np
import pytest

from classify.features import FeatureOptions, ViewData, compute_features
from classify.features.image_boundaries import EDGE_CAP_PX, EDGE_CAP_SPACING, edge_maps, image_boundary_features
from core.cameras import Camera, Cameras, View
from core.pointcloud import PointCloud

F, W, H = 50.0, 64, 48
DOWN = np.diag([1.0, -1.0, -1.0])
EDGE_X = 0.1  # the world line x = 0.1 on the plane z = 0 separates grey 0 (x < 0.1) from grey 200


def _rig(scale: int = 1) -> tuple[Cameras, ViewData]:
    """Two views 1 m above z = 0 looking down (x = ±0.1); photos of the step edge at ``scale`` × the camera size."""
    cam = Camera.pinhole(F, F, W / 2, H / 2, W, H)
    views = {
        i + 1: View.from_matrix(i + 1, f"v{i}.png", 1, np.c_[DOWN, -DOWN @ np.array([cx, 0.0, 1.0])])
        for i, cx in enumerate((-0.1, 0.1))
    }
    cams = Cameras({1: cam}, views)

    def image(name: str) -> np.ndarray:
        v = cams.by_name(name)
        cols = (np.arange(W * scale) + 0.5) / scale  # camera pixels of the photo's pixel centres
        world_x = v.center[0] + (cols - W / 2) / F
        row = np.where(world_x >= EDGE_X, 200, 0).astype(np.uint8)
        return np.repeat(np.tile(row, (H * scale, 1))[..., None], 3, axis=2)

    return cams, ViewData(cams, image, lambda name: None)


def test_edge_maps_of_a_step_and_a_ramp():
    step = np.zeros((48, 64), np.uint8)
    step[:, 32:] = 200
    strength, dist = edge_maps(step)
    # Canny marks one side of the step (column 31 or 32); the distance grows one pixel per column away from it.
    marked = np.flatnonzero(dist[24] == 0)
    assert len(marked) == 1 and marked[0] in (31, 32)
    np.testing.assert_allclose(dist[24].astype(float), np.minimum(np.abs(np.arange(64) - marked[0]), EDGE_CAP_PX))
    # Sobel / 8 next to a step of h is h / 2 (grey / 255 per pixel); zero away from it.
    assert strength[24, 31] == pytest.approx(100 / 255, rel=1e-3) and strength[24, 10] == 0
    ramp = np.repeat(np.tile((np.arange(64) * 3).astype(np.uint8), (48, 1))[..., None], 3, axis=2)  # 3 levels / px
    strength, dist = edge_maps(ramp)
    assert strength[24, 5:60].astype(float) == pytest.approx(3 / 255, rel=1e-3)
    assert (dist == EDGE_CAP_PX).all()  # no step: no edge anywhere


@pytest.mark.parametrize("scale", [1, 2])
def test_distance_to_an_edge_drawn_at_a_known_place(scale):
    _, views = _rig(scale)
    x0 = np.array([-0.1, 0.0, 0.05, 0.09, 0.12, 0.095])
    pts = np.c_[x0, np.zeros((len(x0), 2))]
    vis = [np.array([1, 2])] * len(x0)
    spacing = 0.01
    f = image_boundary_features(pts, vis, views, spacing)
    # Truth: the edge is |x0 − 0.1| m away on the plane, i.e. 50 |x0 − 0.1| camera pixels at depth 1 m (f = 50 px),
    # scale × that in the photo's pixels. Canny marks the pixel on one side of the step and the feature reads the
    # nearest pixel: ±1 photo pixel.
    px = F * np.abs(x0 - EDGE_X) * scale
    np.testing.assert_allclose(f["edge_distance_px"], px, atol=1.0 + 1e-6)
    np.testing.assert_allclose(f["edge_distance_spacing"], np.abs(x0 - EDGE_X) / spacing, atol=2.0 / scale + 1e-6)
    # Far from the step the photo is flat; at it (x0 = 0.095, one pixel off in both views) the step's h / 2.
    assert f["edge_strength_views"][0] == 0.0
    assert f["edge_strength_views"][-1] == pytest.approx(100 / 255, rel=1e-3)


def test_points_far_from_edges_and_unseen_points_get_the_caps():
    _, views = _rig()
    pts = np.array([[-0.6, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    vis = [np.array([1, 2]), np.array([1, 2]), np.array([], dtype=np.int64)]
    f = image_boundary_features(pts, vis, views, 0.01)
    # Point 0: only view 1 holds it, 35 px from the step (over the cap). Point 1: outside both images. Point 2:
    # fused by no view.
    assert f["edge_distance_px"].tolist() == [EDGE_CAP_PX] * 3
    assert f["edge_distance_spacing"].tolist() == [EDGE_CAP_SPACING] * 3
    assert f["edge_strength_views"].tolist() == [0.0] * 3


def test_compute_features_image_boundaries_group_caches_each_view_once():
    cams, views = _rig()
    calls: list[str] = []

    def image(name: str) -> np.ndarray:
        calls.append(name)
        return views.image(name)

    counted = ViewData(cams, image, views.depth)
    x = np.linspace(-0.2, 0.3, 40)
    cloud = PointCloud(np.c_[x, 0.01 * np.sin(7 * x), np.zeros(40)], visibility=[np.array([1, 2])] * 40)
    opts = FeatureOptions(names=("image_boundaries",))
    t = compute_features(cloud, FeatureOptions(names=opts.names, multiview=type(opts.multiview)(chunk_size=7)), counted)
    assert t.names == ("edge_strength_views", "edge_distance_px", "edge_distance_spacing")
    assert sorted(calls) == ["v0.png", "v1.png"]  # six chunks, one edge map per view
    assert np.isfinite(t.values).all()
