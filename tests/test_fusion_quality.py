"""Rendered quality: the adaptive conversion beats the paper's Eq. 1–4 at the training cameras of a data_synth scene
(textured pixels). Slow (scene generation + rendering); the full comparison is bench/bench_convert_quality.py."""

from __future__ import annotations

import importlib.util
import sys
import warnings
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench" / "bench_convert_quality.py"


def _bench_module():
    spec = importlib.util.spec_from_file_location("bench_convert_quality", BENCH)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


@pytest.mark.slow
def test_adaptive_renders_better_than_paper_on_the_tiny_scene(tmp_path):
    from data_synth import generate_scene, load_scene
    from fusion.convert import convert_points

    bench = _bench_module()
    scene = load_scene(generate_scene("tiny", tmp_path / "scene", seed=0))
    cloud = bench.fused_cloud(scene, voxel=2.0 * scene.gsd_m)
    views = bench.load_views(scene, "train")
    psnr = {}
    for mode in ("paper", "adaptive"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gs = convert_points(cloud, mode).gaussians
        psnr[mode] = bench.evaluate(gs, scene, "train", views)
    # measured: paper 25.0 dB, adaptive 25.4 dB (tabletop at 320x240: +1.2 dB); require a strict gain
    assert psnr["adaptive"] > psnr["paper"], psnr
    assert psnr["paper"] > 18.0, psnr  # both are sensible renders of the photos, not noise
