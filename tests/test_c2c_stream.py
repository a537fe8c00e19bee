"""Out-of-core C2C (eval.c2c_stream) against the in-memory C2C on the same clouds: brute force on small inputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.errors import ConfigError, DataError
from core.io.las import read_las, write_las
from core.pointcloud import PointCloud
from eval.c2c import compare_clouds, nearest_distances
from eval.c2c_stream import array_chunks, las_chunks, streamed_c2c

HALO, TAU = 0.05, 0.02


def _surface(n: int, seed: int, noise: float) -> np.ndarray:
    """n points on a wavy 4 m × 3 m surface with Gaussian noise (metres)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0, 0], [4, 3], (n, 2))
    z = 0.2 * np.sin(2 * xy[:, 0]) * np.cos(3 * xy[:, 1]) + rng.normal(0, noise, n)
    return np.column_stack([xy, z])


@pytest.fixture(scope="module")
def clouds() -> tuple[np.ndarray, np.ndarray]:
    reference = _surface(30_000, 0, 0.0)
    compared = np.vstack([_surface(20_000, 1, 0.01), [[2.0, 1.5, 5.0], [-3.0, -3.0, 0.0]]])  # two beyond the halo
    return compared, reference


def test_distances_and_scores_equal_the_in_memory_c2c_across_many_cells(clouds, tmp_path: Path):
    compared, reference = clouds
    out = tmp_path / "d.npy"
    result = streamed_c2c(
        array_chunks(compared, 7_001), array_chunks(reference, 5_003), HALO, TAU,
        work_dir=tmp_path, points_per_cell=400, distances_path=out,
    )  # fmt: skip
    assert result.grid.nx * result.grid.ny >= 40  # many cells: most nearest neighbours near a border
    expected = nearest_distances(compared, reference, max_dist=HALO)
    got = np.load(out)
    np.testing.assert_array_equal(got, expected.astype(np.float32))
    assert result.stats.outlier_count == 2 and result.stats.count == len(compared) - 2
    memory = compare_clouds(PointCloud(compared), PointCloud(reference), max_dist=HALO, tau=TAU)
    for name in ("mean", "std", "median", "rmse", "p95", "min", "max"):
        assert getattr(result.stats, name) == pytest.approx(getattr(memory.stats, name), rel=1e-6, abs=1e-8), name
    back = nearest_distances(reference, compared, max_dist=HALO).astype(np.float32)
    assert result.scores.precision == np.count_nonzero(got < np.float32(TAU)) / len(compared)
    assert result.scores.recall == np.count_nonzero(back < np.float32(TAU)) / len(reference)
    assert result.scores.fscore == pytest.approx(memory.scores.fscore, abs=1e-6)
    assert result.reverse.mean == pytest.approx(float(back[back < HALO].mean()), rel=1e-6)
    assert not list(tmp_path.glob("hybridsplat_c2c_*"))  # the cell files are gone


def test_the_halo_carries_neighbours_across_edges_and_corners(tmp_path: Path):
    """Queries just inside a cell whose only reference point lies across an edge or a corner of the grid."""
    reference = np.array([[0.0, 0.0, 0.0], [10.0, 10.0, 0.0], [4.99, 5.02, 0.0], [5.01, 4.98, 0.0]])
    compared = np.array([[5.02, 5.01, 0.01], [4.98, 4.99, 0.0], [0.01, 0.0, 0.0]])
    result = streamed_c2c(
        array_chunks(compared), array_chunks(reference), 0.1, work_dir=tmp_path, points_per_cell=1,
        distances_path=tmp_path / "d.npy",
    )  # fmt: skip
    assert result.grid.nx >= 2 and result.grid.ny >= 2  # (5, 5) is a corner of four cells
    np.testing.assert_allclose(np.load(tmp_path / "d.npy"), nearest_distances(compared, reference), rtol=1e-6)


def test_las_chunks_at_utm_coordinates_give_the_in_memory_result(clouds, tmp_path: Path):
    compared, reference = clouds
    utm = np.array([2_600_000.0, 1_200_000.0, 400.0])
    for name, pts in (("cmp.laz", compared), ("ref.laz", reference)):
        write_las(tmp_path / name, PointCloud(pts, origin=utm))  # 1 mm integer steps around the UTM offset
    a, b = read_las(tmp_path / "cmp.laz"), read_las(tmp_path / "ref.laz")
    memory = compare_clouds(a, b, max_dist=HALO, tau=TAU)
    origin = a.origin
    result = streamed_c2c(
        las_chunks(tmp_path / "cmp.laz", origin, 6_000), las_chunks(tmp_path / "ref.laz", origin, 6_000), HALO, TAU,
        points_per_cell=1_000,
    )  # fmt: skip
    assert result.stats.mean == pytest.approx(memory.stats.mean, rel=1e-6)
    assert result.scores.recall == pytest.approx(memory.scores.recall, abs=1e-4)


def test_bad_arguments_are_refused(clouds):
    compared, reference = clouds
    with pytest.raises(ConfigError, match="halo"):
        streamed_c2c(array_chunks(compared), array_chunks(reference), 0.0)
    with pytest.raises(ConfigError, match="tau"):
        streamed_c2c(array_chunks(compared), array_chunks(reference), HALO, tau=2 * HALO)
    with pytest.raises(DataError, match="points in both clouds"):
        streamed_c2c(array_chunks(compared), array_chunks(reference[:0]), HALO)
    with pytest.raises(DataError, match="finite"):
        bad = compared.copy()
        bad[5, 0] = np.nan
        streamed_c2c(array_chunks(bad), array_chunks(reference), HALO)
