"""The whole pipeline on the tiny synthetic scene: every stage recorded, products written, re-run cached."""

import json

import numpy as np
import pytest

from core.io.gaussian_ply import read_gaussian_ply
from data_synth import generate_scene
from hybridsplat.pipeline import PipelineConfig, run_pipeline


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    root = tmp_path_factory.mktemp("pipeline")
    scene = generate_scene("tiny", root / "scene", seed=0)
    project = root / "project"
    run_pipeline(scene, project, PipelineConfig(convert_mode="adaptive"))
    return scene, project


def test_every_stage_is_recorded_with_outputs(project):
    scene, project = project
    manifest = json.loads((project / "manifest.json").read_text())
    stages = manifest["stages"]
    assert list(stages) == ["sfm", "mvs", "classify", "convert", "train", "merge", "eval", "report"]
    for name in ("sfm", "mvs", "convert", "merge", "eval", "report"):
        assert not stages[name]["skipped"] and stages[name]["seconds"] > 0, name
    assert stages["classify"]["skipped"] and stages["classify"]["reason"]
    assert stages["train"]["skipped"] and stages["train"]["reason"]
    for rel in (
        "config.toml",
        "sparse/cameras.bin",
        "dense/fused.ply",
        "dense/fused.ply.vis",
        "export/mvs_gaussians.ply",
        "export/merged.ply",
        "export/merged_points.ply",
        "export/merged_points.las",
        "eval/metrics.json",
        "report/report.html",
        "report/report.md",
        "report/report.json",
    ):
        assert (project / rel).is_file(), rel
    merged = read_gaussian_ply(project / "export" / "merged.ply")
    assert len(merged) == stages["merge"]["counts"]["merged"] > 100


def test_report_schema_and_mvs_accuracy(project):
    scene, project = project
    report = json.loads((project / "report" / "report.json").read_text())
    gsd = json.loads((scene / "scene.json").read_text())["gsd_m"]
    mvs = report["products"]["mvs"]
    for key in ("count", "mean", "std", "median", "rmse", "p95", "max", "completeness", "fscore"):
        assert mvs["c2c"][key] is not None, key
    # tiny is 96x72 px: MVS is coarse but must sit on the true surfaces within a few GSD
    assert mvs["c2c"]["median"] < 3 * gsd
    for part in ("full", "masked"):
        scores = mvs["images"][part]
        assert all(np.isfinite(scores[k]) for k in ("mse", "psnr", "ssim", "ms_ssim", "delta_e")), part
    assert report["products"]["splats"]["skipped"]
    assert report["stages"]["train"]["skipped"] and report["stages"]["mvs"]["seconds"] > 0


def test_rerun_is_cached(project):
    scene, project = project
    manifest = run_pipeline(scene, project, PipelineConfig(convert_mode="adaptive"))
    for name in ("sfm", "mvs", "convert", "merge"):
        assert manifest.stages[name].cached, name
