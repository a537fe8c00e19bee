"""The eval stage's C2C with ``memory_limit_mb`` (``run --memory-limit``, issue 34): the reference cloud read in
chunks and compared cell by cell (eval.geometry_stream over eval.c2c_stream.exact_nearest) gives the figures and
files of the in-memory path (eval.c2c.compare_clouds, eval.per_material.geometry_per_material), which is the truth
here.

Tolerance: exact equality everywhere but the reverse mean / std / rmse, float64 sums by chunks against numpy's
pairwise sums (a few ulps: rel 1e-12). The real plan cannot make several cells of a small cloud (the least limit,
576 MiB, plans ~55 000 points a cell), so the multi-cell runs patch it to 300 points a cell and 1 111-point chunks.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import eval.c2c_stream as c2c_stream
from core.errors import ConfigError
from core.io import read_point_cloud, write_point_cloud
from core.pointcloud import PointCloud
from eval.c2c import distance_stats, nearest_distances
from eval.c2c_stream import C2CPlan, array_chunks, exact_nearest, streamed_distance_stats
from eval.geometry import GeometryOptions, evaluate_geometry
from eval.geometry_stream import geometry_per_material_streamed, reference_source, spool_reference
from eval.per_material import geometry_per_material

UTM = np.array([500_000.0, 5_200_000.0, 300.0])
TAU = 0.05
SMALL = C2CPlan(600.0, 300, 1_111)  # ≥ 16 cells on these clouds; chunks cut across cells
INEXACT = ("mean", "std", "rmse")  # of the reverse distances only


@pytest.fixture
def clouds() -> tuple[PointCloud, PointCloud]:
    """A reference of 8 000 points on a 20 m × 20 m wavy surface at a UTM origin with 4 materials, and a compared
    cloud of 3 002 near it (2 cm noise, 3 classes) in another origin, two of them far beyond any halo."""
    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 20, (8_000, 2))
    ref_pos = np.c_[xy, np.sin(xy[:, 0])]
    material = (xy[:, 0] > 10).astype(np.int32) + 2 * (xy[:, 1] > 15)
    reference = PointCloud(ref_pos, UTM, fields={"material": material})
    near = np.vstack([ref_pos[:3_000] + rng.normal(0, 0.02, (3_000, 3)), [[5, 5, 9.0], [40, 40, 0]]])
    classes = rng.integers(0, 3, len(near)).astype(np.uint8)
    compared = PointCloud(near + 0.123, UTM - 0.123, fields={"classification": classes})
    return compared, reference


def test_streamed_statistics_equal_numpy_with_ties_and_outliers():
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 7, 100, 1_001, 5_000):
        d = np.abs(rng.normal(size=n))
        d[: n // 3] = d[n // 4]  # ties
        for max_dist in (None, 1.0):
            memory, streamed = distance_stats(d, max_dist), streamed_distance_stats(d, max_dist, chunk=97)
            for name, value in memory.as_dict().items():
                if name in INEXACT:
                    assert getattr(streamed, name) == pytest.approx(value, rel=1e-12, abs=0), (n, name)
                else:
                    assert getattr(streamed, name) == value, (n, max_dist, name)


def test_exact_nearest_is_the_in_memory_search_both_ways_beyond_the_halo(tmp_path: Path):
    rng = np.random.default_rng(2)
    xy = rng.uniform(0, 10, (6_000, 2))
    ref = np.c_[xy, np.sin(xy[:, 0])]
    cmp_ = np.vstack([ref[:3_000] + rng.normal(0, 0.01, (3_000, 3)), [[5, 5, 9.0], [30, 30, 0]]])
    near = exact_nearest(array_chunks(cmp_, 777), array_chunks(ref, 555), 0.2, tmp_path, points_per_cell=200, block=5)
    assert near.grid.nx * near.grid.ny >= 16 and near.far[0] >= 2 and near.far[1] > 0
    np.testing.assert_array_equal(near.forward, nearest_distances(cmp_, ref))
    np.testing.assert_array_equal(near.reverse, nearest_distances(ref, cmp_))
    np.testing.assert_array_equal(np.linalg.norm(cmp_ - ref[np.asarray(near.nearest)], axis=1), near.forward)


@pytest.mark.parametrize("suffix", [".ply", ".las", ".laz"])
def test_eval_geometry_with_a_memory_limit_gives_the_in_memory_figures_and_files(clouds, tmp_path, monkeypatch,
                                                                                 suffix):  # fmt: skip
    compared, reference = clouds
    path = write_point_cloud(tmp_path / f"ref{suffix}", reference)
    memory = evaluate_geometry(compared, path, tmp_path / "memory", "x", GeometryOptions(tau=TAU)).as_dict()
    monkeypatch.setattr(c2c_stream, "plan_c2c_memory", lambda limit: SMALL)
    options = GeometryOptions(tau=TAU, memory_limit_mb=600.0)
    streamed = evaluate_geometry(compared, path, tmp_path / "streamed", "x", options).as_dict()
    spooled = spool_reference(reference_source(path, 1_000), tmp_path / "spool", 997)
    assert evaluate_geometry(compared, spooled, tmp_path / "spooled", "x", options).as_dict() == streamed
    assert streamed["per_class"] and streamed["outlier_count"] == memory["outlier_count"]
    for key, value in memory.items():
        if key == "reverse":
            for name, v in value.items():
                assert streamed[key][name] == (pytest.approx(v, rel=1e-12) if name in INEXACT else v), name
        else:
            assert streamed[key] == value, key
    for name in ("c2c_x.ply", "c2c_x.las", "plots/c2c_x_hist.svg", "plots/c2c_x_preview.png"):
        assert (tmp_path / "streamed" / name).read_bytes() == (tmp_path / "memory" / name).read_bytes(), name
    assert not list((tmp_path / "streamed").glob("hybridsplat_*"))  # the work files are gone


@pytest.mark.parametrize("suffix", [".ply", ".las"])
def test_scores_per_material_equal_the_in_memory_ones(clouds, tmp_path, suffix):
    compared, reference = clouds
    path = write_point_cloud(tmp_path / f"ref{suffix}", reference)
    ref = read_point_cloud(path)
    source = reference_source(path, SMALL.chunk)
    spooled = spool_reference(source, tmp_path / "spool", 997)  # what the eval stage reads: decoded once
    for points in (compared.world_positions, compared.world_positions[:0], compared.world_positions[::7]):
        memory = geometry_per_material(points, ref.world_positions, ref.fields["material"], TAU)
        assert geometry_per_material_streamed(points, source, TAU, SMALL, tmp_path) == memory
        assert geometry_per_material_streamed(points, spooled, TAU, SMALL, tmp_path) == memory
    assert not list(tmp_path.glob("hybridsplat_*"))


def test_too_small_a_limit_is_a_config_error_naming_it():
    from hybridsplat.stages.evaluate import EvalStageOptions

    for make in (lambda: EvalStageOptions(memory_limit_mb=100), lambda: GeometryOptions(memory_limit_mb=100)):
        with pytest.raises(ConfigError, match="memory_limit_mb = 100 is too small for the streamed C2C"):
            make()
    with pytest.raises(ConfigError, match="ICP"):
        GeometryOptions(memory_limit_mb=1024, icp_max_correspondence=0.1)
    assert c2c_stream.plan_c2c_memory(1024).points_per_cell > 10_000


def test_run_memory_limit_reaches_the_eval_and_merge_stages(monkeypatch, tmp_path):
    """``run --memory-limit`` is one flag of ``run``; its value sets the eval and merge stages' options (and the
    convert and classify stages')."""
    import hybridsplat.pipeline as pipeline
    from fusion.merge_options import MergeOptions
    from hybridsplat.cli import main
    from hybridsplat.commands.run import _run_parameters
    from hybridsplat.stages.evaluate import EvalStage, EvalStageOptions

    assert [p.name for p in _run_parameters()].count("memory_limit") == 1  # one flag for every stage
    assert any(o.path == "memory_limit_mb" and o.flag == "--memory-limit" for o in EvalStage.run_options)
    seen = {}

    def fake_run(out, config, **kwargs):  # noqa: ANN001, ANN003
        seen["eval"], seen["merge"] = config.options("eval", EvalStageOptions), config.options("merge", MergeOptions)
        raise SystemExit(0)

    monkeypatch.setattr(pipeline, "run_pipeline", fake_run)
    photos = tmp_path / "photos"
    photos.mkdir()
    with pytest.raises(SystemExit):
        main(["run", str(photos), "--out", str(tmp_path / "p"), "--memory-limit", "1024"])
    assert seen["eval"].memory_limit_mb == 1024.0 and seen["merge"].memory_limit_mb == 1024.0


def test_the_summary_and_the_report_name_the_limit_and_the_peak():
    from hybridsplat.stages.evaluate import EvalResult, EvalStage, ProductHeadline

    mvs = {"mvs": ProductHeadline(c2c_mean_m=0.01)}
    result = EvalResult(memory_limit_mb=700.0, peak_rss_mb=612.4, products=mvs)
    line = EvalStage().summary(result)
    assert line.startswith("C2C streamed within 700 MiB (peak 612 MiB)") and "mvs C2C mean" in line
    section = EvalStage().report_section(result)
    assert section is not None and "--memory-limit 700 MiB (peak resident memory of the run 612 MiB" in section.lines[0]
    assert EvalStage().report_section(EvalResult(products=mvs)) is None
