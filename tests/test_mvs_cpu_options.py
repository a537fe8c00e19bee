"""The CPU MVS quality presets (``--mvs-quality``): what each sets, explicit options over presets, the CLI and
config.toml paths, and that the presets order the work done per pixel."""

from __future__ import annotations

import numpy as np
import pytest

import recon.mvs_cpu as mvs_cpu
from core.errors import ConfigError
from hybridsplat.commands.stages import apply_cli_values
from hybridsplat.options import options_from_table, options_to_data
from hybridsplat.stages.mvs import MvsStage
from recon.mvs import MvsOptions
from recon.mvs_cpu_options import EFFORT, CpuMvsOptions, MvsEffort, MvsQuality


def test_balanced_is_the_default_and_keeps_the_effort_before_issue_32():
    assert CpuMvsOptions().quality is MvsQuality.BALANCED
    # the accuracy figures of the issue were measured against this effort: 64 planes, 3 rounds a level, ±4 px
    assert CpuMvsOptions().effort() == MvsEffort(num_planes=64, refine_rounds=3, finest_rounds=3, far_propagation=True)


def test_options_given_override_the_preset():
    opts = CpuMvsOptions(quality="fast", num_planes=40, far_propagation=False)
    assert opts.quality is MvsQuality.FAST
    effort = opts.effort()
    assert (effort.num_planes, effort.far_propagation) == (40, False)
    assert (effort.refine_rounds, effort.finest_rounds) == (EFFORT[MvsQuality.FAST].refine_rounds, 1)


def test_unknown_quality_names_the_choices():
    with pytest.raises(ConfigError, match="quality must be one of fast, balanced, high, got 'best'"):
        CpuMvsOptions(quality="best")


@pytest.mark.parametrize("declared", ["command_options", "run_options"])
def test_mvs_quality_on_the_command_line_sets_the_preset(declared: str):
    options = apply_cli_values(MvsOptions(), getattr(MvsStage, declared), {"mvs_quality": "high"})
    assert options.cpu.quality is MvsQuality.HIGH
    assert options.max_image_size == MvsOptions().max_image_size  # resolution stays its own control


def test_presets_order_the_hypotheses_tried_per_pixel(monkeypatch):
    rng = np.random.default_rng(0)
    img = rng.random((48, 64)).astype(np.float32)
    K = np.array([[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]])
    move = np.eye(4)
    move[0, 3] = -0.3
    evaluated = {}
    cost = mvs_cpu._cost
    for quality in MvsQuality:
        count = [0]

        def counting(level, inv, count=count):
            count[0] += inv.numel()
            return cost(level, inv)

        monkeypatch.setattr(mvs_cpu, "_cost", counting)
        opts = CpuMvsOptions(quality=quality, coarse_size=32)
        mvs_cpu.estimate_depth(img, [np.roll(img, 3, axis=1)], K, [K], [move], (2.0, 8.0), opts)
        evaluated[quality] = count[0] / img.size
    fast, balanced, high = (evaluated[q] for q in MvsQuality)
    assert fast < 0.6 * balanced and high > 1.2 * balanced


def test_config_toml_round_trip_keeps_preset_and_overrides():
    given = MvsOptions(cpu=CpuMvsOptions(quality="fast", num_planes=40))
    data = options_to_data(given)
    assert data["cpu"]["quality"] == "fast" and data["cpu"]["refine_rounds"] == "none"
    back = options_from_table(MvsOptions, data, "config.toml")
    assert back.cpu == given.cpu and back.cpu.effort().num_planes == 40
