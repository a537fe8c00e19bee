"""A tiled run (``run --tiles 2x1``) on a small aerial block (24 photos of 256 × 192): tiles as projects of their
own, products stitched by core ownership (no duplicate, nothing lost, rows byte for byte), the parent's later stages
on the stitched products, its disk estimate, a second run up to date, an interrupted tile resumed alone, and the
same tiles as tasks on a 2-worker local Ray instance."""

import json

import numpy as np
import pytest

from core.io.colmap_vis import read_vis
from core.io.ply import load_ply_data
from data_synth import generate_scene
from fusion.appearance import AppearanceOptions
from fusion.train.masked import MaskedTrainingOptions
from hybridsplat.config import InputOptions, ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.manifest import Manifest
from hybridsplat.options import options_with
from hybridsplat.pipeline import run_pipeline
from hybridsplat.project_io import stage_result
from hybridsplat.stages import stage_named
from hybridsplat.stages.tiles import TilesOptions
from hybridsplat.tile_projects import PER_TILE_IN_PARENT, TILE_STAGES
from recon.mvs import MvsOptions
from recon.tiling import read_tile_plan

pytestmark = pytest.mark.slow  # about 2 min on 2 cores: MVS and training of two tiles, twice (here and on Ray)

FAST = {
    "mvs": options_with(MvsOptions, {"max_image_size": 160}),
    "train": options_with(MaskedTrainingOptions, {"training.iterations": 30, "snapshot_iterations": [20]}),
    "appearance": options_with(AppearanceOptions, {"enabled": False}),
}


def _config(scene, **tiles) -> ProjectConfig:
    stages = {**FAST, "tiles": TilesOptions(grid="2x1", **tiles)}
    return ProjectConfig(input=InputOptions(path=str(scene)), stages=stages)


@pytest.fixture(scope="module")
def tiled(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiled")
    # the aerial layout at a test's size: its sparse points span the block, so a 2 x 1 grid cuts the fused cloud
    scene = generate_scene("aerial", root / "scene", seed=0, views=24, width=256, height=192, supersample=1,
                           test_views=2)  # fmt: skip
    project = root / "project"
    run_pipeline(project, _config(scene))
    return scene, project


def _rows(path):
    return load_ply_data(path)["vertex"].data


def test_tiles_run_as_projects_and_the_parent_skips_what_they_made(tiled):
    _, project = tiled
    layout = ProjectLayout(project)
    stages = Manifest(layout.manifest).stages
    assert not stages["tiles"].skipped and stage_result(layout, stage_named("tiles")).tiles == 2
    for name in PER_TILE_IN_PARENT:
        assert stages[name].skipped and "made per tile" in stages[name].reason, name
    for name in ("masks", "convert", "merge", "eval", "report"):
        assert not stages[name].skipped, name
    plan = read_tile_plan(layout.tile_plan)
    assert [t.name for t in plan.tiles] == ["r0c0", "r0c1"]
    for tile in plan.tiles:
        sub = Manifest(ProjectLayout(layout.tile_project(tile.name)).manifest).stages
        assert list(sub) == list(TILE_STAGES)
        assert not sub["mvs"].skipped and not sub["classify"].skipped


def test_the_second_phase_trains_with_its_neighbours_splats_frozen_in_the_overlap(tiled):
    from core.io.gaussian_ply import read_gaussian_ply

    _, project = tiled
    layout = ProjectLayout(project)
    plan = read_tile_plan(layout.tile_plan)
    first, second = (ProjectLayout(layout.tile_project(n)) for n in ("r0c0", "r0c1"))  # (row + column) even, odd
    assert not first.neighbour_splats.exists()
    splats = read_gaussian_ply(first.cleaned_splats)
    # what the stitch keeps of r0c0 and what lies in r0c1's overlap, in r0c0's order
    keep = (plan.owner(splats.means) == 0) & plan.in_bounds(splats.means, 1)
    given = read_gaussian_ply(second.neighbour_splats)
    assert 0 < len(given) == int(keep.sum()) < len(splats)
    np.testing.assert_array_equal(given.means, splats.means[keep])
    np.testing.assert_array_equal(given.logit_opacities, splats.logit_opacities[keep])
    assert stage_result(second, stage_named("train")).neighbour_context == len(given)
    assert stage_result(first, stage_named("train")).neighbour_context == 0


def test_stitched_clouds_keep_each_point_once_from_the_tile_that_owns_it(tiled):
    _, project = tiled
    layout = ProjectLayout(project)
    plan = read_tile_plan(layout.tile_plan)
    import pycolmap

    parent_ids = list(pycolmap.Reconstruction(str(layout.dense_workspace.sparse)).reg_image_ids())
    parent_names = {k: pycolmap.Reconstruction(str(layout.dense_workspace.sparse)).image(i).name
                    for k, i in enumerate(parent_ids)}  # fmt: skip
    for product in ("fused_ply", "classified_points", "cleaned_splats"):
        stitched = _rows(getattr(layout, product))
        expected, expected_vis, parts = [], [], []
        for tile in plan.tiles:
            sub = ProjectLayout(layout.tile_project(tile.name))
            rows = _rows(getattr(sub, product))
            pos = np.stack([rows["x"], rows["y"], rows["z"]], axis=1).astype(np.float64)
            own = plan.owner(pos) == tile.index
            assert 0 < own.sum() <= len(rows), (product, tile.name)
            if product == "fused_ply":  # each tile reconstructs into its overlap and gives those points up
                assert own.sum() < len(rows), tile.name
            expected.append(rows[own])
            parts.append(rows[own])
            if product == "fused_ply":
                rec = pycolmap.Reconstruction(str(sub.dense_workspace.sparse))
                names = [rec.image(i).name for i in rec.reg_image_ids()]
                vis = read_vis(sub.fused_vis, len(rows))
                expected_vis += [sorted(names[j] for j in v) for v, keep in zip(vis, own, strict=True) if keep]
        expected = np.concatenate(expected)
        assert stitched.tobytes() == expected.tobytes(), product  # byte for byte, tile by tile
        xyz = np.stack([stitched["x"], stitched["y"], stitched["z"]], axis=1)
        per_tile = sum(len(np.unique(np.stack([e["x"], e["y"], e["z"]], axis=1), axis=0)) for e in parts)
        assert len(np.unique(xyz, axis=0)) == per_tile, product  # no position from two tiles
        if product == "fused_ply":
            assert per_tile == len(xyz)  # and no fused point twice (training may clone a splat in place)
        if product == "fused_ply":
            vis = read_vis(layout.fused_vis, len(stitched))
            assert [sorted(parent_names[j] for j in v) for v in vis] == expected_vis


def test_the_disk_estimate_bounds_the_tiles_and_the_stitched_products(tiled):
    from hybridsplat.disk_space import tree_bytes

    _, project = tiled
    layout = ProjectLayout(project)
    record = Manifest(layout.manifest).stages["tiles"]
    written = record.bytes_written + tree_bytes([layout.tiles_dir])
    assert 0 < written <= record.bytes_expected <= 20 * written + 4 * 2**20


def test_the_parent_products_come_from_the_stitched_cloud(tiled):
    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.convert_options import Source

    _, project = tiled
    layout = ProjectLayout(project)
    fused = _rows(layout.fused_ply)
    mvs = read_gaussian_ply(layout.mvs_gaussians)
    assert len(mvs) == len(fused)  # the parent's conversion ran on the stitched cloud
    merged = read_gaussian_ply(layout.merged_ply)
    source = np.asarray(merged.fields["source"])
    assert int((source == Source.SPLAT).sum()) > 0 and int((source == Source.MVS).sum()) > 0
    metrics = json.loads(layout.metrics_json.read_text())["products"]
    assert np.isfinite(metrics["merged"]["images"]["full"]["psnr"])
    record = json.loads(layout.record("tiles").read_text())
    assert record["prediction"]["wall_s"] > 0 and record["prediction"]["measured_wall_s"] > 0
    assert "Tiles" in (layout.report_dir / "report.md").read_text()


def test_a_second_run_is_up_to_date_and_an_interrupted_tile_resumes_alone(tiled):
    scene, project = tiled
    layout = ProjectLayout(project)
    again = run_pipeline(project, _config(scene))
    assert all(r.cached or r.skipped for r in again.stages.values())
    # an interrupted run: the parent's tiles stage unfinished, tile r0c1 stopped before training
    Manifest(layout.manifest).invalidate("tiles")
    sub = Manifest(ProjectLayout(layout.tile_project("r0c1")).manifest)
    sub.invalidate("train")
    sub.invalidate("clean")
    before = _rows(layout.fused_ply).tobytes()
    run_pipeline(project, _config(scene))
    per_tile = {t["tile"]: t["stages"] for t in json.loads(layout.record("tiles").read_text())["per_tile"]}
    assert all(s["cached"] or s["skipped"] for s in per_tile["r0c0"].values())
    assert [n for n, s in per_tile["r0c1"].items() if not (s["cached"] or s["skipped"])] == ["train", "clean"]
    assert _rows(layout.fused_ply).tobytes() == before


def test_tiles_on_a_two_worker_ray_instance_make_the_same_clouds(tiled, tmp_path):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'hybridsplat[distributed]')")
    scene, sequential = tiled
    project = tmp_path / "ray"
    config = _config(scene, workers=2)
    manifest = run_pipeline(project, config, stages=[stage_named("sfm"), stage_named("tiles")])
    assert stage_result(manifest, stage_named("tiles")).workers == 2
    for tile in json.loads(ProjectLayout(project).record("tiles").read_text())["per_tile"]:
        # each task declared one CPU and its predicted peak memory (the cost model's, well above a megabyte)
        assert tile["resources"]["CPU"] == 1 and tile["resources"]["memory"] > 100 * 2**20, tile["tile"]
    for product in ("fused_ply", "classified_points"):
        ours = _rows(getattr(ProjectLayout(project), product)).tobytes()
        assert ours == _rows(getattr(ProjectLayout(sequential), product)).tobytes(), product
    assert ProjectLayout(project).cleaned_splats.is_file()


def test_a_failing_tile_task_raises_its_own_error_naming_the_tile(tmp_path):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'hybridsplat[distributed]')")
    from core.errors import InputFileError
    from hybridsplat.tile_execution import ExecutionOptions, run_tiles
    from hybridsplat.tile_projects import TileJob

    bad = ProjectConfig(input=InputOptions(path=str(tmp_path / "no_such_photos")))
    jobs = [TileJob(name="r0c0", root=str(tmp_path / "r0c0"), config=bad)]
    with pytest.raises(InputFileError, match="no_such_photos") as err:
        run_tiles(jobs, ExecutionOptions(workers=2))
    assert "in tile r0c0 (a Ray task)" in err.value.__notes__


def test_the_appearance_stage_refines_each_gaussian_in_the_tile_whose_core_holds_it(tiled, tmp_path):
    import shutil

    from core.io.gaussian_ply import read_gaussian_ply
    from hybridsplat.project_io import needs_splats_per_gaussian

    scene, sequential = tiled
    project = tmp_path / "appearance"
    shutil.copytree(sequential, project)
    layout = ProjectLayout(project)
    fit = options_with(AppearanceOptions, {"training.iterations": 20, "training.min_iterations": 20})
    config = ProjectConfig(input=InputOptions(path=str(scene)),
                           stages={**FAST, "tiles": TilesOptions(grid="2x1"), "appearance": fit})  # fmt: skip
    fitted = stage_result(run_pipeline(project, config, stages=[stage_named("appearance")]), stage_named("appearance"))
    assert fitted.tiles == 2 and fitted.survey_unrefined == 0 and fitted.fill_unrefined == 0
    assert not any(r.cached for r in fitted.per_tile)
    plan = read_tile_plan(layout.tile_plan)
    mvs, survey = read_gaussian_ply(layout.mvs_gaussians), read_gaussian_ply(layout.survey_splats)
    np.testing.assert_array_equal(survey.means, mvs.means)
    rows = np.flatnonzero(~needs_splats_per_gaussian(layout, mvs))
    assert not np.allclose(survey.sh_dc[rows], mvs.sh_dc[rows])  # refined
    fill, fill_refined = read_gaussian_ply(layout.cleaned_splats), read_gaussian_ply(layout.refined_fill_splats)
    for t, tile in enumerate(plan.tiles):  # every row is its core's tile's, independent of the stitch's code
        files = ProjectLayout(layout.tile_project(tile.name)).tile_appearance_files()
        for whole, rows_of, part in ((survey, rows, files.survey_refined),
                                     (fill_refined, np.arange(len(fill)), files.fill_refined)):  # fmt: skip
            given = rows_of[plan.in_bounds(whole.means[rows_of], t)]
            own = plan.owner(whole.means[given]) == t
            refined = read_gaussian_ply(part)
            assert own.any() and not own.all(), tile.name  # the tile saw its overlap too; the stitch kept its core
            np.testing.assert_array_equal(whole.sh_dc[given[own]], refined.sh_dc[own])
            np.testing.assert_array_equal(whole.logit_opacities[given[own]], refined.logit_opacities[own])
    background = read_gaussian_ply(layout.background_splats)
    kept = read_gaussian_ply(layout.refined_background_splats)
    np.testing.assert_array_equal(kept.sh_dc, background.sh_dc)  # not refined tile by tile
    # an interrupted stage: the tile whose record is gone is fitted again, the other one taken as it was
    before = layout.survey_splats.read_bytes()
    ProjectLayout(layout.tile_project("r0c1")).tile_appearance_files().record.unlink()
    Manifest(layout.manifest).invalidate("appearance")
    again = stage_result(run_pipeline(project, config, stages=[stage_named("appearance")]), stage_named("appearance"))
    assert {r.tile: r.cached for r in again.per_tile} == {"r0c0": True, "r0c1": False}
    assert layout.survey_splats.read_bytes() == before  # the fit is deterministic for its seed


def test_the_tiles_appearance_fits_as_ray_tasks_make_the_same_survey_layer(tiled, tmp_path):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'hybridsplat[distributed]')")
    import shutil

    scene, sequential = tiled
    layout = ProjectLayout(tmp_path / "appearance")
    shutil.copytree(sequential, layout.root)
    fit = options_with(AppearanceOptions, {"training.iterations": 10, "training.min_iterations": 10})
    products = []
    for workers in (1, 2):
        stages = {**FAST, "tiles": TilesOptions(grid="2x1", workers=workers), "appearance": fit}
        config = ProjectConfig(input=InputOptions(path=str(scene)), stages=stages)
        for tile in ("r0c0", "r0c1"):
            ProjectLayout(layout.tile_project(tile)).tile_appearance_files().record.unlink(missing_ok=True)
        manifest = run_pipeline(layout.root, config, stages=[stage_named("appearance")], force=["appearance"])
        per_tile = stage_result(manifest, stage_named("appearance")).per_tile
        assert sorted(r.tile for r in per_tile if not r.cached) == ["r0c0", "r0c1"]
        products.append((layout.survey_splats.read_bytes(), layout.refined_fill_splats.read_bytes()))
    assert products[0] == products[1]


def test_a_tile_that_fuses_no_point_adds_nothing_and_is_not_redone(tiled, tmp_path, monkeypatch):
    import shutil

    import hybridsplat.pipeline
    from core.errors import EmptyFusionError

    scene, sequential = tiled
    project = tmp_path / "copy"
    shutil.copytree(sequential, project)
    layout = ProjectLayout(project)
    real_run = hybridsplat.pipeline.run_pipeline
    calls = []

    def fusion_fails_in_r0c1(root, *args, **kwargs):  # as COLMAP's fusion does over water or a bare roof
        calls.append(str(root))
        if str(root).endswith("r0c1"):
            raise EmptyFusionError("fusion produced no points", root)
        return real_run(root, *args, **kwargs)

    monkeypatch.setattr(hybridsplat.pipeline, "run_pipeline", fusion_fails_in_r0c1)
    tiles_only = [stage_named("sfm"), stage_named("tiles")]
    result = stage_result(
        run_pipeline(project, _config(scene), stages=tiles_only, force=["tiles"]), stage_named("tiles")
    )
    assert result.without_points == ("r0c1",)
    assert "fused no point: r0c1" in stage_named("tiles").summary(result)
    plan = read_tile_plan(layout.tile_plan)
    r0c0 = _rows(ProjectLayout(layout.tile_project("r0c0")).fused_ply)
    own = plan.owner(np.stack([r0c0["x"], r0c0["y"], r0c0["z"]], axis=1).astype(np.float64)) == 0
    assert _rows(layout.fused_ply).tobytes() == r0c0[own].tobytes()  # only the other tile's core
    # a second run takes the tile's record while its model is unchanged: its MVS is not run again
    calls.clear()
    again = stage_result(
        run_pipeline(project, _config(scene), stages=tiles_only, force=["tiles"]), stage_named("tiles")
    )
    assert again.without_points == ("r0c1",) and not any(c.endswith("r0c1") for c in calls)
    # every tile empty: the run fails, naming the tiles' folder
    monkeypatch.setattr(hybridsplat.pipeline, "run_pipeline", lambda root, *a, **k: (_ for _ in ()).throw(
        EmptyFusionError("fusion produced no points", root)))  # fmt: skip
    (ProjectLayout(layout.tile_project("r0c1")).empty_tile_record).unlink()
    ProjectLayout(layout.tile_project("r0c0")).manifest.unlink()
    with pytest.raises(EmptyFusionError, match="no tile fused a point"):
        run_pipeline(project, _config(scene), stages=tiles_only, force=["tiles"])
