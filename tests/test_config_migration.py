"""config.toml of hybridsplat 0.2 (flat stage tables) loads into the 0.3 options, with every value where it belongs,
and a stage recorded by 0.2 stays up to date when its effective options did not change."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from core.errors import ConfigError
from fusion.train.options import HardViewOptions, PriorOptions
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
    assert train.snapshot_iterations == (500, 1000, 1500) and train.training.priors is None
    assert train.training.hard_views is None and train.max_image_size == 640
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
    table = {"iterations": 50, "depth_prior": 0.3, "normal_prior": 0.0, "prior_border_px": -1.0, "hard_views": True}
    options = options_from_table(stage_options_types()["train"], migrate_table("train", table), "config.toml")
    assert options.training.priors == PriorOptions(depth_weight=0.3, normal_weight=0.0, border_px=None)
    assert options.training.hard_views == HardViewOptions()
    merge = options_from_table(stage_options_types()["merge"], migrate_table("merge", {"points_min_views": -1,
                               "points_max_rim_spacing": -1.0}), "config.toml")  # fmt: skip
    assert merge.points.min_views == 0 and merge.points.max_rim_spacing is None


def test_the_new_form_round_trips_none_tables_and_enums(tmp_path):
    types = stage_options_types()
    stages = {
        "train": options_with(
            types["train"],
            {"training.priors": {"depth_weight": 0.2}, "training.hard_views": {}, "training.strategy.cap": 1234},
        ),  # fmt: skip
        "clean": options_with(types["clean"], {"min_opacity": "none", "max_scale_spacing": 3.0}),
        "mvs": options_with(types["mvs"], {"backend": "cpu", "num_threads": 1}),
    }
    (tmp_path / "config.toml").write_text(ProjectConfig(stages=stages).to_toml())
    text = (tmp_path / "config.toml").read_text()
    assert 'min_opacity = "none"' in text and "[train.training.priors]" in text and 'kind = "DefaultStrategy"' in text
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
