"""The whole pipeline on the tiny synthetic scene: every stage recorded, products written, reruns skip what is
current, per-stage commands run the same stages, and a bad input leaves nothing behind."""

import json
import shutil

import numpy as np
import pytest
from scipy.spatial import cKDTree

from core.errors import ConfigError
from core.io.gaussian_ply import read_gaussian_ply
from data_synth import generate_scene
from fusion.appearance import AppearanceOptions
from fusion.train.masked import MaskedTrainingOptions, WholeSceneOptions
from hybridsplat.cli import main
from hybridsplat.config import InputOptions, ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.options import options_with
from hybridsplat.pipeline import load_config, run_pipeline
from hybridsplat.stages import STAGES, stage_options_types

# tiny trains its splats (and the whole-scene baseline) for a few dozen steps in tests (the default is thousands)
FAST_STAGES = {
    "train": options_with(MaskedTrainingOptions, {"training.iterations": 40, "snapshot_iterations": [20]}),
    "baseline": options_with(WholeSceneOptions, {"enabled": True, "training.iterations": 40, "checkpoints": [20]}),
    "appearance": options_with(AppearanceOptions, {"training.iterations": 60, "training.min_iterations": 60}),
}


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    root = tmp_path_factory.mktemp("pipeline")
    scene = generate_scene("tiny", root / "scene", seed=0)
    project = root / "project"
    run_pipeline(project, ProjectConfig(input=InputOptions(path=str(scene)), stages=FAST_STAGES))
    return scene, project


def test_every_stage_is_recorded_with_outputs(project):
    scene, project = project
    layout = ProjectLayout(project)
    stages = json.loads(layout.manifest.read_text())["stages"]
    assert list(stages) == [s.name for s in STAGES]
    for name, record in stages.items():
        if name == "mesh":  # off unless a budget is given (run --mesh N); tests/test_mesh_stage.py runs it
            assert record["skipped"] and "no mesh asked" in record["reason"]
            continue
        if name == "control":  # only with ground control (run --control); tests/test_control_*.py run it
            assert record["skipped"] and "no --control file" in record["reason"]
            continue
        if name == "tiles":  # off unless asked (run --tiles); tests/test_tiled_run.py runs it
            assert record["skipped"] and record["reason"].startswith("off")
            continue
        assert not record["skipped"] and record["seconds"] > 0 and record["outputs"], name
    for path in (
        layout.config,
        layout.sparse / "cameras.bin",
        layout.fused_ply,
        layout.fused_vis,
        layout.mvs_gaussians,
        layout.merged_ply,
        layout.merged_points_ply,
        layout.merged_points_las,
        layout.metrics_json,
        layout.per_material_json,
        layout.baseline_splats,
        layout.report_html,
        layout.log("mvs"),
    ):
        assert path.is_file(), path
    merged = read_gaussian_ply(layout.merged_ply)
    assert len(merged) == stages["merge"]["counts"]["written"] > 100
    # COLMAP's own output went to the stage's log, not the terminal
    assert "Undistorting image" in layout.log("mvs").read_text()


def test_config_round_trip_documents_every_stage(project):
    _, project = project
    config = load_config(project)
    assert config.input.path and config.seed == 0
    for name, options_type in stage_options_types().items():
        assert config.options(name, options_type) == FAST_STAGES.get(name, options_type()), name


def test_report_schema_and_mvs_accuracy(project):
    scene, project = project
    report = json.loads((ProjectLayout(project).report_dir / "report.json").read_text())
    gsd = json.loads((scene / "scene.json").read_text())["gsd_m"]
    mvs = report["products"]["mvs"]
    for key in ("count", "mean", "std", "median", "rmse", "p95", "max", "completeness", "fscore"):
        assert mvs["c2c"][key] is not None, key
    # tiny is 96x72 px: MVS is coarse but must sit on the true surfaces within a few GSD
    assert mvs["c2c"]["median"] < 3 * gsd
    for part in ("full", "masked"):
        scores = mvs["images"][part]
        assert all(np.isfinite(scores[k]) for k in ("mse", "psnr", "ssim", "ms_ssim", "delta_e")), part


def test_three_products_side_by_side_with_scores_per_material(project):
    scene, project = project
    layout = ProjectLayout(project)
    report = json.loads((layout.report_dir / "report.json").read_text())
    for name in ("mvs", "baseline", "merged"):
        product = report["products"][name]
        assert not product["skipped"], name
        assert product["c2c"]["mean"] > 0 and product["c2c"]["completeness"] is not None, name
        assert np.isfinite(product["images"]["full"]["psnr"]) and np.isfinite(product["images"]["masked"]["psnr"])
    splats = report["products"]["splats"]  # the trained splats alone: geometry only
    assert splats["c2c"]["count"] > 0 and splats["images"]["full"] is None
    assert len(read_gaussian_ply(layout.baseline_splats)) > 0
    # per material: every material of the scene that the LiDAR saw, for every measured product
    materials = {m["name"] for m in json.loads((scene / "scene.json").read_text())["materials"]}
    per_material = json.loads(layout.per_material_json.read_text())
    assert set(per_material["products"]) == {
        "mvs", "baseline", "baseline_20", "splats", "merged", "mvs_filtered", "merged_no_background", "merged_unrefined"
    }  # fmt: skip
    seen = set(per_material["products"]["mvs"])
    assert seen and seen <= materials
    for name in ("mvs", "baseline", "merged"):
        rows = per_material["products"][name]
        assert all(0.0 <= r["completeness"] <= 1.0 for r in rows.values())
        assert any(r["psnr"] is not None for r in rows.values()), name
    assert "Table 5 — per ground-truth material" in (layout.report_dir / "report.md").read_text()


def test_the_filtered_mvs_control_is_the_mvs_part_of_merged(project):
    """The control beside merged: the MVS Gaussians and survey points the merge kept, measured alone."""
    from core.io import read_point_cloud
    from fusion.convert_options import Source

    _, project = project
    layout = ProjectLayout(project)
    products = json.loads(layout.metrics_json.read_text())["products"]
    points = read_point_cloud(layout.merged_points_ply)
    kept = int((points.fields["source"] == Source.MVS).sum())
    assert 0 < kept < len(points) and products["mvs_filtered"]["c2c"]["count"] == kept
    assert products["mvs_filtered"]["c2c"]["count"] <= products["mvs"]["c2c"]["count"]
    full = products["mvs_filtered"]["images"]["full"]
    assert np.isfinite(full["psnr"]) and full["psnr"] != products["merged"]["images"]["full"]["psnr"]
    text = (layout.report_dir / "report.md").read_text()
    assert "control: the MVS part of merged alone (no splats)" in text
    assert "whole scene: 40 steps (its whole step budget)" in text  # each trained product's step budget


def test_three_layers_the_survey_positions_untouched_and_the_background_in_the_viewer_product_only(project):
    """merged.ply: survey (MVS), fill (splats) and background layers by ``source``; every survey Gaussian sits
    exactly (bit for bit) where the MVS conversion put it; the survey points and C2C never see the background."""
    from core.io import read_point_cloud
    from fusion.convert_options import Source

    _, project = project
    layout = ProjectLayout(project)
    merged = read_gaussian_ply(layout.merged_ply)
    source = np.asarray(merged.fields["source"])
    counts = json.loads(layout.manifest.read_text())["stages"]["merge"]["counts"]
    assert counts["background"] == int((source == Source.BACKGROUND).sum()) > 0
    assert counts["mvs"] == int((source == Source.MVS).sum())
    assert counts["splats"] == int((source == Source.SPLAT).sum())
    mvs = read_gaussian_ply(layout.mvs_gaussians)
    survey = merged.subset(source == Source.MVS)
    assert np.array_equal(survey.origin, mvs.origin)
    known = {row.tobytes() for row in mvs.means}
    assert all(row.tobytes() in known for row in survey.means)  # positions never change
    background = merged.subset(source == Source.BACKGROUND)
    region = np.linalg.norm(survey.means - survey.means.mean(0), axis=1).max()
    assert np.linalg.norm(background.means - survey.means.mean(0), axis=1).min() > 2 * region
    assert Source.BACKGROUND not in set(read_point_cloud(layout.merged_points_ply).fields["source"].tolist())
    products = json.loads(layout.metrics_json.read_text())["products"]
    with_bg, without = products["merged"]["images"]["full"], products["merged_no_background"]["images"]["full"]
    assert with_bg["psnr"] > without["psnr"]  # the background layer draws what nothing else covers
    names = ("merged", "merged_no_background")
    figures = [{k: v for k, v in products[n]["c2c"].items() if k != "files"} for n in names]
    assert figures[0] == figures[1]  # and no survey figure changes
    assert "The merged product's layers" in (layout.report_dir / "report.md").read_text()


def test_the_survey_layer_is_refined_for_viewers_only(project):
    """splats/survey.ply: the converted MVS Gaussians row for row, positions bit for bit, appearance refined; the
    viewer product takes it, the survey points keep the converted attributes, and the control without it is
    measured beside merged with the same survey figures."""
    from core.io import read_point_cloud
    from fusion.convert_options import Source

    _, project = project
    layout = ProjectLayout(project)
    converted, refined = read_gaussian_ply(layout.mvs_gaussians), read_gaussian_ply(layout.survey_splats)
    assert np.array_equal(refined.means, converted.means) and np.array_equal(refined.origin, converted.origin)
    assert refined.sh_degree == 3 and not np.array_equal(refined.sh_dc, converted.sh_dc)
    merged = read_gaussian_ply(layout.merged_ply)
    survey = merged.subset(np.asarray(merged.fields["source"]) == Source.MVS)
    row_of = {row.tobytes(): i for i, row in enumerate(converted.means)}
    rows = np.array([row_of[row.tobytes()] for row in survey.means])
    np.testing.assert_array_equal(survey.sh_dc, refined.sh_dc[rows])  # the viewer product: refined
    points = read_point_cloud(layout.merged_points_ply)
    mvs_points = points.subset(np.asarray(points.fields["source"]) == Source.MVS)
    point_rows = np.array([row_of[row.tobytes()] for row in mvs_points.positions])
    alpha = 1 / (1 + np.exp(-converted.logit_opacities[point_rows].astype(np.float64)))
    np.testing.assert_allclose(mvs_points.fields["opacity"], alpha, rtol=1e-6)  # the survey points: converted
    products = json.loads(layout.metrics_json.read_text())["products"]
    refined_psnr, unrefined_psnr = (products[n]["images"]["full"]["psnr"] for n in ("merged", "merged_unrefined"))
    assert refined_psnr != unrefined_psnr
    figures = [{k: v for k, v in products[n]["c2c"].items() if k != "files"} for n in ("merged", "merged_unrefined")]
    assert figures[0] == figures[1]
    record = json.loads(layout.manifest.read_text())["stages"]["appearance"]["counts"]
    assert record["gaussians"] == len(converted) - record["unrefined_needs_splats"]


def test_the_fill_and_background_are_refined_for_viewers_only(project):
    """splats/fill_refined.ply and background_refined.ply: splats/cleaned.ply and background.ply row for row,
    positions bit for bit, appearance refined; the viewer product takes them, the survey points keep the fill as
    trained, and the merged_unrefined control gives every layer back its attributes as trained."""
    from core.io import read_point_cloud
    from fusion.convert_options import Source
    from hybridsplat.project_io import unrefined_layers

    _, project = project
    layout = ProjectLayout(project)
    merged = read_gaussian_ply(layout.merged_ply)
    sources = np.asarray(merged.fields["source"])
    for base_path, refined_path, source in ((layout.cleaned_splats, layout.refined_fill_splats, Source.SPLAT),
                                            (layout.background_splats, layout.refined_background_splats,
                                             Source.BACKGROUND)):  # fmt: skip
        base, refined = read_gaussian_ply(base_path), read_gaussian_ply(refined_path)
        assert len(base) == len(refined) and np.array_equal(base.means, refined.means), refined_path
        assert np.array_equal(base.origin, refined.origin) and not np.array_equal(base.sh_dc, refined.sh_dc)
        rows = np.flatnonzero(sources == source)
        assert len(rows) > 0, source
        means = refined.with_origin(merged.origin).means
        # Rows are matched by position and colour together: two splats may share a position bit for bit (a clone
        # that moved with its parent), so a position alone does not name a row.
        _assert_rows_within((merged.means[rows], merged.sh_dc[rows]), (means, refined.sh_dc))  # viewer: refined
        unrefined = unrefined_layers(layout, merged)
        _assert_rows_within((merged.means[rows], unrefined.sh_dc[rows]), (means, base.sh_dc))  # control: as trained
    splats = read_gaussian_ply(layout.cleaned_splats).with_origin(merged.origin)
    points = read_point_cloud(layout.merged_points_ply)
    fill_points = points.subset(np.asarray(points.fields["source"]) == Source.SPLAT)
    alpha = 1 / (1 + np.exp(-splats.logit_opacities.astype(np.float64)))
    rows_at: dict[bytes, list[int]] = {}
    for i, m in enumerate(splats.means):
        rows_at.setdefault(m.tobytes(), []).append(i)
    for position, opacity in zip(fill_points.with_origin(merged.origin).positions, fill_points.fields["opacity"],
                                 strict=True):  # fmt: skip
        candidates = alpha[rows_at[position.tobytes()]]
        assert np.isclose(candidates, opacity, rtol=1e-6, atol=0).any()  # the survey points: as trained


def _assert_rows_within(part: tuple[np.ndarray, ...], whole: tuple[np.ndarray, ...]) -> None:
    """Every row of the columns ``part`` (arrays of M rows) occurs bit for bit among the rows of ``whole`` (N rows),
    each row of ``whole`` used at most once."""
    from collections import Counter

    def keys(columns: tuple[np.ndarray, ...]) -> list[bytes]:
        return [b"".join(np.ascontiguousarray(c[i]).tobytes() for c in columns) for i in range(len(columns[0]))]

    left = Counter(keys(whole))
    for key in keys(part):
        assert left[key] > 0, "a row of the product is not a row of its layer"
        left[key] -= 1


def test_the_merge_takes_the_layers_as_trained_without_their_refined_copies(project, tmp_path):
    from fusion.convert_options import Source

    _, project = project
    copy = tmp_path / "project"
    shutil.copytree(project, copy)
    layout = ProjectLayout(copy)
    layout.refined_fill_splats.unlink()
    layout.refined_background_splats.unlink()
    merge = [s for s in STAGES if s.name == "merge"]
    run_pipeline(copy, load_config(copy), stages=merge, force=["merge"])
    merged = read_gaussian_ply(layout.merged_ply)
    sources = np.asarray(merged.fields["source"])
    background = read_gaussian_ply(layout.background_splats)
    counts = json.loads(layout.manifest.read_text())["stages"]["merge"]["counts"]
    assert counts["background"] == int((sources == Source.BACKGROUND).sum()) > 0
    assert not counts["background_refined"] and not counts["fill_refined"]
    rows = np.flatnonzero(sources == Source.BACKGROUND)
    known = {m.tobytes(): i for i, m in enumerate(background.with_origin(merged.origin).means)}
    match = [known[m.tobytes()] for m in merged.means[rows]]
    np.testing.assert_array_equal(merged.sh_dc[rows], background.sh_dc[match])  # the background as trained


def test_layers_are_chosen_on_export_render_and_view_and_named_in_the_sidecar(project, tmp_path, capsys):
    from fusion.convert_options import Source
    from hybridsplat.viewer.scene import load_project

    _, project = project
    layout = ProjectLayout(project)
    sidecar = json.loads(layout.merged_ply.with_name("merged.origin.json").read_text())
    assert sidecar["layers"] == {"survey": 1, "fill": 2, "background": 3}
    out = tmp_path / "survey_fill.ply"
    assert main_code(["export", str(layout.merged_ply), "--out", str(out), "--layers", "survey,fill",
                      "--extra-fields", "--min-opacity", "0"]) == 0  # fmt: skip
    kept = read_gaussian_ply(out)
    merged = read_gaussian_ply(layout.merged_ply)
    assert set(np.unique(kept.fields["source"]).astype(int)) == {Source.MVS, Source.SPLAT}
    assert len(kept) == int((merged.fields["source"] != Source.BACKGROUND).sum())
    renders = tmp_path / "renders"
    args = ["render", str(layout.merged_ply), "--cameras", str(layout.dense_workspace.sparse), "--out", str(renders)]
    assert main_code([*args, "--layers", "background"]) == 0
    assert main_code([*args[:-1], str(tmp_path / "all")]) == 0
    assert len(list(renders.glob("*.png"))) == len(list((tmp_path / "all").glob("*.png"))) > 0
    only = load_project(project, layers=(Source.BACKGROUND,))
    assert only.splats.total == int((merged.fields["source"] == Source.BACKGROUND).sum())
    assert main_code(["export", str(layout.merged_ply), "--out", str(out), "--layers", "sky"]) == 2
    assert "--layers takes a comma-separated list of survey, fill, background, got 'sky'" in capsys.readouterr().err


def main_code(argv: list[str]) -> int:
    from hybridsplat.cli import run_cli

    return run_cli(argv)


def test_baseline_checkpoints_are_measured_as_products(project):
    _, project = project
    layout = ProjectLayout(project)
    record = json.loads(layout.manifest.read_text())["stages"]["baseline"]
    assert sorted(p.name for p in layout.baseline_checkpoints_dir.iterdir()) == ["baseline_000020.ply"]
    seconds = record["counts"]["checkpoints"]
    assert list(seconds) == ["20"] and 0 < seconds["20"] < record["seconds"]
    checkpoint = read_gaussian_ply(layout.baseline_checkpoints_dir / "baseline_000020.ply")
    final = read_gaussian_ply(layout.baseline_splats)
    assert len(checkpoint) > 0 and not (len(checkpoint) == len(final) and np.allclose(checkpoint.means, final.means)), (
        "the step-20 checkpoint is the final state"
    )
    metrics = json.loads(layout.metrics_json.read_text())["products"]
    product = metrics["baseline_20"]
    assert not product.get("skipped") and product["c2c"]["count"] == len(checkpoint)
    assert np.isfinite(product["images"]["full"]["psnr"]) and np.isfinite(product["images"]["masked"]["psnr"])


def test_baseline_checkpoints_must_lie_inside_the_run():
    for bad in ((0,), (100,), (50, 150)):
        with pytest.raises(ConfigError, match="checkpoints"):
            options_with(WholeSceneOptions, {"training.iterations": 100, "checkpoints": list(bad)})
    ok = options_with(WholeSceneOptions, {"training.iterations": 100, "checkpoints": [1, 99]})
    assert ok.checkpoints == (1, 99)


def test_a_baseline_without_checkpoints_is_up_to_date_on_the_next_run(project, tmp_path):
    scene, project = project
    copy = tmp_path / "project"
    shutil.copytree(project, copy)
    stages = {**FAST_STAGES, "baseline": options_with(WholeSceneOptions, {"enabled": True, "training.iterations": 40})}
    config = ProjectConfig(input=InputOptions(path=str(scene)), stages=stages)
    first = run_pipeline(copy, config).stages
    assert not first["baseline"].cached and not first["eval"].cached  # the checkpoint option changed
    assert not any(ProjectLayout(copy).baseline_checkpoints_dir.iterdir())
    assert "baseline_20" not in json.loads(ProjectLayout(copy).metrics_json.read_text())["products"]
    second = run_pipeline(copy, config).stages
    assert all(r.cached or r.skipped for r in second.values()), [n for n, r in second.items() if not r.cached]


def test_rerun_skips_every_stage_and_a_stage_command_reruns_only_what_changed(project, capsys):
    scene, project = project
    manifest = run_pipeline(project, load_config(project))
    # every stage is up to date, except those the project does not need (control: no GCPs; tiles: off; mesh: no
    # budget), skipped again
    assert all(rec.cached or rec.skipped for rec in manifest.stages.values()), {
        n: r.reason for n, r in manifest.stages.items()
    }
    assert [n for n, r in manifest.stages.items() if r.skipped] == ["control", "tiles", "mesh"]

    assert main(["mvs", str(project)]) is None  # up to date: nothing runs
    layout = ProjectLayout(project)
    assert main(["eval", "project", str(project)]) is None  # the eval stage with the project's config: up to date
    assert json.loads(layout.manifest.read_text())["stages"]["eval"]["cached"]
    main(["eval", "project", str(project), "--force"])  # measured again (from the eval cache), then the report
    stages = json.loads(layout.manifest.read_text())["stages"]
    assert not stages["eval"]["cached"] and not stages["report"]["cached"]
    assert json.loads(layout.manifest.read_text())["stages"]["mvs"]["cached"]
    before = layout.fused_ply.read_bytes()
    main(["mvs", str(project), "--min-num-pixels", "2"])  # an option changed: mvs reruns, and says so
    stages = json.loads(layout.manifest.read_text())["stages"]
    assert not stages["mvs"]["cached"] and stages["mvs"]["config"]["options"]["fusion"]["min_num_pixels"] == 2
    assert load_config(project).options("mvs", stage_options_types()["mvs"]).fusion.min_num_pixels == 2
    assert len(layout.fused_ply.read_bytes()) >= len(before)  # a looser fusion keeps at least as many points
    manifest = run_pipeline(project, load_config(project))
    ran = [n for n, r in manifest.stages.items() if not r.cached and not r.skipped]
    assert "sfm" not in ran and "convert" in ran and "report" in ran


def test_a_new_evaluation_measures_only_the_products_that_changed(project, tmp_path):
    from dataclasses import replace

    from core.io.gaussian_ply import write_gaussian_ply
    from fusion.render.gsplat_backend import gsplat_available
    from hybridsplat.stages.evaluate import EvalStageOptions

    _, project = project
    copy = tmp_path / "project"
    shutil.copytree(project, copy)
    layout = ProjectLayout(copy)
    first = json.loads(layout.metrics_json.read_text())
    measured = sorted(n for n, p in first["products"].items() if not p["skipped"])
    assert {"mvs", "baseline", "baseline_20", "merged"} <= set(measured)

    from hybridsplat.project_io import stage_result
    from hybridsplat.stages.evaluate import EvalStage

    again = stage_result(run_pipeline(copy, load_config(copy), force=["eval"]), EvalStage)
    assert again.reused == len(measured)  # nothing changed: every measurement restored
    assert again.renderer == ("gsplat" if gsplat_available() else "cpu")  # the report names it
    assert json.loads(layout.metrics_json.read_text()) == first
    for name in measured:  # with the files they name
        for rel in first["products"][name]["c2c"]["files"].values():
            assert (layout.eval_dir / rel).is_file(), rel

    merged = read_gaussian_ply(layout.merged_ply)  # a changed product: the merged set loses half its Gaussians
    write_gaussian_ply(layout.merged_ply, merged.subset(np.arange(len(merged) // 2)), extra_fields=True)
    manifest = run_pipeline(copy, load_config(copy))
    changed = stage_result(manifest, EvalStage)
    assert not manifest.stages["eval"].cached and changed.reused == len(measured) - 4  # merged and its 3 controls
    images = json.loads(layout.metrics_json.read_text())["products"]["merged"]["images"]["full"]
    assert images["psnr"] != first["products"]["merged"]["images"]["full"]["psnr"]
    line = EvalStage().summary(changed)  # the headline the run prints: PSNR and, with weights, LPIPS
    assert f"merged PSNR {images['psnr']:.2f} dB" in line
    if images.get("lpips") is not None:
        assert f"LPIPS {images['lpips']:.3f}" in line

    config = load_config(copy)
    config = config.with_stage_options("eval", replace(config.options("eval", EvalStageOptions), cache=False))
    off = run_pipeline(copy, config).stages["eval"]
    assert not off.cached and "reused" not in off.counts and stage_result(layout, EvalStage).reused is None


def test_bad_input_leaves_no_project_behind(tmp_path, capsys):
    empty = tmp_path / "photos"
    empty.mkdir()
    out = tmp_path / "project"
    with pytest.raises(SystemExit) as exit_info:
        main(["run", str(empty), "--out", str(out)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("hybridsplat: error:")]
    assert len(errors) == 1 and "found no photos" in errors[0] and str(empty) in errors[0]
    assert "Traceback" not in err
    assert not out.exists()


@pytest.mark.slow
def test_full_sfm_runs_are_byte_identical(tmp_path):
    """Same inputs, options and seed: the same sparse model, fused cloud, merged product and metrics, byte for byte
    (measured on tiny: identical; recon.sfm fixes threads and seeds, fusion runs single-threaded)."""
    scene = generate_scene("tiny", tmp_path / "scene", seed=0)
    config = ProjectConfig(input=InputOptions(path=str(scene), use_scene_cameras=False), stages=FAST_STAGES)
    layouts = [ProjectLayout(tmp_path / f"p{i}") for i in (1, 2)]
    for layout in layouts:
        run_pipeline(layout.root, config)
    a, b = layouts
    for name in ("cameras.bin", "images.bin", "points3D.bin"):
        assert (a.sparse / name).read_bytes() == (b.sparse / name).read_bytes(), name
    for path_a, path_b in ((a.fused_ply, b.fused_ply), (a.merged_ply, b.merged_ply), (a.metrics_json, b.metrics_json)):
        assert path_a.read_bytes() == path_b.read_bytes(), path_a.name


def test_photo_folder_with_a_georeferenced_reference_in_millimetres(tmp_path, capsys):
    """Photos only (images/ one level down) + camera centres in mm at UTM-like coordinates: the model is aligned in
    metres around a local origin, the sidecars carry that origin and the CRS, and the report prints millimetres."""
    from core.io.origin import read_origin
    from core.io.ply import read_ply, write_ply
    from core.pointcloud import PointCloud
    from recon.model import from_reconstruction, read_reconstruction

    scene = generate_scene("tiny", tmp_path / "scene", seed=0)
    photos = tmp_path / "survey"
    (photos / "images").mkdir(parents=True)
    for image in (scene / "images").iterdir():
        (photos / "images" / image.name).write_bytes(image.read_bytes())
    offset = np.array([512_345.0, 5_412_345.0, 250.0])
    truth = {v.name: v.center for v in from_reconstruction(read_reconstruction(scene / "sparse" / "0"))}
    reference = tmp_path / "centres_mm.txt"
    lines = [f"{n} {' '.join(f'{v:.3f}' for v in (c + offset) * 1000)}\n" for n, c in truth.items()]
    reference.write_text("".join(lines))
    lidar = read_ply(scene / "gt" / "lidar.ply")
    write_ply(tmp_path / "lidar_utm.ply", PointCloud(lidar.positions, origin=offset))  # world = offset + local
    project = tmp_path / "project"
    main(["run", str(photos), "--out", str(project), "--reference", str(reference), "--units", "mm",
          "--crs", "EPSG:32632", "--holdout", "0", "--lidar", str(tmp_path / "lidar_utm.ply"),
          "--train-iterations", "20", "--viewer-format", "spz", "--viewer-format", "3dtiles", "--quiet"])  # fmt: skip
    layout = ProjectLayout(project)
    origin = read_origin(layout.merged_ply)
    assert np.all(np.abs(origin - offset) < 5.0)  # a rounded local origin near the block
    sidecar = json.loads(layout.merged_ply.with_suffix(".origin.json").read_text())
    assert sidecar["crs"] == "EPSG:32632"
    import laspy

    las_crs = laspy.read(layout.merged_points_las).header.parse_crs()
    assert las_crs is not None and las_crs.to_epsg() == 32632  # the LAS carries the CRS as WKT
    fused = read_ply(layout.fused_ply)
    distances, _ = cKDTree(lidar.positions).query(fused.world_positions - offset)
    # Self-calibrated SfM of tiny's single 96x72 ring leaves ~8 cm of structure error (measured: median 0.084 m
    # with or without the georeference); float32 world coordinates would add 0.25 m, a lost origin kilometres.
    assert np.median(distances) < 0.12
    c2c = json.loads(layout.metrics_json.read_text())["products"]["mvs"]["c2c"]
    assert c2c["median"] == pytest.approx(np.median(distances), rel=1e-3)  # the eval stage saw the same geometry
    report = (layout.report_dir / "report.md").read_text()
    assert "(mm)" in report and f"{c2c['mean'] * 1000:.3g}" in report  # lengths printed in the user's unit
    _survey_layer_recovered_through_spz_and_3d_tiles(layout, "EPSG:32632")


def _survey_layer_recovered_through_spz_and_3d_tiles(layout: ProjectLayout, crs: str) -> None:
    """The survey layer's world positions (merged.ply: float64 origin + local) come back within 1 mm through
    export/merged.spz (+ its origin sidecar) and through the tileset (tile transforms · the 3D Tiles y-up → z-up turn
    · node matrix · POSITION, ECEF back to ``crs`` with pyproj); each decoded survey splat matched to its nearest."""
    import pyproj

    from core.io.origin import read_origin
    from fusion.gltf_splats import read_splat_glb
    from fusion.spz_format import read_spz

    merged = read_gaussian_ply(layout.merged_ply)
    survey = merged.origin + merged.means[np.asarray(merged.fields["source"]) == 1]
    spz_path = layout.merged_viewer("spz")
    spz_world = read_origin(spz_path) + read_spz(spz_path).to_gaussians().means
    spz_error = cKDTree(spz_world).query(survey)[0].max()
    y_up_to_z_up = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])  # 3D Tiles 1.1 spec
    tileset_path = layout.merged_viewer("3dtiles")
    ecef = []

    def walk(tile: dict, parent: np.ndarray) -> None:
        t = parent @ np.asarray(tile.get("transform", np.eye(4).reshape(-1)), float).reshape(4, 4).T
        uri = tile.get("content", {}).get("uri", "")
        if uri.startswith("survey/") and uri.endswith(".glb"):
            prim = read_splat_glb(tileset_path.parent / uri)
            chain = t @ y_up_to_z_up @ prim.node_matrix
            ecef.append((np.c_[prim.positions.astype(np.float64), np.ones(len(prim.positions))] @ chain.T)[:, :3])
        for child in tile.get("children", []):
            walk(child, t)

    walk(json.loads(tileset_path.read_text())["root"], np.eye(4))
    x, y, z = pyproj.Transformer.from_crs("EPSG:4978", crs, always_xy=True).transform(*np.concatenate(ecef).T)
    tiles_error = cKDTree(np.c_[x, y, z]).query(survey)[0].max()
    print(f"survey layer ({len(survey)} splats) recovered: SPZ {spz_error * 1e6:.2f} µm, "
          f"3D Tiles {tiles_error * 1e6:.2f} µm")  # fmt: skip
    assert spz_error < 1e-3 and tiles_error < 1e-3


def test_the_merge_stage_writes_the_viewer_product_in_other_formats(project, tmp_path, capsys):
    """The merge stage again on a copy of the project with ``viewer_formats`` (what ``run --viewer-format`` sets):
    the same Gaussians as merged.ply (those a viewer sees: opacity ≥ 1/255), its origin beside each file."""
    import shutil

    from core.io.origin import read_origin
    from fusion.sog_format import read_sog
    from fusion.spz_format import read_spz

    scene, original = project
    copy = tmp_path / "p"
    shutil.copytree(original, copy)
    layout = ProjectLayout(copy)
    from hybridsplat.commands.common import run_project_stage

    run_project_stage(copy, "merge", {"viewer_formats": ["spz", "sog", "3dtiles"]}, quiet=True)
    merged = read_gaussian_ply(layout.merged_ply)
    visible = int((merged.logit_opacities >= np.log(1 / 254)).sum())  # α ≥ 1/255
    assert len(read_spz(layout.merged_viewer("spz"))) == len(read_sog(layout.merged_viewer("sog")).positions) == visible
    for fmt in ("spz", "sog", "3dtiles"):
        np.testing.assert_array_equal(read_origin(layout.merged_viewer(fmt)), read_origin(layout.merged_ply))
    assert json.loads(layout.merged_viewer("3dtiles").read_text())["asset"]["version"] == "1.1"
    assert 'viewer_formats = ["spz", "sog", "3dtiles"]' in (copy / "config.toml").read_text()
    assert main_code(["run", str(scene), "--out", str(tmp_path / "q"), "--viewer-format", "jpeg"]) == 2
    allowed = "a list of values, each one of spz, sog, compressed-ply, splat, 3dtiles"
    assert f"option viewer_formats must be {allowed}, got ['jpeg']" in capsys.readouterr().err


def test_eval_with_a_memory_limit_gives_the_in_memory_figures(project, tmp_path, monkeypatch):
    """``run --memory-limit`` on the eval stage: the reference read in chunks and compared cell by cell (several cells
    forced by a small plan) gives every product's C2C figures and per-material scores of the in-memory run and the
    same distance clouds; the reverse mean / std / rmse within rel 1e-12 (sums by chunks, tests/test_eval_stream.py)."""
    from dataclasses import replace

    import eval.c2c_stream as c2c_stream
    import eval.geometry_stream as geometry_stream
    from hybridsplat.stages.evaluate import EvalStage, EvalStageOptions

    _, project = project
    copy = tmp_path / "project"
    shutil.copytree(project, copy)
    layout = ProjectLayout(copy)
    memory, tables = json.loads(layout.metrics_json.read_text()), json.loads(layout.per_material_json.read_text())
    clouds = {p.name: p.read_bytes() for p in layout.eval_dir.glob("c2c_*.*")}
    monkeypatch.setattr(c2c_stream, "plan_c2c_memory", lambda limit: c2c_stream.C2CPlan(limit, 2_000, 3_001))
    cells = []

    def exact_nearest(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        near = c2c_stream.exact_nearest(*args, **kwargs)
        cells.append(near.grid.nx * near.grid.ny)
        return near

    monkeypatch.setattr(geometry_stream, "exact_nearest", exact_nearest)
    config = load_config(copy)
    options = replace(config.options("eval", EvalStageOptions), cache=False, memory_limit_mb=1024.0)
    from hybridsplat.project_io import stage_result

    manifest = run_pipeline(copy, config.with_stage_options("eval", options), force=["eval"])
    result = stage_result(manifest, EvalStage)
    assert result.memory_limit_mb == 1024.0 and result.peak_rss_mb > 0
    assert "C2C streamed within 1024 MiB" in EvalStage().summary(result)
    assert max(cells) >= 4  # several cells, and the points beyond the halo searched in the whole cloud
    assert "Evaluation with bounded memory" in (layout.report_dir / "report.md").read_text()
    streamed = json.loads(layout.metrics_json.read_text())
    measured = [n for n, p in memory["products"].items() if p.get("c2c")]
    assert {"mvs", "merged", "splats"} <= set(measured)
    for name in measured:
        got, want = streamed["products"][name]["c2c"], memory["products"][name]["c2c"]
        for key, value in want.items():
            if key == "reverse" and value is not None:
                for k, v in value.items():
                    assert got[key][k] == (pytest.approx(v, rel=1e-12) if k in ("mean", "std", "rmse") else v), k
            else:
                assert got[key] == value, (name, key)
    geometry = ("accuracy_mean_m", "accuracy_points", "completeness", "reference_points")
    streamed_tables = json.loads(layout.per_material_json.read_text())
    for name, rows in tables["products"].items():
        for material, row in rows.items():
            got = streamed_tables["products"][name][material]
            want = {k: row[k] for k in row if k in geometry}
            assert {k: got[k] for k in want} == want, (name, material)
    assert {p.name: p.read_bytes() for p in layout.eval_dir.glob("c2c_*.*")} == clouds
    assert not list(layout.eval_dir.glob("hybridsplat_*"))  # the work files are gone
