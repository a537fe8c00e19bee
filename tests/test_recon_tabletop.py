"""Slow acceptance tests on the data_synth tabletop scene (known poses MVS per material; full SfM + alignment).

The scene is generated once per session (minutes) unless HYBRIDSPLAT_TABLETOP points to a generated copy.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def tabletop(tmp_path_factory) -> Path:
    given = os.environ.get("HYBRIDSPLAT_TABLETOP")
    if given:
        if not (Path(given) / "scene.json").is_file():
            pytest.skip(f"HYBRIDSPLAT_TABLETOP={given} is not a data_synth scene")
        return Path(given)
    from data_synth.generate import generate_scene

    return generate_scene("tabletop", tmp_path_factory.mktemp("tabletop") / "scene", seed=0)


def test_tabletop_known_poses_cpu_mvs_per_material(tabletop: Path, tmp_path: Path):
    sys.path.insert(0, str(REPO / "bench"))
    from bench_mvs import evaluate

    from hybridsplat.config import InputOptions, ProjectConfig
    from hybridsplat.pipeline import run_pipeline
    from hybridsplat.stages import stage_named
    from recon.mvs import MvsOptions

    config = ProjectConfig(
        input=InputOptions(path=str(tabletop)), stages={"mvs": MvsOptions(backend="cpu", max_image_size=-1)}
    )
    manifest = run_pipeline(tmp_path, config, [stage_named("sfm"), stage_named("mvs")])
    assert manifest.stages["mvs"].counts["points"] > 10_000
    _, scores = evaluate(tabletop, tmp_path / "dense" / "fused.ply", tau_gsd=3.0)
    collab = [s for s in scores if s.collaborative]
    non = [s for s in scores if not s.collaborative]
    for s in collab:
        assert s.median_c2c_gsd <= 1.0, s
        assert s.completeness >= 0.80, s
    best_non = max(s.completeness for s in non)
    worst_collab = min(s.completeness for s in collab)
    assert best_non < worst_collab  # mirror / glass / textureless: measurably worse or missing


def test_tabletop_full_sfm_registers_all_and_aligns(tabletop: Path, tmp_path: Path):
    import json

    from hybridsplat.config import InputOptions, ProjectConfig
    from hybridsplat.layout import ProjectLayout
    from hybridsplat.pipeline import run_pipeline
    from hybridsplat.stages import stage_named

    config = ProjectConfig(input=InputOptions(path=str(tabletop), use_scene_cameras=False))
    counts = run_pipeline(tmp_path, config, [stage_named("sfm")]).stages["sfm"].counts
    n_train = len(list((tabletop / "images").iterdir()))
    assert counts["registered"] == n_train, counts["unregistered"]
    gsd = json.loads((tabletop / "scene.json").read_text())["gsd_m"]
    # measured (seed 0, 72 views, all cameras in the alignment): median 0.09 GSD, 90th percentile 0.23 GSD,
    # max 0.36-0.54 GSD over runs (lowest ring); without the robust final BA: median 0.19-0.25, max 1.4-2.4 GSD
    alignment = json.loads(ProjectLayout(tmp_path).record("sfm").read_text())["report"]["alignment"]
    residuals = np.asarray(alignment["residuals"])
    assert counts["alignment_inliers"] == n_train and sum(alignment["inliers"]) == n_train
    assert np.median(residuals) <= 0.2 * gsd
    assert np.percentile(residuals, 90) <= 0.5 * gsd
    assert np.max(residuals) <= 1.0 * gsd
