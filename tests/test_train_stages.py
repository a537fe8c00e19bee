"""The train, clean and merge stages as thin shells over fusion.train / fusion.clean / fusion.merge, on a hand-made
project (ring cameras around a known Gaussian scene; the right half of it is the region that needs splats)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from test_train_trainer import alpha_masks, blob_set, render_all, ring_cameras

from core.gaussians import GaussianSet
from core.io import read_point_cloud, write_point_cloud
from core.io.colmap import write_model
from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply
from core.io.images import write_image
from core.pointcloud import PointCloud
from fusion.convert import Source
from hybridsplat.config import ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.options import options_with
from hybridsplat.stages.base import StageContext
from hybridsplat.stages.clean import CleanStage
from hybridsplat.stages.merge import MergeStage
from hybridsplat.stages.train import MaskedTrainingOptions, TrainStage


def make_project(root) -> tuple[ProjectLayout, GaussianSet, np.ndarray]:
    layout = ProjectLayout(root)
    cams = ring_cameras(6)
    truth = blob_set(200, 0)
    needs = truth.means[:, 0] > 0
    ws = layout.dense_workspace
    ws.make_dirs()
    write_model(ws.sparse, cams)
    write_model(layout.sparse, cams)
    for name, img in render_all(truth, cams).items():
        write_image(ws.images / name, np.clip(img * 255, 0, 255).astype(np.uint8))
    for name, m in alpha_masks(truth.subset(needs), cams, 0.5).items():
        write_image(layout.mask_path(name), (m * 255).astype(np.uint8))
    colours = np.clip(truth.base_colors * 255, 0, 255).astype(np.uint8)
    cloud = PointCloud(truth.means, colors=colours, fields={"needs_splats": needs.astype(np.uint8)})
    write_point_cloud(layout.classified_points, cloud)
    mvs = truth.subset(slice(None))
    mvs.fields = {"source": np.full(len(mvs), 1, np.uint8)}
    write_gaussian_ply(layout.mvs_gaussians, mvs, extra_fields=True)
    return layout, truth, needs


def test_train_clean_merge_stages_write_the_hybrid(tmp_path) -> None:
    layout, truth, needs = make_project(tmp_path / "p")
    config = ProjectConfig().with_stage_options(
        "train",
        options_with(
            MaskedTrainingOptions,
            {
                "training.iterations": 24,
                "init.rays_per_view": 20,
                "training.sh_degree": 1,
                "snapshot_iterations": [12],
            },
        ),  # fmt: skip
    )
    ctx = StageContext(layout=layout, config=config, source=SimpleNamespace(holdout_names=()))
    train, clean, merge = TrainStage(), CleanStage(), MergeStage()
    assert train.needs(ctx) is None
    counts = train.run(ctx)
    assert counts.iterations == 24 and counts.views_used > 0
    assert counts.seeds.mvs == int(needs.sum()) and counts.context_gaussians == int((~needs).sum())
    trained = read_gaussian_ply(layout.trained_splats)
    assert len(trained) == counts.trained and (layout.snapshots_dir / "splats_000012.ply").is_file()
    assert clean.needs(ctx) is None
    c = clean.run(ctx)
    assert c.kept + c.outside_masks + c.low_opacity + c.extreme_scale + c.isolated == c.input
    m = merge.run(ctx)
    merged = read_gaussian_ply(layout.merged_ply)
    assert m.mvs == int((~needs).sum()) and m.splats == c.kept
    assert int((merged.fields["source"] == Source.MVS).sum()) == m.mvs
    assert layout.splats_export.is_file()
    # the point product: the MVS points and only the trustworthy splats, every left-out splat counted with a reason
    p = m.point_splats  # the selection's counts (fusion.clean.SurveyPointCounts), by name
    assert p["input"] == c.kept
    left_out = p["low_opacity"] + p["thick"] + p["large"] + p["few_views"] + p["off_masks"] + p["interior"]
    assert p["kept"] + left_out == p["input"]
    points = read_point_cloud(layout.merged_points_ply)
    q = m.point_needs_mvs  # the needs_splats MVS points that pass the same view and rim tests
    assert q["input"] == int(needs.sum()) and q["low_opacity"] == q["thick"] == q["large"] == 0  # no shape tests
    assert len(points) == m.points == m.mvs + p["kept"] + q["kept"]
    assert int((points.fields["source"] == Source.SPLAT).sum()) == p["kept"]
    # merged.ply's surface field: every MVS Gaussian, and the splats that pass the surface test, counted by reason
    s = m.surface_splats
    surface = np.asarray(merged.fields["surface"]) > 0.5
    is_mvs = merged.fields["source"] == Source.MVS
    assert surface[is_mvs].all() and int(surface[~is_mvs].sum()) == s["kept"]
    assert s["input"] == c.kept and s["thick"] == s["large"] == s["interior"] == 0  # not part of that rule
    assert s["kept"] + s["low_opacity"] + s["few_views"] + s["off_masks"] + s["behind"] == s["input"]


def test_training_masks_are_the_region_masks_dilated_by_the_recorded_margin(tmp_path) -> None:
    import cv2

    from core.io.json_io import write_json_atomic
    from hybridsplat.project_io import read_region_masks

    layout, _, _ = make_project(tmp_path / "p")
    cams = ring_cameras(6)
    names = [v.name for v in cams]
    record = {"per_photo": [{"name": names[0], "train_margin_px": 3}, {"name": names[1], "train_margin_px": 0}]}
    write_json_atomic(layout.record("masks"), record)
    region, train = read_region_masks(layout, cams), read_region_masks(layout, cams, training=True)
    assert region.keys() == train.keys() and region[names[0]].any()
    # scipy's dilation with the disk of radius 3 that the masks stage uses (OpenCV's 7 × 7 ellipse element)
    from scipy import ndimage

    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7)).astype(bool)
    np.testing.assert_array_equal(train[names[0]], ndimage.binary_dilation(region[names[0]], structure=disk))
    assert train[names[0]].sum() > region[names[0]].sum()
    for name in names[1:]:  # margin 0, or no entry in the record
        np.testing.assert_array_equal(train[name], region[name])


def test_train_is_skipped_without_classification(tmp_path) -> None:
    layout = ProjectLayout(tmp_path / "empty")
    ctx = StageContext(layout=layout, config=ProjectConfig(), source=SimpleNamespace(holdout_names=()))
    assert "classified" in TrainStage().needs(ctx)
    assert "no trained splats" in CleanStage().needs(ctx)


def test_point_product_keeps_the_needs_splats_mvs_points_of_the_chosen_classes(tmp_path) -> None:
    """Textureless (and thin) MVS points that needed splats go into the point product as they are; reflective ones
    only through the view and rim tests; ``points_needs_mvs_classes = ()`` keeps none by class."""
    import json

    from fusion.merge_options import MergeOptions

    layout, truth, needs = make_project(tmp_path / "p")
    codes = np.zeros(len(truth), np.uint8)
    idx = np.flatnonzero(needs)
    codes[idx[::2]] = 3  # textureless
    codes[idx[1::2]] = 1  # reflective
    cloud = read_point_cloud(layout.classified_points)
    cloud.fields["classification"] = codes
    write_point_cloud(layout.classified_points, cloud)
    names = ("collaborative", "reflective", "transparent", "textureless", "thin")
    classes = [{"name": n, "code": c, "needs_splats": c > 0} for c, n in enumerate(names)]
    layout.classify_report.write_text(json.dumps({"classes": {"class": classes}}))
    train_options = options_with(MaskedTrainingOptions, {"training.iterations": 12, "init.rays_per_view": 20})
    config = ProjectConfig().with_stage_options("train", train_options)
    ctx = StageContext(layout=layout, config=config, source=SimpleNamespace(holdout_names=()))
    TrainStage().run(ctx)
    CleanStage().run(ctx)
    products = {}
    for kept in (("textureless", "thin"), ()):
        ctx.config = config.with_stage_options("merge", MergeOptions(needs_mvs_classes=kept))
        counts = MergeStage().run(ctx)
        products[kept] = (counts, read_point_cloud(layout.merged_points_ply))
    (with_classes, pts_with), (without, pts_without) = products[("textureless", "thin")], products[()]
    textureless = truth.means[codes == 3]
    assert with_classes.point_needs_mvs_classes == {"textureless": len(textureless), "thin": 0}
    assert without.point_needs_mvs_classes == {}

    def has(points, queries):
        d = np.linalg.norm(points.positions[None, :, :] - queries[:, None, :], axis=2).min(axis=1)
        return d < 1e-6

    assert has(pts_with, textureless).all()
    assert not has(pts_without, textureless).all()  # the rule alone drops some of them
    reflective = truth.means[codes == 1]
    np.testing.assert_array_equal(has(pts_with, reflective), has(pts_without, reflective))
    extra = len(pts_with) - len(pts_without)
    assert extra == int((~has(pts_without, textureless)).sum()) > 0


def test_a_collaborative_only_project_trains_no_fill_and_merges_the_survey_layer(tmp_path) -> None:
    """Issue 29's skip: every region mask empty (no non-collaborative point, no hole) → no fill training, said
    with its reason; the merge writes the survey layer alone."""
    from core.io.json_io import write_json_atomic

    layout, truth, _ = make_project(tmp_path / "p")
    names = [v.name for v in ring_cameras(6)]
    for name in names:
        write_image(layout.mask_path(name), np.zeros((48, 64), np.uint8))
    per_photo = [{"name": n, "coverage": 0.0, "empty": True, "train_margin_px": 0} for n in names]
    write_json_atomic(layout.record("masks"), {"per_photo": per_photo, "training_needed": False})
    ctx = StageContext(layout=layout, config=ProjectConfig(), source=SimpleNamespace(holdout_names=()))
    assert TrainStage().needs(ctx) == "every region mask is empty: no non-collaborative region or hole needs splats"
    assert "stage 'train' was skipped" in CleanStage().needs(ctx)
    counts = MergeStage().run(ctx)
    merged = read_gaussian_ply(layout.merged_ply)
    assert counts.splats == 0 and counts.mvs == len(merged) > 0.9 * len(truth)  # the merge's filter aside
    assert (np.asarray(merged.fields["source"]) == Source.MVS).all()
    converted = read_gaussian_ply(layout.mvs_gaussians)
    rows = {tuple(p) for p in converted.means + converted.origin}
    assert all(tuple(p) in rows for p in merged.means + merged.origin)  # every position exactly an MVS Gaussian's
