"""classify.run and the stages' functions on a hand-made dense workspace: three views over a chequered plane with a
floating non-collaborative patch."""

from __future__ import annotations

import numpy as np
import pytest

from classify.classes import load_classes
from classify.features import FeatureGroup, FeatureOptions, compute_features, views_from_workspace
from classify.model import ForestOptions, save_model, train
from classify.run import classify_dense, project_masks, write_classified
from core.cameras import Camera, Cameras, View
from core.errors import InputFileError
from core.io.colmap import write_model
from core.io.images import read_image, write_image
from core.io.json_io import write_json_atomic
from core.io.ply import read_ply, write_ply
from core.pointcloud import PointCloud
from recon.workspace import DenseWorkspace, write_array, write_vis


@pytest.fixture()
def workspace(tmp_path):
    """dense/: 3 cameras 1 m above z = 0 looking down (64 × 48, f = 50 px), photos of a chequered plane,
    depth maps of the plane, and a fused cloud: the plane (on it) plus a patch floating 0.3 m above it."""
    cam = Camera.pinhole(50.0, 50.0, 32.0, 24.0, 64, 48)
    down = np.diag([1.0, -1.0, -1.0])
    views = {}
    for i, cx in enumerate((-0.05, 0.0, 0.05)):
        centre = np.array([cx, 0.0, 1.0])
        views[i + 1] = View.from_matrix(i + 1, f"v{i}.png", 1, np.c_[down, -down @ centre])
    cams = Cameras({1: cam}, views)
    ws = DenseWorkspace(tmp_path / "dense")
    ws.make_dirs()
    write_model(ws.sparse, cams)
    for v in cams:
        rows, cols = np.mgrid[0:48, 0:64] + 0.5
        world_x = v.center[0] + (cols - 32) / 50
        world_y = v.center[1] - (rows - 24) / 50
        board = ((np.floor(world_x / 0.04) + np.floor(world_y / 0.04)) % 2).astype(np.uint8) * 180 + 40
        write_image(ws.images / v.name, np.repeat(board[..., None], 3, axis=2))
        write_array(ws.depth_map(v.name), np.ones((48, 64), np.float32))
        write_array(ws.normal_map(v.name), np.dstack([np.zeros((48, 64, 2)), -np.ones((48, 64))]))
    g = np.arange(-0.38, 0.4, 0.04)  # square centres of the 4 cm chequer: colours are unambiguous
    x, y = np.meshgrid(g, g, indexing="ij")
    plane = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    patch = plane[(np.abs(plane[:, 0]) < 0.1) & (np.abs(plane[:, 1]) < 0.1)] + [0, 0, 0.3]
    pts = np.r_[plane, patch]
    rng = np.random.default_rng(0)
    cloud = PointCloud(pts, colors=rng.integers(0, 255, (len(pts), 3)).astype(np.uint8),
                       normals=np.tile([0, 0, 1.0], (len(pts), 1)))  # fmt: skip
    write_ply(ws.fused_ply, cloud)
    write_vis(ws.fused_vis, [np.array([0, 1, 2])] * len(pts))
    truth = np.r_[np.zeros(len(plane), np.uint8), np.ones(len(patch), np.uint8)]
    return ws, truth


def test_fallback_classifies_and_masks_are_written(workspace, tmp_path):
    ws, truth = workspace
    result = classify_dense(ws.root, model="none")
    assert result.model == "fallback" and len(result.cloud) == len(truth)
    # The floating patch is in front of what both depth maps see: free-space violations flag it.
    assert result.prediction.needs_splats[truth == 1].all()
    assert result.prediction.needs_splats[truth == 0].mean() < 0.05
    points = write_classified(tmp_path / "classify" / "points.ply", result)
    back = read_ply(points)
    assert back.fields["classification"].dtype == np.uint8 and back.fields["needs_splats"].dtype == np.uint8
    assert back.fields["probability"].dtype == np.float32
    assert np.array_equal(back.fields["needs_splats"] > 0, result.prediction.needs_splats)
    report = tmp_path / "classify" / "report.json"
    write_json_atomic(report, result.report())
    record = project_masks(points, report, ws.sparse, lambda n: tmp_path / "masks" / f"{n}.png")
    assert record["photos"] == 3 and record["training_needed"]
    mask = read_image(tmp_path / "masks" / "v0.png.png", grayscale=True)
    assert set(np.unique(mask)) <= {0, 255} and mask[24, 32 + 2] == 255  # the patch is seen near the centre
    held = project_masks(points, report, ws.sparse, lambda n: tmp_path / "m2" / f"{n}.png", held_out={"v1.png"})
    assert held["photos"] == 2 and not (tmp_path / "m2" / "v1.png.png").exists()


def test_trained_model_in_classify_dense(workspace, tmp_path):
    ws, truth = workspace
    from recon.workspace import read_fused

    cloud = read_fused(ws.root)
    opts = FeatureOptions(groups=(FeatureGroup.GEOMETRIC, FeatureGroup.MULTIVIEW))
    table = compute_features(cloud, opts, views_from_workspace(ws.root))
    model, _ = train(table, truth, load_classes(), opts, ForestOptions(n_estimators=4, n_jobs=1))
    path = save_model(model, tmp_path / "m.skops")
    result = classify_dense(ws.root, model=str(path))
    assert (result.prediction.needs_splats == (truth == 1)).mean() > 0.95
    assert result.model == str(path)
    with pytest.raises(InputFileError):
        classify_dense(ws.root, model=str(tmp_path / "missing.skops"))


def _decode_png(data: bytes) -> np.ndarray:
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None
    return img[..., ::-1]  # RGB


def test_figures_show_the_classes_importances_and_masks(tmp_path):
    """The class figure holds the colour of each class present and none of an absent one; the mask overlay is
    red exactly on the mask; the importances chart is an image."""
    from classify.figures import class_colour, classified_cloud_png, importances_png, masks_png, overlay

    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 1, (3000, 3))
    codes = np.where(pts[:, 0] > 0.8, 1, 0).astype(np.uint8)  # a reflective strip; no transparent points
    img = _decode_png(classified_cloud_png(pts, codes, load_classes())).astype(int)

    def has(code: int) -> bool:
        target = np.round(np.array(class_colour(code)) * 255).astype(int)
        return bool((np.abs(img - target).max(axis=2) <= 3).sum() > 20)

    assert has(0) and has(1) and not has(2)
    photo = np.full((40, 60, 3), 200, np.uint8)
    mask = np.zeros((40, 60), bool)
    mask[10:20, 30:50] = True
    over = overlay(photo, mask)
    inner = over[12:18, 32:48].reshape(-1, 3)
    assert np.all(inner[:, 0] > inner[:, 1] + 50)  # red blend inside
    assert np.array_equal(over[30:, :20], photo[30:, :20])  # untouched far from the mask
    assert _decode_png(masks_png([("a.png", photo, mask, 0.08)] * 3)).shape[0] > 100
    assert _decode_png(importances_png(["a", "b", "c"], [0.5, 0.3, 0.2])).shape[1] > 100


def test_report_shows_the_classification_figures(workspace, tmp_path):
    """classify + masks on the hand-made workspace write the figures; the report's HTML embeds them."""
    from classify.run import write_classify_figures
    from eval.report import to_html

    ws, _ = workspace
    result = classify_dense(ws.root, model="none")
    points = write_classified(tmp_path / "classify" / "points.ply", result)
    report = tmp_path / "classify" / "report.json"
    write_json_atomic(report, result.report())
    figs = write_classify_figures(result, tmp_path / "fig" / "classes.png", tmp_path / "fig" / "importances.png")
    assert [f.name for f in figs] == ["classes.png"]  # the fallback has no importances
    record = project_masks(
        points, report, ws.sparse, lambda n: tmp_path / "masks" / f"{n}.png",
        figure=tmp_path / "fig" / "masks.png", image_dir=ws.images,
    )  # fmt: skip
    assert record["figure"] and (tmp_path / "fig" / "masks.png").is_file()
    stages = {
        "classify": {"counts": {"points": 10, "needs_splats": 2, "per_class": {"a": 8}, "model": "m",
                                "figures": ["fig/classes.png"]}},
        "masks": {"counts": {"photos": 3, "empty": 0, "mean_coverage": 0.1, "training_needed": True,
                             "figures": ["fig/masks.png"]}},
    }  # fmt: skip
    from hybridsplat.stages import stage_named

    report_data = _minimal_report(tmp_path, stages)
    report_data["sections"] = []
    for name in ("classify", "masks"):  # as the report stage makes them from the recorded results
        stage = stage_named(name)
        section = stage.report_section(stage.Result.from_json(stages[name]["counts"]))
        report_data["sections"].append({"title": section.title, "lines": section.lines, "figures": section.figures})
    page = to_html(report_data, None, None)
    assert "Classification and region masks" in page and page.count("data:image/jpeg;base64,") == 2
    assert "20.0% need splats" in page and "mean coverage 10.0%" in page
    assert "Classification and region masks" not in to_html(_minimal_report(tmp_path, {}), None, None)


def _minimal_report(root, stages) -> dict:
    for st in stages.values():
        st.update(seconds=1.0, peak_mb=10.0, skipped=False, reason=None, cached=False)
    return {
        "project": str(root), "generated_utc": "now", "timings": {"total_seconds": 0.0}, "products": {},
        "stages": stages, "versions": {}, "config": {}, "units": "m",
    }  # fmt: skip
