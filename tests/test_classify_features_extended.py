"""The four opt-in view-based groups (fusion, view_dependent, image_boundaries, image_texture) wired into the registry,
compute_features and the model file: the defaults unchanged, selection by group name, every value finite on a
small dense workspace read from disk (COLMAP model, photos, depth maps, fused.ply + .vis), and a model trained
on all seven groups saved and loaded."""

from __future__ import annotations

import numpy as np
import pytest

from classify.classes import load_classes
from classify.features import (
    ALL_GROUPS,
    ALL_GROUPS_EXTENDED,
    VIEW_GROUPS,
    FeatureGroup,
    FeatureOptions,
    compute_features,
    feature_specs,
    views_from_workspace,
)
from classify.model import ForestOptions, load_model, save_model, train
from core.cameras import Camera, Cameras, View
from core.errors import ConfigError
from core.io.colmap import write_model
from core.io.images import write_image
from core.io.ply import write_ply
from core.pointcloud import PointCloud
from recon.workspace import DenseWorkspace, read_fused, write_array, write_vis

NEW = (FeatureGroup.FUSION, FeatureGroup.VIEW_DEPENDENT, FeatureGroup.IMAGE_BOUNDARIES, FeatureGroup.IMAGE_TEXTURE)


def test_defaults_are_the_three_groups_and_the_extension_lists_seven_in_registry_order():
    assert FeatureOptions().groups == ALL_GROUPS and ALL_GROUPS_EXTENDED == (*ALL_GROUPS, *NEW)
    default = FeatureOptions().selected()
    assert len(default) == 51 and not any(feature_specs(3)[n].group in NEW for n in default)
    every = FeatureOptions(groups=ALL_GROUPS_EXTENDED).selected()
    assert every[:51] == default and len(every) == 51 + 3 + 4 + 3 + 3
    assert list(every) == list(feature_specs(3))  # the registry order
    assert set(VIEW_GROUPS) == {FeatureGroup.MULTIVIEW, *NEW}
    for g in NEW:
        names = FeatureOptions(names=(g.value,)).selected()
        assert names == FeatureOptions(groups=(g,)).selected() and names
        assert all(feature_specs(3)[n].unit and feature_specs(3)[n].meaning for n in names)


@pytest.fixture()
def workspace(tmp_path):
    """dense/: 4 cameras 1 m above z = 0 looking down (64 × 48, f = 50 px), photos of a chequered plane with a
    brighter patch, depth maps of the plane, and a fused cloud: the plane plus a patch floating 0.3 m above it."""
    cam = Camera.pinhole(50.0, 50.0, 32.0, 24.0, 64, 48)
    down = np.diag([1.0, -1.0, -1.0])
    centres = [(-0.05, 0.0, 1.0), (0.0, 0.0, 1.0), (0.05, 0.0, 1.0), (0.0, 0.05, 1.0)]
    views = {
        i + 1: View.from_matrix(i + 1, f"v{i}.png", 1, np.c_[down, -down @ np.array(c)]) for i, c in enumerate(centres)
    }
    cams = Cameras({1: cam}, views)
    ws = DenseWorkspace(tmp_path / "dense")
    ws.make_dirs()
    write_model(ws.sparse, cams)
    for i, v in enumerate(cams):
        rows, cols = np.mgrid[0:48, 0:64] + 0.5
        world_x = v.center[0] + (cols - 32) / 50
        world_y = v.center[1] - (rows - 24) / 50
        board = ((np.floor(world_x / 0.04) + np.floor(world_y / 0.04)) % 2) * 150 + 40 + 10 * i  # view-dependent
        write_image(ws.images / v.name, np.repeat(board.astype(np.uint8)[..., None], 3, axis=2))
        depth = np.ones((48, 64), np.float32)
        depth[:4] = 0.0  # a band without depth
        write_array(ws.depth_map(v.name), depth)
        write_array(ws.normal_map(v.name), np.dstack([np.zeros((48, 64, 2)), -np.ones((48, 64))]))
    g = np.arange(-0.38, 0.4, 0.02)
    x, y = np.meshgrid(g, g, indexing="ij")
    plane = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    patch = plane[(np.abs(plane[:, 0]) < 0.1) & (np.abs(plane[:, 1]) < 0.1)] + [0, 0, 0.3]
    pts = np.r_[plane, patch]
    rng = np.random.default_rng(0)
    normals = np.tile([0, 0, 1.0], (len(pts), 1))
    normals[::7] = 0.0  # some points without a normal
    cloud = PointCloud(pts, colors=rng.integers(0, 255, (len(pts), 3)).astype(np.uint8), normals=normals)
    write_ply(ws.fused_ply, cloud)
    vis = [np.array([0, 1, 2, 3])[: 1 + i % 4] for i in range(len(pts))]  # 1 to 4 fusing views
    write_vis(ws.fused_vis, vis)
    truth = np.r_[np.zeros(len(plane), np.uint8), np.ones(len(patch), np.uint8)]
    return ws, truth


def test_all_seven_groups_on_a_dense_workspace_and_the_model_round_trip(workspace, tmp_path):
    ws, truth = workspace
    cloud = read_fused(ws.root)
    views = views_from_workspace(ws.root)
    opts = FeatureOptions(groups=ALL_GROUPS_EXTENDED)
    t = compute_features(cloud, opts, views)
    assert t.names == opts.selected() and np.isfinite(t.values).all()
    # The depth maps (of the plane, 1 m away) put the floating patch's points 0.3 m = 15 spacings further along
    # their rays wherever the map is valid; the plane's points agree with them.
    floating = truth == 1
    dist = t.column("fusion_backproj_dist")
    assert np.median(dist[floating]) > 10 * np.median(dist[~floating])
    with pytest.raises(ConfigError, match="fusion, view_dependent, image_boundaries, image_texture"):
        compute_features(cloud, FeatureOptions(groups=NEW))
    model, _ = train(t, truth, load_classes(), opts, ForestOptions(n_estimators=4, n_jobs=1))
    back = load_model(save_model(model, tmp_path / "m.skops"))
    assert back.feature_options.groups == ALL_GROUPS_EXTENDED and back.feature_names == t.names
    # A model of only the new groups: its options select the same columns again.
    sub = FeatureOptions(names=("fusion", "edge_distance_px"))
    t2 = compute_features(cloud, sub, views)
    np.testing.assert_array_equal(t2.values, t.select(t2.names).values)
    m2, _ = train(t2, truth, load_classes(), sub, ForestOptions(n_estimators=2, n_jobs=1))
    back2 = load_model(save_model(m2, tmp_path / "m2.skops"))
    assert back2.feature_options.selected() == t2.names
