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

    from recon.mvs import MvsBackend, MvsOptions
    from recon.stages import mvs_stage, sfm_stage

    sfm_stage(tabletop, tmp_path, known_poses=True)
    report = mvs_stage(tmp_path, MvsOptions(backend=MvsBackend.CPU))
    assert report.num_points > 10_000
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

    from recon.stages import sfm_stage

    report = sfm_stage(tabletop, tmp_path, known_poses=False)
    n_train = len(list((tabletop / "images").iterdir()))
    assert len(report.registered) == n_train, report.unregistered
    gsd = json.loads((tabletop / "scene.json").read_text())["gsd_m"]
    # measured (seed 0, 72 views, all cameras in the alignment): median 0.09 GSD, 90th percentile 0.23 GSD,
    # max 0.36-0.54 GSD over runs (lowest ring); without the robust final BA: median 0.19-0.25, max 1.4-2.4 GSD
    residuals = report.alignment.residuals
    assert report.alignment.num_inliers == n_train
    assert np.median(residuals) <= 0.2 * gsd
    assert np.percentile(residuals, 90) <= 0.5 * gsd
    assert np.max(residuals) <= 1.0 * gsd
