"""config.toml of hybridsplat 0.2 (flat stage tables) loads into the 0.3 options, with every value where it belongs,
and a stage recorded by 0.2 stays up to date when its effective options did not change."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from core.errors import ConfigError
from hybridsplat.config import ProjectConfig, read_config
from hybridsplat.config_migration import migrate_table
from hybridsplat.manifest import StageRecord
from hybridsplat.options import options_digest, options_from_table, options_with
from hybridsplat.runner import record_is_current
from hybridsplat.stages import stage_named, stage_options_types

OLD_CONFIG = Path(__file__).parent / "data" / "config_v0.2.toml"  # written by `hybridsplat demo` of 0.2


def test_a_config_written_by_0_2_loads_with_every_value_in_its_new_place():
    config = read_config(OLD_CONFIG, stage_options_types())
    train, baseline = config.stages["train"], config.stages["baseline"]
    assert train.training.iterations == 600 and train.training.strategy.cap == 60_000
    assert train.training.strategy.refine_start == 100 and train.init.rays_per_view == 400
    assert train.snapshot_iterations == (500, 1000, 1500)
    assert train.max_image_size == 640
    assert baseline.enabled and baseline.training.iterations == 1000 and baseline.checkpoints == ()
    assert config.stages["mvs"].num_threads is None and config.stages["mvs"].fusion.min_num_pixels == 3
    assert config.stages["sfm"].align_threshold_m is None
    clean = config.stages["clean"]
    assert clean.max_scale_spacing is None and clean.min_opacity == 0.02  # "-1 = off" became None
    merge = config.stages["merge"]
    assert merge.points.max_rim_spacing == 0.5 and merge.needs_mvs_classes == ("textureless",)
    assert config.stages["mesh"].budget == 2000 and config.stages["mesh"].mesh.use_snapshots
    assert config.stages["eval"].tau_m is None
    # the demo's options of 0.2 are exactly those of 0.3's demo
    from hybridsplat.commands.common import stage_options_from_cli
    from hybridsplat.commands.run import DEMO_STAGES

    demo = stage_options_from_cli(**DEMO_STAGES)
    for name, options_type in stage_options_types().items():
        expected = demo.get(name, options_type())
        if name == "sfm":  # 0.2 wrote its default matcher, exhaustive, and keeps it (auto came later)
            assert config.options(name, options_type).matcher.value == "exhaustive"
            expected = dataclasses.replace(expected, matcher="exhaustive")
        if name == "merge":  # the demo's SPZ and SOG copies of the viewer product came later
            expected = dataclasses.replace(expected, viewer_formats=())
        assert config.options(name, options_type) == expected, name


def test_old_switches_become_the_new_optional_tables():
    merge = options_from_table(stage_options_types()["merge"], migrate_table("merge", {"points_min_views": -1,
                               "points_max_rim_spacing": -1.0}), "config.toml")  # fmt: skip
    assert merge.points.min_views == 0 and merge.points.max_rim_spacing is None


def test_the_new_form_round_trips_none_tables_and_enums(tmp_path):
    types = stage_options_types()
    stages = {
        "train": options_with(
            types["train"],
            {"training.strategy.cap": 1234},
        ),  # fmt: skip
        "clean": options_with(types["clean"], {"min_opacity": "none", "max_scale_spacing": 3.0}),
        "mvs": options_with(types["mvs"], {"backend": "cpu", "num_threads": 1}),
    }
    (tmp_path / "config.toml").write_text(ProjectConfig(stages=stages).to_toml())
    text = (tmp_path / "config.toml").read_text()
    assert 'min_opacity = "none"' in text and "[train.training.strategy]" in text and "kind" not in text
    back = read_config(tmp_path / "config.toml", types)
    assert back.stages == stages


def test_config_errors_name_the_option_and_the_file(tmp_path):
    path = tmp_path / "config.toml"
    for text, words in (
        ("[train.training]\niterations = 'many'\n", "training.iterations must be int"),
        ("[mvs]\nbackend = 'gpu'\n", "backend must be one of auto, cpu, colmap"),
        ("[train.training]\nwarp = 1\n", "unknown option(s) training.warp"),
        ("[clean]\nmin_opacity = 'sometimes'\n", "min_opacity"),
    ):
        path.write_text(text)
        with pytest.raises(ConfigError) as err:
            read_config(path, stage_options_types())
        assert words in str(err.value) and "config.toml" in err.value.one_line(), text


def test_a_removed_option_value_is_refused_naming_the_key_the_version_and_the_record(tmp_path):
    """``[masks] hole_area = "region"`` (removed by issue 54): one ConfigError naming the key, the value, the version
    and docs/migration.md, from config.toml and from the command line alike; the values that stay still load."""
    from classify.mask_options import HOLE_AREAS, MaskOptions
    from hybridsplat.config_migration import NEXT_VERSION
    from hybridsplat.options import with_option

    path = tmp_path / "config.toml"
    path.write_text('[masks]\nhole_area = "region"\n')
    with pytest.raises(ConfigError) as err:
        read_config(path, stage_options_types())
    line = err.value.one_line()
    assert f'[masks] hole_area = "region" was removed in {NEXT_VERSION}' in line and "docs/migration.md" in line
    assert "config.toml" in line and "\n" not in line
    with pytest.raises(ConfigError, match='hole_area = "region" was removed') as err:
        with_option(MaskOptions(), "hole_area", "region", "--hole-area")
    assert "--hole-area" in err.value.one_line()
    assert "region" not in HOLE_AREAS
    for kept in HOLE_AREAS:
        path.write_text(f'[masks]\nhole_area = "{kept}"\n')
        assert read_config(path, stage_options_types()).stages["masks"].hole_area.value == kept


def test_a_stage_recorded_by_0_2_is_current_when_its_options_did_not_move_in_value(tmp_path):
    clean = stage_named("clean")
    old = {"min_opacity": 0.02, "max_scale_scene": 0.2, "max_scale_spacing": -1.0, "cluster_eps_spacing": 50.0,
           "min_cluster_size": 3, "mask_dilation_px": 2}  # fmt: skip
    record = StageRecord(name="clean", config={"options": old, "fingerprint": {}}, inputs={"a": "h"})
    now = {"options": options_digest(clean.Options()), "fingerprint": {}}
    assert record_is_current(record, clean, {"a": "h"}, now, tmp_path)
    changed = {"options": options_digest(dataclasses.replace(clean.Options(), min_cluster_size=4)), "fingerprint": {}}
    assert not record_is_current(record, clean, {"a": "h"}, changed, tmp_path)
    assert not record_is_current(record, clean, {"a": "other"}, now, tmp_path)


# -- removed options (issue 54) -----------------------------------------------------------------------------------
#: the splat-surface options of [merge] as a default config.toml of 0.3 spelled them (every one, the switch off)
SPLAT_SURFACE_OFF = {
    "splat_surface": False, "splat_surface_keep_centres": False, "splat_surface_support": 2.0,
    "splat_surface_sigma_scale": [["reflective", 1.25]],
    "splat_surface_points": {
        "depth": "plane", "min_agreeing": 2, "max_reproj_px": 1.0, "max_rel_depth": 0.01, "front_margin": 0.01,
        "sigma_floor_px": 0.1, "sigma_footprint": 1.5, "sigma_roughness": 0.5, "sigma_anchor": 2.0,
        "sigma_neighbours": 8,
    },
}  # fmt: skip
#: (stage, the option as the error spells it, its stage table with the option off, the same with it on)
REMOVED_CASES = {
    "priors": ("train", "train.training.priors", {"training": {"priors": "none"}},
               {"training": {"priors": {"depth_weight": 0.2}}}),
    "priors of 0.2": ("train", "train.depth_prior", {"depth_prior": 0.0, "prior_border_px": 8.0}, {"depth_prior": 0.3}),
    "baseline priors": ("baseline", "baseline.training.priors", {"training": {"priors": "none"}},
                        {"training": {"priors": {}}}),
    "geometry": ("train", "train.training.geometry",
                 {"training": {"geometry": "none", "flat": False, "flat_reg": 10.0}},
                 {"training": {"geometry": {"every": 2}}}),
    "flat": ("background", "background.training.flat", {"training": {"flat": False}}, {"training": {"flat": True}}),
    "flat of 0.2": ("train", "train.flat", {"flat": False}, {"flat": True}),
    "lpips": ("train", "train.training.lpips_weight",
              {"lpips_weights": "", "training": {"lpips_weight": 0.0, "lpips_start": 0.8, "lpips_margin": 16}},
              {"training": {"lpips_weight": 0.1}}),
    "photometric": ("baseline", "baseline.training.photometric",
                    {"training": {"photometric": "l1_ssim", "smoothl1_beta": 0.05}},
                    {"training": {"photometric": "smoothl1_msssim"}}),
    "photometric of 0.2": ("train", "train.photometric", {"photometric": "l1_ssim"},
                           {"photometric": "smoothl1_msssim"}),
    "hard views": ("train", "train.training.hard_views", {"training": {"hard_views": "none"}},
                   {"training": {"hard_views": {"start": 0.2}}}),
    "hard views of 0.2": ("train", "train.hard_views", {"hard_views": False}, {"hard_views": True}),
    "mcmc": ("train", "train.training.strategy.kind", {"training": {"strategy": {"kind": "DefaultStrategy"}}},
             {"training": {"strategy": {"kind": "MCMCStrategy", "grow_rate": 0.05}}}),
    "lpips in appearance": ("appearance", "appearance.training.lpips_weight", {"training": {"lpips_weight": 0}},
                            {"training": {"lpips_weight": 0.2, "lpips_start": 0.5}}),
    "lpips of 0.2": ("train", "train.lpips_weight", {"lpips_weight": 0.0, "lpips_start": 0.8, "lpips_weights": ""},
                     {"lpips_weight": 0.1}),
    "splat surface": ("merge", "merge.splat_surface", SPLAT_SURFACE_OFF,
                      {**SPLAT_SURFACE_OFF, "splat_surface": True}),
}  # fmt: skip


def _write_table(path: Path, stage: str, table: dict) -> None:
    from hybridsplat.options import _toml_tables

    path.write_text("\n".join(_toml_tables(stage, table)), encoding="utf-8")


@pytest.mark.parametrize("case", sorted(REMOVED_CASES))
def test_a_removed_option_off_is_left_out_and_on_is_one_error_naming_it(case, tmp_path):
    """What earlier versions wrote (every option, the removed ones off) still loads, to today's defaults; a removed
    option set on fails with one line naming the file, the option, the version and the migration notes."""
    stage, spelled, off, on = REMOVED_CASES[case]
    types = stage_options_types()
    path = tmp_path / "config.toml"
    _write_table(path, stage, off)
    assert read_config(path, types).options(stage, types[stage]) == types[stage]()
    _write_table(path, stage, on)
    with pytest.raises(ConfigError) as err:
        read_config(path, types)
    line = err.value.one_line()
    assert line.startswith(f"{path}: ") and f"{spelled} = " in line, line
    assert "removed in 0.4" in line and "docs/migration.md" in line and "\n" not in line


def test_a_stage_recorded_with_removed_options_off_stays_current(tmp_path):
    train = stage_named("train")
    recorded = options_digest(train.Options())
    recorded["training"] = {**recorded["training"], "priors": "none"}
    record = StageRecord(name="train", config={"options": recorded, "fingerprint": {}}, inputs={"a": "h"})
    now = {"options": options_digest(train.Options()), "fingerprint": {}}
    assert record_is_current(record, train, {"a": "h"}, now, tmp_path)
    recorded["training"]["priors"] = {"depth_weight": 0.2}  # it trained with priors: rerun without them
    assert not record_is_current(record, train, {"a": "h"}, now, tmp_path)


def test_an_old_config_with_splat_surface_on_fails_naming_it_and_the_verdict(tmp_path):
    """``[merge] splat_surface = true`` (removed by issue 54): one line naming the file, the key, the version, why
    and where to read more; the same option off loads to today's defaults."""
    types = stage_options_types()
    path = tmp_path / "config.toml"
    path.write_text("[merge]\nsplat_surface = true\nsplat_surface_support = 2.0\n", encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        read_config(path, types)
    line = err.value.one_line()
    assert line.startswith(f"{path}: option(s) removed in 0.4: merge.splat_surface = true (the splat-surface"), line
    assert "did not hold on the scoring ones" in line and "docs/migration.md" in line
    assert "splat_surface_support" not in line  # acts only with the switch: left out, not refused on its own
    path.write_text("[merge]\nsplat_surface = false\n", encoding="utf-8")
    assert read_config(path, types).options("merge", types["merge"]) == types["merge"]()


def test_a_merge_recorded_with_the_splat_surface_options_off_stays_current(tmp_path):
    """A merge of 0.3 recorded every splat-surface option (off): not re-run for their removal; on, it is."""
    merge = stage_named("merge")
    recorded = {**options_digest(merge.Options()), **SPLAT_SURFACE_OFF}
    record = StageRecord(name="merge", config={"options": recorded, "fingerprint": {}}, inputs={"a": "h"})
    now = {"options": options_digest(merge.Options()), "fingerprint": {}}
    assert record_is_current(record, merge, {"a": "h"}, now, tmp_path)
    recorded["splat_surface"] = True  # it merged with splat-surface points: rerun without them
    assert not record_is_current(record, merge, {"a": "h"}, now, tmp_path)
