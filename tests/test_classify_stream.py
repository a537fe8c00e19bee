"""The streamed classification (classify.stream, ``run --memory-limit``) against the in-memory one, the truth:
classify/points.ply byte for byte over 16 cells with points exactly on their borders, the stage's record, and a
limit too small refused.

The scene is tiny: 2 400 points on a wavy 2 m × 2 m surface seen by 3 synthetic views, a small forest trained on
its features (every group: geometric at 2 scales with k = 8, radiometric, multi-view) that smooths its
probabilities once. A
grid of 4 × 4 cells of 0.5 m is patched in (the memory plan cannot make several cells of so few points), with a
halo too small for the coarse level (0.15 m) so that cells are redone with larger halos, as a real cloud's would
be where the first halo is not enough.
"""

from __future__ import annotations

import numpy as np
import pytest

import classify.stream as stream
from classify.classes import load_classes
from classify.features import ALL_GROUPS, FeatureOptions, GeometricOptions, ViewData, compute_features
from classify.model import ForestOptions, train
from classify.run import ClassifiedCloud, feature_options_for, predict_table, write_classified
from core.cameras import Camera, Cameras, View
from core.errors import ConfigError
from core.io.origin import sidecar_path
from core.io.point_stream import cloud_source
from core.pointcloud import PointCloud
from eval.c2c_stream import Grid

UTM = np.array([500_000.0, 5_200_000.0, 300.0])
GRID = Grid(0.0, 0.0, 0.5, 4, 4)


def _cloud(n: int = 2_400, seed: int = 3) -> PointCloud:
    """Random points on z = 0.1 sin(3x) + noise over [0, 2]², 64 of them exactly on the grid's inner lines (x or y
    in {0.5, 1, 1.5}), 6 exact duplicates; colours, unit normals and visibility of 1 to 3 of the views."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 2.0, (n, 2))
    xy[:32, 0] = rng.choice([0.5, 1.0, 1.5], 32)
    xy[32:64, 1] = rng.choice([0.5, 1.0, 1.5], 32)
    xy[64:68] = [[0.5, 0.5], [1.0, 1.5], [1.5, 1.0], [1.0, 1.0]]
    z = 0.1 * np.sin(3.0 * xy[:, 0]) + rng.normal(0.0, 0.004, n)
    z[n // 2 : n // 2 + 200] += 0.05 * rng.random(200)  # a rougher patch: something to classify
    pos = np.column_stack([xy, z])
    pos[100:106] = pos[200:206]
    normals = rng.normal(size=(n, 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    colors = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    vis = [np.sort(rng.choice([1, 2, 3], rng.integers(1, 4), replace=False)) for _ in range(n)]
    return PointCloud(pos, UTM, colors, normals, visibility=vis)


def _views() -> ViewData:
    """3 pinhole views 3 m above the surface looking down, random photos and depth maps at 3 m − 0.1 sin(3x)."""
    cam = Camera.pinhole(60.0, 60.0, 40.0, 30.0, 80, 60)
    down = np.diag([1.0, -1.0, -1.0])
    views = {}
    for i, cx in zip((1, 2, 3), (0.8, 1.0, 1.2), strict=True):
        centre = np.array([cx, 1.0, 3.0])
        views[i] = View.from_matrix(i, f"v{i}.png", 1, np.c_[down, -down @ centre])
    cams = Cameras({1: cam}, views)
    rng = np.random.default_rng(11)
    photos = {v.name: rng.integers(0, 256, (60, 80, 3)).astype(np.uint8) for v in cams}
    depths = {v.name: (3.0 + rng.normal(0, 0.01, (60, 80))).astype(np.float32) for v in cams}
    return ViewData(cams, photos.__getitem__, depths.__getitem__)


@pytest.fixture(scope="module")
def scene():
    """The cloud, the views and a model trained on the cloud's own features (labels: the rough patch and a few
    points with a high red channel), smoothing once."""
    cloud, views, classes = _cloud(), _views(), load_classes()
    opts = FeatureOptions(groups=ALL_GROUPS, geometric=GeometricOptions(voxel_factors=(1.0, 3.0), k=8))
    table = compute_features(cloud, opts, views)
    labels = np.full(len(cloud), classes.collaborative_code, np.uint8)
    other = next(c.code for c in classes.classes if c.needs_splats)
    labels[len(cloud) // 2 : len(cloud) // 2 + 200] = other
    labels[cloud.colors[:, 0] > 240] = other
    model, _ = train(table, labels, classes, opts, ForestOptions(n_estimators=8, n_jobs=1, smooth_passes=1))
    model.info["smooth_passes"] = 1
    return cloud, views, classes, model


def _in_memory(path, cloud, views, classes, model):  # noqa: ANN001, ANN202
    table = compute_features(cloud, feature_options_for(model), views)
    pred = predict_table(model, table, classes)
    write_classified(path, ClassifiedCloud(cloud, pred, table.spacing, classes, "m", 0.0, table.names))
    return table.spacing, pred


@pytest.mark.parametrize("use_model", [True, False], ids=["model", "fallback"])
def test_streamed_points_ply_is_the_in_memory_one(scene, tmp_path, monkeypatch, use_model):
    cloud, views, classes, model = scene
    model = model if use_model else None
    spacing, pred = _in_memory(tmp_path / "memory.ply", cloud, views, classes, model)
    monkeypatch.setattr(stream, "_choose_grid", lambda *a, **k: (GRID, 0.15))
    opts = stream.ClassifyStreamOptions(memory_limit_mb=1024, chunk_size=500, work_dir=tmp_path)
    out = tmp_path / "streamed.ply"
    result = stream.classify_stream(cloud_source(cloud, 700), model, views, classes, out, opts)
    assert result.cells == 16 and result.regrown > 0
    assert result.spacing == spacing
    assert (tmp_path / "streamed.ply").read_bytes() == (tmp_path / "memory.ply").read_bytes()
    assert sidecar_path(out).read_bytes() == sidecar_path(tmp_path / "memory.ply").read_bytes()
    assert result.needs_splats == int(np.count_nonzero(pred.needs_splats))
    assert result.per_code == {c.code: int(np.count_nonzero(pred.classification == c.code)) for c in classes.classes}
    names = {"memory.ply", "streamed.ply", sidecar_path(out).name, sidecar_path(tmp_path / "memory.ply").name}
    assert {p.name for p in tmp_path.iterdir()} == names  # the cell files are gone


def test_cells_and_halo_of_a_cell_hold_every_point_near_it(scene, tmp_path):
    """Every point within the halo of a cell's rectangle is loaded with it (the x-y region of the proofs)."""
    cloud = scene[0]
    job = stream._Job(cloud_source(cloud), GRID, 0.2, FeatureOptions(), None, None, load_classes(), 0.5,
                      len(cloud), cloud.positions.min(0), cloud.positions.max(0), UTM, 500)  # fmt: skip
    cells = stream._Cells(tmp_path / "cells", GRID, 0.2, (True, True, True))
    cells.add_cloud(cloud)
    for key in (0, 5, 15):
        loaded = stream._load(cells, key, job)
        room = stream._room(cloud.positions[:, :2], GRID, key, 0.2)
        np.testing.assert_array_equal(loaded.index, np.flatnonzero(room >= 0))
        gathered = stream._gather(job, key, 0.2)
        np.testing.assert_array_equal(gathered.index, loaded.index)
        for a, b in zip(gathered.cloud.visibility, loaded.cloud.visibility, strict=True):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(gathered.cloud.colors, loaded.cloud.colors)


def test_a_limit_too_small_is_refused_naming_it():
    with pytest.raises(ConfigError, match="memory_limit_mb = 300"):
        stream.plan_memory(300)
    with pytest.raises(ConfigError, match="300"):
        stream.ClassifyStreamOptions(memory_limit_mb=300).plan()


def _project(root):  # noqa: ANN001, ANN202
    """A project whose dense/ holds 3 views 1 m above a chequered plane (photos, depth maps) and a fused cloud of
    3 000 random points on it (4 of them on the patched grid's lines) with a patch floating 0.3 m above."""
    from core.io.colmap import write_model
    from core.io.images import write_image
    from core.io.ply import write_ply
    from hybridsplat.layout import ProjectLayout
    from recon.workspace import DenseWorkspace, write_array, write_vis

    layout = ProjectLayout(root)
    ws = DenseWorkspace(layout.dense)
    ws.make_dirs()
    cam = Camera.pinhole(50.0, 50.0, 32.0, 24.0, 64, 48)
    down = np.diag([1.0, -1.0, -1.0])
    views = {i + 1: View.from_matrix(i + 1, f"v{i}.png", 1, np.c_[down, -down @ [cx, 0.0, 1.0]])
             for i, cx in enumerate((-0.05, 0.0, 0.05))}  # fmt: skip
    write_model(ws.sparse, Cameras({1: cam}, views))
    rows, cols = np.mgrid[0:48, 0:64] + 0.5
    for v in views.values():
        x, y = v.center[0] + (cols - 32) / 50, v.center[1] - (rows - 24) / 50
        board = ((np.floor(x / 0.04) + np.floor(y / 0.04)) % 2).astype(np.uint8) * 180 + 40
        write_image(ws.images / v.name, np.repeat(board[..., None], 3, axis=2))
        write_array(ws.depth_map(v.name), np.ones((48, 64), np.float32))
    rng = np.random.default_rng(7)
    pts = np.c_[rng.uniform(-0.4, 0.4, (3000, 2)), rng.normal(0.0, 0.002, 3000)]
    pts[:4, :2] = [[-0.15, -0.15], [0.15, 0.0], [-0.15, 0.3], [0.15, 0.15]]
    floating = (np.abs(pts[:, 0]) < 0.1) & (np.abs(pts[:, 1]) < 0.1)
    pts[floating, 2] += 0.3
    colors = rng.integers(0, 255, (len(pts), 3)).astype(np.uint8)
    write_ply(ws.fused_ply, PointCloud(pts, UTM, colors, np.tile(np.float32([0, 0, 1]), (len(pts), 1))))
    write_vis(ws.fused_vis, [np.arange(3)] * len(pts))
    return layout


def test_stage_with_a_memory_limit_writes_the_same_points_and_records_it(tmp_path, monkeypatch):
    from classify.options import ClassifyOptions
    from hybridsplat.config import ProjectConfig
    from hybridsplat.stages.base import StageContext
    from hybridsplat.stages.classify import ClassifyStage

    layout = _project(tmp_path / "p")

    def run(**options):  # noqa: ANN003, ANN202
        config = ProjectConfig().with_stage_options("classify", ClassifyOptions(**options))
        ctx = StageContext(layout=layout, config=config, source=None)  # type: ignore[arg-type]
        result = ClassifyStage().run(ctx)
        return result, layout.classified_points.read_bytes(), ClassifyStage().expected_bytes(ctx)

    memory, memory_ply, memory_bytes = run()
    monkeypatch.setattr(stream, "_choose_grid", lambda *a, **k: (Grid(-0.45, -0.45, 0.3, 3, 3), 0.3))
    streamed, streamed_ply, streamed_bytes = run(memory_limit_mb=1024)
    assert streamed_ply == memory_ply
    assert streamed.memory_limit_mb == 1024 and streamed.cells == 9 and streamed.peak_rss_mb > 0
    for key in ("points", "needs_splats", "per_class", "spacing_m", "model", "figures"):
        assert getattr(streamed, key) == getattr(memory, key), key
    assert streamed_bytes > memory_bytes
    assert "classified in 9 cells (peak" in ClassifyStage().summary(streamed)
    assert not [p for p in layout.classified_points.parent.iterdir() if p.name.startswith("hybridsplat_")]
    with pytest.raises(ConfigError, match="memory_limit_mb = 100"):
        ClassifyOptions(memory_limit_mb=100)


def test_run_memory_limit_is_one_flag_that_sets_classify_and_convert():
    from hybridsplat.commands.run import _run_parameters
    from hybridsplat.commands.stages import apply_cli_values
    from hybridsplat.stages.classify import ClassifyStage
    from hybridsplat.stages.convert import ConvertStage

    assert [p.name for p in _run_parameters()].count("memory_limit") == 1
    for stage in (ClassifyStage, ConvertStage):
        options = apply_cli_values(stage.Options(), stage.run_options, {"memory_limit": 1024.0})
        assert options.memory_limit_mb == 1024.0
