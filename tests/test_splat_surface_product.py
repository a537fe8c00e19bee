"""Splat-surface points in the survey point product (issue 31, part 3): ``source`` = 4 and their σ through the PLY and
LAS exports, the merge stage's ``splat_surface`` option (off: the products of a merge without it, byte for byte; on:
points on the plane a trained-looking fill layer lies on, none of a virtual layer behind a trusted surface), and the
option tables and command-line flags that turn it on."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import tomllib
import torch
from test_splat_surface import layer
from test_train_trainer import ring_cameras

from core.errors import ConfigError
from core.gaussians import GaussianSet
from core.io import read_point_cloud, write_point_cloud
from core.io.colmap import write_model
from core.io.gaussian_ply import write_gaussian_ply
from core.io.images import write_image
from core.pointcloud import PointCloud
from fusion.convert_options import SPLAT_SURFACE_CLASS, Source
from fusion.export import export_points
from fusion.merge_options import MergeOptions
from fusion.splat_surface import SplatSurfaceOptions, SplatSurfacePoints, as_point_set
from fusion.survey import classes_of_points, with_splat_surface
from hybridsplat.config import ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.options import options_from_table, toml_tables
from hybridsplat.stages.base import StageContext
from hybridsplat.stages.merge import MergeStage


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def found_points(n: int, seed: int = 0) -> SplatSurfacePoints:
    rng = np.random.default_rng(seed)
    return SplatSurfacePoints(
        positions=rng.uniform(-1, 1, (n, 3)), normals=np.tile([0.0, 0, 1], (n, 1)),
        colours=rng.uniform(0, 1, (n, 3)).astype(np.float32), sigma=rng.uniform(1e-4, 5e-3, n),
        confidence=rng.uniform(0.2, 1.0, n), n_views=np.full(n, 3, np.int32), reference=np.zeros(n, np.int32),
    )  # fmt: skip


def product_points(n_mvs: int, n_splat: int, origin: np.ndarray, seed: int = 1) -> GaussianSet:
    """A point product as the merge makes it: MVS points then splat centres, fields ``source`` and
    ``classification``, SH degree 1."""
    rng = np.random.default_rng(seed)
    n = n_mvs + n_splat
    source = np.r_[np.full(n_mvs, Source.MVS), np.full(n_splat, Source.SPLAT)].astype(np.uint8)
    return GaussianSet(rng.uniform(-1, 1, (n, 3)) + 5.0, np.full((n, 3), np.log(2e-3)), np.tile([1.0, 0, 0, 0], (n, 1)),
                       np.full(n, 2.0), rng.normal(0, 0.5, (n, 3)), np.zeros((n, 3, 3)), origin,
                       {"source": source, "classification": np.zeros(n, np.uint8)})  # fmt: skip


@pytest.mark.parametrize("suffix", [".ply", ".las"])
def test_source_4_and_sigma_round_trip_through_the_point_exports(tmp_path, suffix) -> None:
    """Written with the merge's point exporter and read back: ``source`` 4, classification 68 and σ (float32) per
    splat-surface point, the MVS points' σ 0, positions to the LAS 1 mm grid (PLY: float32 about the origin),
    colours to 1/255."""
    origin = np.array([432_100.0, 5_410_200.0, 250.0])
    found = found_points(50)
    surface = as_point_set(found, origin)
    points, counts = with_splat_surface(product_points(30, 0, origin), surface, False, 1e-9)
    assert counts == {"splat_centres_dropped": 0, "unsupported": 0, "near_mvs": 0, "kept": 50} and len(points) == 80
    path = tmp_path / f"points{suffix}"
    export_points(path, points)
    back = read_point_cloud(path)
    source = np.asarray(back.fields["source"])
    assert np.array_equal(np.unique(source), [Source.MVS, Source.SPLAT_SURFACE])
    is_surface = source == Source.SPLAT_SURFACE
    assert int(is_surface.sum()) == 50
    assert np.all(np.asarray(back.fields["classification"])[is_surface] == SPLAT_SURFACE_CLASS)
    assert np.all(np.asarray(back.fields["classification"])[~is_surface] == 0)
    sigma = np.asarray(back.fields["sigma"])
    np.testing.assert_array_equal(sigma[is_surface], found.sigma.astype(np.float32))
    assert np.all(sigma[~is_surface] == 0)
    tol = 5e-4 + 1e-9 if suffix == ".las" else 1e-6  # PLY: float32 about the origin (points within 1 m of it)
    np.testing.assert_allclose(back.world_positions[is_surface], origin + found.positions, rtol=0, atol=tol)
    colours = np.asarray(back.colors[is_surface], np.float64) / 255
    np.testing.assert_allclose(colours, found.colours, atol=0.5 / 255 + 1e-6)


def test_splat_centres_leave_unless_kept_and_mvs_wins_where_both_sample_a_surface() -> None:
    origin = np.zeros(3)
    points = product_points(20, 10, origin)
    found = found_points(40)
    found.positions[:5] = points.means[:5] + 1e-4  # 5 surface points on MVS points, 1 on a splat centre
    found.positions[5] = points.means[25]
    surface = as_point_set(found, origin)
    replaced, c = with_splat_surface(points, surface, keep_centres=False, tolerance=1e-3)
    assert c == {"splat_centres_dropped": 10, "unsupported": 0, "near_mvs": 5, "kept": 35} and len(replaced) == 20 + 35
    assert not np.any(replaced.fields["source"] == Source.SPLAT)
    kept, c = with_splat_surface(points, surface, keep_centres=True, tolerance=1e-3)
    assert c == {"splat_centres_dropped": 0, "unsupported": 0, "near_mvs": 5, "kept": 35} and len(kept) == 30 + 35
    assert "sigma" not in points.fields  # the input is left as it was
    assert kept.sh_degree == 1 and np.all(kept.sh_rest[30:] == 0)  # surface points: DC colour only
    np.testing.assert_allclose(kept.scales[30:, 0], np.delete(found.sigma, range(5)), rtol=1e-5)
    empty = as_point_set(found_points(0), origin)
    same, c = with_splat_surface(points, empty, keep_centres=True, tolerance=1e-3, support=(found.positions, 0.05))
    assert c == {"splat_centres_dropped": 0, "unsupported": 0, "near_mvs": 0, "kept": 0} and len(same) == 30
    np.testing.assert_array_equal(same.means, points.means)
    assert np.all(same.fields["sigma"] == 0)
    # support: only surface points within 0.05 m of a support point stay (a floater has no MVS point near it)
    support = found.positions[5:15] + [0.01, 0, 0]
    held, c = with_splat_surface(points, surface, keep_centres=False, tolerance=1e-3, support=(support, 0.05))
    far = np.linalg.norm(found.positions[:, None] - support[None], axis=2).min(axis=1) > 0.05
    assert c["unsupported"] == int(far.sum()) > 0 and c["kept"] == int((~far[5:]).sum())
    assert c["near_mvs"] == int((~far[:5]).sum())


def test_points_per_class_take_the_nearest_needs_splats_point() -> None:
    means = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    mvs = GaussianSet(means, np.zeros((4, 3)), np.tile([1.0, 0, 0, 0], (4, 1)), np.zeros(4), np.zeros((4, 3)))
    needs = np.array([False, True, True, True])
    predicted = np.array([0, 3, 1, 9])
    query = np.array([[0.1, 0, 0], [1.1, 0, 0], [1.9, 0, 0], [3.2, 0, 0], [2.2, 0, 0]])
    codes = {"reflective": 1, "textureless": 3}
    assert classes_of_points(query, mvs, needs, predicted, codes) == {"reflective": 2, "textureless": 2, "other": 1}
    assert classes_of_points(query, mvs, needs, None, codes) == {"other": 5}
    assert classes_of_points(np.zeros((0, 3)), mvs, needs, predicted, codes) == {}


# ------------------------------------------------------------------------------------------ the merge stage


def plane_project(root) -> tuple[ProjectLayout, StageContext]:
    """Six ring cameras over the plane z = 0. Trusted MVS points (1 cm grid) cover x ∈ [0.1, 1.2]; 400 noisy
    textureless MVS points need splats on x < 0, where the fill layer (cleaned splats) is flat on z = 0; a second
    fill layer at z = −0.3 under x ∈ [0.5, 0.8] is a virtual image (what a mirror at z = 0 would show) behind the
    trusted surface. Masks cover every pixel."""
    layout = ProjectLayout(root)
    cams = ring_cameras(6, width=96, height=72)
    ws = layout.dense_workspace
    ws.make_dirs()
    write_model(ws.sparse, cams)
    write_model(layout.sparse, cams)
    for v in cams:
        cam = cams.camera_of(v)
        write_image(layout.mask_path(v.name), np.full((cam.height, cam.width), 255, np.uint8))
    gx, gy = np.meshgrid(np.arange(0.1, 1.2, 0.01), np.arange(-1.2, 1.2, 0.01))
    trusted = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    rng = np.random.default_rng(3)
    noisy = np.c_[rng.uniform(-0.45, -0.02, 400), rng.uniform(-0.45, 0.45, 400), rng.normal(0, 0.01, 400)]
    means = np.r_[trusted, noisy]
    n = len(means)
    needs = np.r_[np.zeros(len(trusted), bool), np.ones(len(noisy), bool)]
    codes = np.where(needs, 3, 0).astype(np.uint8)
    colours = np.full((n, 3), 128, np.uint8)
    write_point_cloud(layout.classified_points, PointCloud(means, colors=colours, fields={
        "needs_splats": needs.astype(np.uint8), "classification": codes}))  # fmt: skip
    names = ("collaborative", "reflective", "transparent", "textureless", "thin")
    classes = [{"name": nm, "code": c, "needs_splats": c > 0} for c, nm in enumerate(names)]
    layout.classify_report.write_text(json.dumps({"classes": {"class": classes}}))
    mvs = GaussianSet(
        means,
        np.full((n, 3), np.log(4e-3)),
        np.tile([1.0, 0, 0, 0], (n, 1)),
        np.full(n, 3.0),
        np.zeros((n, 3)),
        fields={"source": np.full(n, Source.MVS, np.uint8), "classification": codes},
    )
    write_gaussian_ply(layout.mvs_gaussians, mvs, extra_fields=True)
    real = layer(0.0, half=0.45)
    real = real.subset(real.means[:, 0] < 0)
    virtual = layer(-0.3, half=0.15, seed=1)
    virtual.means[:, 0] += 0.65
    write_gaussian_ply(layout.cleaned_splats, GaussianSet.concatenate([real, virtual]))
    ctx = StageContext(layout=layout, config=ProjectConfig(), source=SimpleNamespace(holdout_names=()))
    return layout, ctx


def products(layout: ProjectLayout) -> dict[str, bytes]:
    files = (layout.merged_ply, layout.merged_points_ply, layout.merged_points_las, layout.splats_export)
    return {p.name: p.read_bytes() for p in files}


def test_merge_stage_adds_splat_surface_points_on_the_plane_only_when_asked(tmp_path, monkeypatch) -> None:
    layout, ctx = plane_project(tmp_path / "p")
    stage = MergeStage()
    ctx.config = ctx.config.with_stage_options("merge", MergeOptions(splat_surface=False))
    off = stage.run(ctx)
    assert off.splat_surface is None and "splat_surface" not in off.as_dict()
    assert "splat-surface" not in stage.summary(off)
    before = products(layout)
    points = read_point_cloud(layout.merged_points_ply)
    assert "sigma" not in points.fields and not np.any(points.fields["source"] == Source.SPLAT_SURFACE)
    # off, whatever the surface rule says: the code path is not entered and the files are the same, byte for byte
    import hybridsplat.stages.merge as merge_module

    def not_called(*args, **kwargs):
        raise AssertionError("the splat-surface path ran with the option off")

    monkeypatch.setattr(merge_module, "_add_splat_surface", not_called)
    rule = SplatSurfaceOptions(min_agreeing=1, max_reproj_px=3.0)
    merge_off = MergeOptions(splat_surface=False, splat_surface_keep_centres=True, splat_surface_points=rule)
    ctx.config = ctx.config.with_stage_options("merge", merge_off)
    assert stage.run(ctx) == off and products(layout) == before
    monkeypatch.undo()

    ctx.config = ctx.config.with_stage_options("merge", MergeOptions(splat_surface=True))
    on = stage.run(ctx)
    c = on.splat_surface
    points = read_point_cloud(layout.merged_points_ply)
    source = np.asarray(points.fields["source"])
    surface = source == Source.SPLAT_SURFACE
    assert int(surface.sum()) == c.kept > 300 and on.points == len(points)
    pos = points.world_positions[surface]
    # on the real layer's plane (a few rim pixels of the layer's edge at x = 0 off by 1.6 mm, within their σ of 4 mm),
    # none of the virtual layer behind the trusted surface
    assert np.quantile(np.abs(pos[:, 2]), 0.99) < 1e-4 and np.abs(pos[:, 2]).max() < 3e-3 and pos[:, 0].max() < 0.1
    assert c.pixels["virtual"] > 100 and c.views == 6
    assert c.found == c.kept + c.near_mvs + c.unsupported and c.per_class == {"textureless": c.kept}
    sigma = np.asarray(points.fields["sigma"])
    assert np.all(sigma[surface] > 0) and np.all(sigma[~surface] == 0)
    assert np.all(np.asarray(points.fields["classification"])[surface] == SPLAT_SURFACE_CLASS)
    # the surface points replace the splat centres; MVS points and the viewer product stay as they were
    assert not np.any(source == Source.SPLAT) and c.splat_centres_dropped == off.point_splats["kept"]
    assert int((source == Source.MVS).sum()) == off.points - off.point_splats["kept"]
    after = products(layout)
    assert after["merged.ply"] == before["merged.ply"] and after["splats.ply"] == before["splats.ply"]
    las = read_point_cloud(layout.merged_points_las)
    assert int((np.asarray(las.fields["source"]) == Source.SPLAT_SURFACE).sum()) == c.kept
    assert f"{c.kept} splat-surface points (textureless {c.kept})" in stage.summary(on)
    assert stage.expected_bytes(ctx) > sum(len(b) for b in after.values())


# ------------------------------------------------------------------------------------- options and the CLI


def test_the_new_options_round_trip_through_config_tables() -> None:
    merge = MergeOptions(splat_surface=False, splat_surface_keep_centres=True,
                         splat_surface_sigma_scale=(("reflective", 1.5), ("thin", 2.0)),
                         splat_surface_points=SplatSurfaceOptions(min_agreeing=3, depth="median"))  # fmt: skip
    table = tomllib.loads("\n".join(toml_tables("merge", merge)))["merge"]
    assert table["splat_surface"] is False and table["splat_surface_points"]["depth"] == "median"
    assert table["splat_surface_sigma_scale"] == [["reflective", 1.5], ["thin", 2.0]]
    assert options_from_table(MergeOptions, table, "test") == merge
    default = tomllib.loads("\n".join(toml_tables("merge", MergeOptions())))["merge"]
    assert default["splat_surface"] is False and options_from_table(MergeOptions, default, "test") == MergeOptions()


def test_splat_surface_flag_on_run() -> None:
    from hybridsplat.commands.stages import apply_cli_values

    merge = apply_cli_values(MergeOptions(), MergeStage.run_options, {"splat_surface": True})
    assert merge == MergeOptions(splat_surface=True)
    assert apply_cli_values(MergeOptions(), MergeStage.run_options, {"splat_surface": None}) == MergeOptions()


def test_run_command_shows_the_splat_surface_flag() -> None:
    from typer.testing import CliRunner

    from hybridsplat.cli import app

    runner = CliRunner()
    run_help = runner.invoke(app, ["run", "--help"], env={"COLUMNS": "250", "TERMINAL_WIDTH": "250"}).output
    assert "--splat-surface" in run_help


# ------------------------------------------------------------------------------------------ eval and report


def test_eval_scores_the_splat_surface_points_per_material_and_the_report_shows_them_only_when_present() -> None:
    from core.units import Units
    from eval.per_material import as_table, geometry_per_material
    from eval.report import _per_material_tables
    from hybridsplat.stages.evaluate import _MaterialReference, _splat_surface_group

    # reference: material 1 on x < 0, material 2 on x > 0 (1 cm grid on z = 0)
    g = np.arange(-0.5, 0.5, 0.01) + 0.005
    x, y = np.meshgrid(g, g)
    ref = PointCloud(np.c_[x.ravel(), y.ravel(), np.zeros(x.size)], fields={"material": (x.ravel() > 0) + 1})
    names = {1: "wood", 2: "mirror"}
    mvs = ref.positions[ref.positions[:, 0] < 0]  # MVS covers the wood only
    surface = ref.positions[ref.positions[:, 0] > 0] + [0, 0, 2e-3]  # surface points 2 mm above the mirror
    source = np.r_[np.full(len(mvs), Source.MVS), np.full(len(surface), Source.SPLAT_SURFACE)].astype(np.uint8)
    cloud = PointCloud(np.r_[mvs, surface], fields={"source": source})
    rows = as_table(geometry_per_material(cloud.world_positions, ref.world_positions, ref.fields["material"], 6e-3),
                    {}, names)  # fmt: skip
    plain = {k: dict(v) for k, v in rows.items()}
    _splat_surface_group(rows, cloud, _MaterialReference(ref, None, Path(".")), 6e-3, names)
    assert rows["mirror"]["splat_surface_points"] == len(surface) and rows["wood"]["splat_surface_points"] == 0
    assert rows["mirror"]["splat_surface_completeness"] == 1.0 and rows["wood"]["splat_surface_completeness"] == 0
    assert abs(rows["mirror"]["splat_surface_accuracy_mean_m"] - 2e-3) < 1e-9
    assert rows["wood"]["splat_surface_accuracy_mean_m"] is None
    without = PointCloud(mvs, fields={"source": np.full(len(mvs), Source.MVS, np.uint8)})
    untouched = {k: dict(v) for k, v in plain.items()}
    _splat_surface_group(untouched, without, _MaterialReference(ref, None, Path(".")), 6e-3, names)
    assert untouched == plain  # no splat-surface points: the rows are as before
    kinds = {"wood": {"kind": "textured", "collaborative": True}, "mirror": {"kind": "mirror", "collaborative": False}}
    table = {"tau_m": 6e-3, "materials": kinds, "products": {"mvs": plain, "merged": rows, "merged_unrefined": rows}}
    tables = {t[0].split(" — ")[0]: t for t in _per_material_tables(table, Units.MM)}
    _, header, body = tables["Table 5c"]
    assert "`merged`" in tables["Table 5c"][0]  # the first product with the points; its controls share them
    assert header == ["material", "kind", "points", "accuracy (mm)", "completeness"]
    assert body[1][0] == "mirror" and body[1][2:] == [str(len(surface)), "2.0", "1.000"]
    assert tables["Table 5"][1] == ["material", "kind", "mvs", "merged", "merged_unrefined"]
    plain_tables = [t[0].split(" — ")[0] for t in _per_material_tables({**table, "products": {"mvs": plain}}, Units.MM)]
    assert plain_tables == ["Table 5", "Table 5b"]  # no splat-surface points: no table of them


def test_the_sigma_scale_of_a_class_multiplies_the_sigma_of_its_points_only(tmp_path) -> None:
    layout, ctx = plane_project(tmp_path / "p")
    stage = MergeStage()
    ctx.config = ctx.config.with_stage_options("merge", MergeOptions(splat_surface=True))
    stage.run(ctx)
    plain = read_point_cloud(layout.merged_points_ply)
    ctx.config = ctx.config.with_stage_options(
        "merge", MergeOptions(splat_surface=True, splat_surface_sigma_scale=(("reflective", 3.0),))
    )
    stage.run(ctx)
    other = read_point_cloud(layout.merged_points_ply)  # the plane's points are predicted textureless: unchanged
    assert np.array_equal(np.asarray(other.fields["sigma"]), np.asarray(plain.fields["sigma"]))
    ctx.config = ctx.config.with_stage_options(
        "merge", MergeOptions(splat_surface=True, splat_surface_sigma_scale=(("textureless", 2.5),))
    )
    stage.run(ctx)
    scaled = read_point_cloud(layout.merged_points_ply)
    surface = np.asarray(plain.fields["source"]) == Source.SPLAT_SURFACE
    assert surface.sum() > 300 and np.array_equal(
        np.asarray(scaled.fields["source"]), np.asarray(plain.fields["source"])
    )
    ratio = (
        np.asarray(scaled.fields["sigma"], np.float64)[surface] / np.asarray(plain.fields["sigma"], np.float64)[surface]
    )
    np.testing.assert_allclose(ratio, 2.5, rtol=1e-6)  # float32 storage
    assert np.array_equal(scaled.world_positions, plain.world_positions)


def test_a_sigma_scale_below_one_is_refused_with_the_entry() -> None:
    with pytest.raises(ConfigError, match=r"splat_surface_sigma_scale .*'reflective', 0.5"):
        MergeOptions(splat_surface_sigma_scale=(("reflective", 0.5),))
