"""Typed stage results: every stage declares one, the manifest stores it as JSON and gives it back equal, a manifest
written before results were typed still reads (with the summaries and report lines that version printed), and
values of the wrong type are refused naming the file and the key."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from core.errors import FormatError
from hybridsplat.layout import ProjectLayout
from hybridsplat.manifest import Manifest, StageRecord
from hybridsplat.project_io import stage_result
from hybridsplat.records import TypedRecord
from hybridsplat.stages import registered_stages, stage_named
from hybridsplat.stages.base import StageResult

OLD_MANIFEST = Path(__file__).parent / "data" / "manifest_0_3_demo.json"
"""manifest.json of the tiny demo (``hybridsplat demo --preset tiny``, seed 0) written by hybridsplat 0.3.1 before
the stage results were typed (the inputs, configuration and outputs of each record left out, the classifier's path
shortened to its name)."""

REMOVED_FIELDS = {"train": {"prior_views", "prior_pixels", "lpips_weights", "refine.relocated"}}
"""Result fields (dotted: nested) of 0.3.1 that 0.4 removed with their options (docs/migration.md): read and
dropped."""


def _without(counts: dict, removed: set[str]) -> dict:
    """``counts`` without the dotted paths ``removed`` (copied where changed)."""
    out = dict(counts)
    for path in removed:
        head, _, rest = path.partition(".")
        if rest and isinstance(out.get(head), dict):
            out[head] = _without(out[head], {rest})
        elif not rest:
            out.pop(head, None)
    return out


OLD_SUMMARIES = {
    "sfm": "10/10 photos registered, 178 points, 0.26 px",
    "mvs": "cpu: 10 views at 96 px, 2.9 s/view, 2085 fused points",
    "classify": "2085 points, 17.7% need splats (default.skops)",
    "masks": "10 masks, mean coverage 48.0%, 0 empty",
    "convert": "2085 Gaussians, median spacing 0.0172 m",
    "train": "6138 splats after 600 steps, masked PSNR 21.62 dB",
    "clean": "4172 of 6138 splats kept",
    "background": "8275 Gaussians on a 4.52 m shell (7970 extrapolated to directions no photo shows), 1.9 % of the "
    "pixels, 300 steps",
    "appearance": "1715 survey Gaussians refined with 12447 fill and background Gaussians (positions frozen), 840 "
    "steps, SH 3, held-back PSNR 21.61 -> 23.32 dB",
    "merge": "14162 Gaussians in the merged product (survey 1715, fill 4172, background 8275), 2079 survey points "
    "(118 of 4172 splats trustworthy)",
    "mesh": "1997 triangles (poisson), ply, obj, glb",
    "baseline": "1110 splats after 1000 steps, PSNR 21.04 dB on held-back pixels",
    "eval": "mvs C2C mean 0.00731 m, mvs PSNR 10.73 dB LPIPS 0.366, baseline C2C mean 0.108 m, baseline PSNR 24.45 dB "
    "LPIPS 0.196, merged C2C mean 0.00798 m, merged PSNR 25.47 dB LPIPS 0.045",
    "report": "report.html 1.3 MB",
}
"""What hybridsplat 0.3.1 printed for each stage of that run (its terminal's summary lines)."""

OLD_REPORT_LINES = {
    "classify": "2,085 points, 17.7% need splats (collaborative 1,306, reflective 302, transparent 2, textureless "
    "475, thin 0); model default.skops.",
    "masks": "10 masks, mean coverage 48.0% of the photo, 0 empty (skipped by training).",
    "merge": "The merged product (export/merged.ply) holds 14,162 Gaussians in three layers (its `source` field): "
    "survey 1,715 (the MVS Gaussians, positions as converted, appearance refined), fill 4,172 (splats trained in the "
    "region masks), background 8,275 (what the photos see beyond the survey region; viewer product only). The survey "
    "points (merged_points.ply/.las) hold 2,079 points, no background.",
}
"""The stages' report lines hybridsplat 0.3.1 wrote for that run (report/report.md)."""


def _old_project(tmp_path: Path) -> ProjectLayout:
    layout = ProjectLayout(tmp_path / "project")
    layout.root.mkdir()
    shutil.copyfile(OLD_MANIFEST, layout.manifest)
    return layout


def test_every_stage_declares_a_frozen_result_whose_fields_all_have_defaults():
    for stage in registered_stages():
        result = stage.Result
        assert result is not StageResult and issubclass(result, StageResult), stage.name
        assert result.__dataclass_params__.frozen and result.__doc__, stage.name
        assert result.__module__ == type(stage).__module__, f"{stage.name}: declared beside its stage"
        empty = result()  # every field defaulted: a record missing a key still reads
        assert result.from_json(empty.as_dict()).as_dict() == empty.as_dict(), stage.name


def test_a_manifest_written_before_results_were_typed_reads_with_that_versions_summaries(tmp_path):
    layout = _old_project(tmp_path)
    manifest = Manifest(layout.manifest)
    assert stage_result(manifest, stage_named("tiles")) is None  # skipped: no result
    for name, line in OLD_SUMMARIES.items():
        stage = stage_named(name)
        result = stage_result(layout, stage)
        assert isinstance(result, stage.Result), name
        assert stage.summary(result) == line, name
        # nothing lost: its JSON is the record's counts as written (the eval stage's flat per-product keys too), but
        # for the fields removed since
        written = _without(manifest.stages[name].counts, REMOVED_FIELDS.get(name, set()))
        assert result.as_dict() == written, name
    for name, line in OLD_REPORT_LINES.items():
        section = stage_named(name).report_section(stage_result(layout, stage_named(name)))
        assert section is not None and section.lines[0] == line, name
    train = stage_result(layout, stage_named("train"))
    assert train.seeds.rays == 4000 and train.refine.split == 1609 and train.resolution == (96, 72)
    evaluated = stage_result(layout, stage_named("eval"))
    assert evaluated.products["merged_no_background"].psnr == pytest.approx(20.322005629233427)
    assert evaluated.renderer == "cpu" and evaluated.per_material == 6
    background = stage_result(layout, stage_named("background"))
    assert background.shell_scores["32"].pairs == 36


def test_status_reads_an_old_manifest_through_the_typed_results(tmp_path):
    from hybridsplat.project_status import StageStatus, _with_record

    layout = _old_project(tmp_path)
    manifest = Manifest(layout.manifest)
    for name, line in OLD_SUMMARIES.items():
        status = _with_record(StageStatus(name, "current"), manifest, stage_named(name))
        assert status.summary == line and status.result == stage_result(manifest, stage_named(name)), name


def _samples() -> list[StageResult]:
    """A populated result of every stage, nested records, NaN-free (see the NaN test), optional fields set."""
    from hybridsplat.stages.appearance import AppearanceResult, TileAppearanceRecord
    from hybridsplat.stages.background import BackgroundResult, ShellScore
    from hybridsplat.stages.baseline import BaselineResult
    from hybridsplat.stages.classify import ClassifyResult
    from hybridsplat.stages.evaluate import EvalResult, ProductHeadline
    from hybridsplat.stages.merge import MergeResult
    from hybridsplat.stages.mesh import MeshResult
    from hybridsplat.stages.sfm import SfmResult
    from hybridsplat.stages.tiles import SeamCheck, StitchedProducts, TilePrediction, TilesResult
    from hybridsplat.stages.train import TrainResult, TrainSeeds

    tile = TileAppearanceRecord("r0c1", 812.5, 100, 20, 6, 0.5, 30, None, 2.5, True, {"CPU": 1.0})
    return [
        SfmResult(images=3, registered=2, unregistered={"c.jpg": "no matches"}, points=9, reprojection_error_px=0.5,
                  mapper="incremental", matcher="exhaustive", alignment_rms_m=0.01, alignment_inliers=2),
        TilesResult(tiles=2, grid="2x1", photos_per_tile=(5, 6),
                    stitched=StitchedProducts(4, 100, (3, 4), 90, 50, 40, SeamCheck(1.1, 0.01, 7)),
                    prediction=TilePrediction(2, 10.0, 900.0, (4.0, 6.0), {"base_mb": 700.0, "source": "reference"},
                                              11.0, 950.0),
                    workers=2, where="2 Ray workers", without_points=("r0c1",)),
        ClassifyResult(points=10, needs_splats=2, model="none", per_class={"a": 8, "b": 2}, spacing_m=0.01,
                       seconds=1.5, figures=("classify/figures/classes.png",), memory_limit_mb=1024.0,
                       peak_rss_mb=600.0, cells=9, regrown=1),
        TrainResult(trained=5, downscale=2, cap=100, iterations=24, holdout_psnr_db=20.5, resolution=(48, 36),
                    seeds=TrainSeeds(1, 2, 3, 4), neighbour_context=3),
        BackgroundResult(share=0.1, gaussians=7, shell_scores={"8": ShellScore(0.1, 26)}, holdout_psnr_db=None),
        AppearanceResult(gaussians=100, iterations=30, sh_degree=3, context_refined=20, background_refined=False,
                         survey_unrefined=0, fill_unrefined=1, tiles=1, per_tile=(tile,), peak_mb_with_workers=900.0),
        MergeResult(merged=10, written=10, mvs=6, splats=3, background=1, points=8, survey_refined=True,
                    point_splats={"input": 3, "kept": 2}, point_needs_mvs_classes={"thin": 0},
                    fill_refined=True, memory_limit_mb=800.0, export_chunk_points=1000),
        MeshResult(triangles_raw=300, triangles=100, vertices=52, budget=100, within_budget_tolerance=True,
                   method="tsdf", formats=("ply",), warnings=("a warning",)),
        BaselineResult(splats=9, iterations=20, holdout_psnr_db=19.0, history=((10, 0.5, 18.0), (20, 1.0, 19.0)),
                       checkpoints={"10": 0.7}),
        EvalResult(lpips=True, views=2, renderer="cpu", reused=1,
                   products={"mvs": ProductHeadline(0.01, 10.5, 0.3), "splats": ProductHeadline(c2c_mean_m=0.04)}),
    ]  # fmt: skip


@pytest.mark.parametrize("result", _samples(), ids=lambda r: type(r).__name__)
def test_a_result_round_trips_through_the_manifest_file(tmp_path, result):
    name = next(s.name for s in registered_stages() if s.Result is type(result))
    manifest = Manifest(tmp_path / "manifest.json")
    manifest.record(StageRecord(name=name, counts=result.as_dict()))  # what the runner records
    text = json.loads((tmp_path / "manifest.json").read_text())["stages"][name]["counts"]
    assert text == result.as_dict()  # JSON data, nothing but
    again = stage_result(Manifest(tmp_path / "manifest.json"), stage_named(name))
    assert again == result and type(again) is type(result)


def test_the_json_keeps_the_manifests_form():
    from hybridsplat.stages.evaluate import EvalResult, ProductHeadline
    from hybridsplat.stages.sfm import SfmResult

    sfm = SfmResult(images=3, registered=3, points=9, matcher="exhaustive")
    # an optional field left out while unset, every other field by name
    assert list(sfm.as_dict()) == ["images", "registered", "unregistered", "points", "reprojection_error_px", "matcher"]
    evaluated = EvalResult(views=2, products={"merged_no_background": ProductHeadline(psnr=20.0, lpips=0.1)})
    assert evaluated.as_dict() == {"lpips": False, "views": 2, "merged_no_background_psnr": 20.0,
                                   "merged_no_background_lpips": 0.1}  # fmt: skip


def test_values_are_normalised_to_the_declared_types_and_wrong_ones_refused(tmp_path):
    from hybridsplat.stages.mvs import MvsResult
    from hybridsplat.stages.train import TrainResult

    result = MvsResult(views=np.int64(3), points=np.int32(7), seconds_per_view=np.float32(0.5), image_size=96)
    assert type(result.views) is int and type(result.seconds_per_view) is float and result.as_dict()["points"] == 7
    assert TrainResult(resolution=[48, 36]).resolution == (48, 36)  # a list as the declared tuple
    with pytest.raises(TypeError, match="views must be int, got float 2.5"):
        MvsResult(views=2.5)
    bad = {"version": "0.3.1", "stages": {"mvs": {"name": "mvs", "counts": {"points": "many"}}}}
    (tmp_path / "manifest.json").write_text(json.dumps(bad))
    with pytest.raises(FormatError, match=r"manifest.json: stages\.mvs\.counts\.points must be int, got str 'many'"):
        stage_result(Manifest(tmp_path / "manifest.json"), stage_named("mvs"))


def test_unknown_keys_are_ignored_missing_ones_defaulted_and_nan_comes_back_as_nan(tmp_path):
    from hybridsplat.stages.baseline import BaselineResult
    from hybridsplat.stages.mvs import MvsResult

    old = MvsResult.from_json({"points": 5, "from_a_later_version": [1, 2]})
    assert old == MvsResult(points=5) and old.backend == "" and old.views == 0
    nan = BaselineResult(holdout_psnr_db=float("nan"), iterations=3)
    manifest = Manifest(tmp_path / "manifest.json")
    manifest.record(StageRecord(name="baseline", counts=nan.as_dict()))
    assert '"holdout_psnr_db": null' in (tmp_path / "manifest.json").read_text()  # strict JSON
    again = stage_result(Manifest(tmp_path / "manifest.json"), stage_named("baseline"))
    assert math.isnan(again.holdout_psnr_db) and again.iterations == 3


def test_the_runner_records_the_result_and_refuses_a_dict(tmp_path):
    from hybridsplat.config import ProjectConfig
    from hybridsplat.runner import run_stages
    from hybridsplat.stages.base import Stage, StageContext
    from hybridsplat.terminal import Terminal

    @dataclasses.dataclass(frozen=True)
    class Written(StageResult):
        """bytes: what the stage wrote."""

        bytes: int = 0

    class Writes(Stage):
        name = "writes"
        Result = Written

        def __init__(self, returns_dict: bool) -> None:
            self.returns_dict = returns_dict

        def outputs(self, ctx):
            return [ctx.layout.root / "out.txt"]

        def run(self, ctx):
            (ctx.layout.root / "out.txt").write_text("abc")
            return {"bytes": 3} if self.returns_dict else Written(3)

    ctx = StageContext(layout=ProjectLayout(tmp_path), config=ProjectConfig(), source=None)  # type: ignore[arg-type]
    manifest = run_stages(ctx, [Writes(False)], Terminal(quiet=True))
    assert manifest.stages["writes"].counts == {"bytes": 3} and stage_result(manifest, Writes(False)) == Written(3)
    with pytest.raises(TypeError, match="stage 'writes' returned a dict, not its Written"):
        run_stages(ctx, [Writes(True)], Terminal(quiet=True), force=["writes"])
    assert not (tmp_path / "out.txt").exists() and "writes" not in Manifest(tmp_path / "manifest.json").stages


def test_nested_records_are_typed_records_too():
    from hybridsplat.stages.train import TrainResult

    seeds = TrainResult.from_json({"seeds": {"mvs": 4}}).seeds
    assert isinstance(seeds, TypedRecord) and seeds.mvs == 4 and seeds.rays == 0
