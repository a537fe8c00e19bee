"""Streamed conversion (fusion.convert_stream) against the in-memory conversion (fusion.convert) as the oracle.

Every comparison is exact (equal bytes of the 3DGS PLY, equal LAS records): the streamed path runs the same float64
operations on the same values (neighbour distances of the same positions, the same median, the same kernels). The
one place where exactness is not promised is ``paper``'s global mean spacing d, summed in another order (relative
difference ~1e-16): the clouds here still give identical float32 values, and the statistics' float64 d is compared
at 1e-12 relative. Ties between distinct neighbours at exactly the k-th distance (which would allow other PCA
neighbours) do not occur in these random clouds. The clouds hold exact duplicates, isolated outliers (searched again
by the fallback), points exactly on cell borders, and a UTM origin.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from core.errors import ConfigError, DataError, FormatError, InputFileError
from core.io.colmap_vis import read_vis, write_vis
from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply
from core.io.las import read_las, write_las
from core.io.ply import read_ply, write_ply
from core.io.point_stream import PointSource, cloud_source, las_source, ply_source
from core.pointcloud import PointCloud
from eval.c2c_stream import grid_for
from fusion.convert import convert_points
from fusion.convert_options import ConvertOptions
from fusion.convert_stream import StreamOptions, convert_stream, order_statistic, plan_memory
from fusion.export import export_points

UTM = np.array([500_000.0, 5_200_000.0, 300.0])
SMALL = StreamOptions(points_per_cell=1_000, chunk_size=4_999, median_in_memory=700)  # ≥ 20 cells, radix median


def _cloud(n: int, seed: int, *, normals: bool = False, origin: np.ndarray | None = None) -> PointCloud:
    """n points on a wavy 4 m × 3 m surface (2 mm noise), 40 exact duplicates, 5 isolated outliers, random
    colours and ``confidence``; the two x-y corners (0, 0) and (4, 3) fix the bounds. With ``normals``, random unit
    normals of which 60 are unusable (zero or NaN), so PCA fills those."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0, 0], [4, 3], (n, 2))
    xy[:2] = [[0, 0], [4, 3]]
    z = 0.2 * np.sin(2 * xy[:, 0]) * np.cos(3 * xy[:, 1]) + rng.normal(0, 0.002, n)
    pos = np.column_stack([xy, z])
    pos[100:140] = pos[200:240]
    pos[300:305, 2] += rng.uniform(1.0, 3.0, 5)
    nrm = None
    if normals:
        nrm = rng.normal(size=(n, 3)).astype(np.float32)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm[400:430], nrm[430:460] = 0.0, np.nan
    fields = {"confidence": rng.random(n).astype(np.float32), "classification": rng.integers(0, 5, n).astype(np.uint8)}
    colors = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    return PointCloud(pos, np.zeros(3) if origin is None else origin, colors, nrm, fields)


def _on_borders(cloud: PointCloud, halo: float, options: StreamOptions) -> PointCloud:
    """Move 300 points exactly onto the interior cell borders of the grid the streamed run will use."""
    grid = grid_for(np.array([0.0, 0.0]), np.array([4.0, 3.0]), len(cloud), halo, options.points_per_cell)
    rng = np.random.default_rng(7)
    pos = cloud.positions.copy()
    rows = np.arange(1_000, 1_300)
    pos[rows[:150], 0] = grid.x0 + grid.cell * rng.integers(1, grid.nx, 150)
    pos[rows[150:], 1] = grid.y0 + grid.cell * rng.integers(1, grid.ny, 150)
    return PointCloud(pos, cloud.origin, cloud.colors, cloud.normals, cloud.fields)


def _same_ply(streamed: Path, gaussians, tmp_path: Path, extra_fields: bool = False) -> None:  # noqa: ANN001
    """The streamed PLY is byte for byte what write_gaussian_ply writes, and reads back to the same set."""
    expected = write_gaussian_ply(tmp_path / "memory.ply", gaussians, extra_fields=extra_fields)
    assert streamed.read_bytes() == expected.read_bytes()
    a, b = read_gaussian_ply(streamed), read_gaussian_ply(expected)
    for name in ("means", "log_scales", "quats", "logit_opacities", "sh_dc", "origin"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def _quiet(fn, *args, **kwargs):  # noqa: ANN001, ANN202
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*args, **kwargs)


@pytest.mark.parametrize("normals", [False, True], ids=["pca-normals", "mvs-normals"])
@pytest.mark.parametrize("mode", ["adaptive", "paper"])
def test_streamed_equals_in_memory_across_many_cells(mode: str, normals: bool, tmp_path: Path):
    halo = 0.04
    options = StreamOptions(points_per_cell=1_000, chunk_size=4_999, median_in_memory=700, halo=halo)
    cloud = _on_borders(_cloud(30_000, 1, normals=normals), halo, options)
    expected = _quiet(convert_points, cloud, mode)
    r = _quiet(convert_stream, cloud_source(cloud, 7_001), mode, stream=options, ply_path=tmp_path / "s.ply")
    assert r.cells >= 20 and r.halo == halo and r.num_points == len(cloud)
    assert r.grid == grid_for(np.zeros(2), np.array([4.0, 3.0]), len(cloud), halo, 1_000)
    assert r.fallback_points >= 5  # the outliers' neighbours lie beyond the halo: searched again, exactly
    _same_ply(tmp_path / "s.ply", expected.gaussians, tmp_path)
    s, e = r.stats, expected.stats
    assert (s.median_spacing, s.clamped_spacing, s.clamped_opacity) == (
        e.median_spacing,
        e.clamped_spacing,
        e.clamped_opacity,
    )
    assert s.estimated_normals == e.estimated_normals
    assert s.mean_nn_spacing == pytest.approx(e.mean_nn_spacing, rel=1e-12)


def test_tiny_halo_falls_back_to_exact_search(tmp_path: Path):
    cloud = _cloud(20_000, 2)
    options = StreamOptions(points_per_cell=800, chunk_size=3_000, halo=0.002)  # below the k-th neighbour distance
    source = cloud_source(cloud, 6_000)
    r = _quiet(convert_stream, source, stream=options, ply_path=tmp_path / "s.ply", extra_fields=True)
    assert r.fallback_points > 1_000
    _same_ply(tmp_path / "s.ply", _quiet(convert_points, cloud).gaussians, tmp_path, extra_fields=True)


def test_default_halo_and_visibility_confidence(tmp_path: Path):
    cloud = _cloud(20_000, 3)
    rng = np.random.default_rng(3)
    cloud.visibility = [np.arange(rng.integers(0, 6)) for _ in range(len(cloud))]
    r = _quiet(
        convert_stream,
        cloud_source(cloud, 5_000),
        stream=StreamOptions(points_per_cell=900),
        ply_path=tmp_path / "s.ply",
    )
    assert r.cells >= 20 and r.halo > 0
    _same_ply(tmp_path / "s.ply", _quiet(convert_points, cloud).gaussians, tmp_path)


def test_utm_las_source_and_laz_export_equal_the_in_memory_export(tmp_path: Path):
    cloud = _cloud(25_000, 4, normals=True, origin=UTM)
    write_las(tmp_path / "in.laz", cloud)
    memory = read_las(tmp_path / "in.laz")  # the oracle reads the file as the stream does
    assert np.abs(memory.origin - UTM).max() < 3  # a local origin near the data (bounding-box centre)
    gaussians = _quiet(convert_points, memory).gaussians
    export_points(tmp_path / "memory.laz", gaussians)
    source = las_source(tmp_path / "in.laz", chunk=6_000)
    r = _quiet(convert_stream, source, stream=SMALL, ply_path=tmp_path / "s.ply", las_path=tmp_path / "s.laz")
    assert np.array_equal(r.origin, memory.origin) and r.cells >= 20 and r.las_points == len(cloud)
    _same_ply(tmp_path / "s.ply", gaussians, tmp_path)
    a, b = read_las(tmp_path / "s.laz"), read_las(tmp_path / "memory.laz")
    np.testing.assert_array_equal(a.origin, b.origin)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.colors, b.colors)
    assert list(a.fields) == list(b.fields) and {"source", "opacity", "scale", "confidence"} <= set(a.fields)
    for name in a.fields:
        np.testing.assert_array_equal(a.fields[name], b.fields[name], err_msg=name)


def test_fused_ply_and_vis_source_equals_read_ply_and_read_vis(tmp_path: Path):
    cloud = _cloud(20_000, 13, normals=True, origin=UTM)
    rng = np.random.default_rng(13)
    visibility = [rng.choice(40, rng.integers(0, 6), replace=False) for _ in range(len(cloud))]
    write_ply(tmp_path / "fused.ply", cloud)
    write_vis(tmp_path / "fused.ply.vis", visibility)
    memory = read_ply(tmp_path / "fused.ply")
    memory.visibility = read_vis(tmp_path / "fused.ply.vis", len(memory))
    expected = _quiet(convert_points, memory).gaussians
    source = ply_source(tmp_path / "fused.ply", tmp_path / "fused.ply.vis", chunk=3_001)
    r = _quiet(convert_stream, source, stream=SMALL, ply_path=tmp_path / "s.ply")
    assert r.cells >= 20 and np.array_equal(r.origin, memory.origin)
    _same_ply(tmp_path / "s.ply", expected, tmp_path)
    write_vis(tmp_path / "short.vis", visibility[:-1])
    with pytest.raises(FormatError, match="lists 19999 points, the cloud has 20000") as err:
        ply_source(tmp_path / "fused.ply", tmp_path / "short.vis")
    assert "short.vis" in str(err.value)
    cut = tmp_path / "cut.vis"
    cut.write_bytes((tmp_path / "fused.ply.vis").read_bytes()[:-8])
    with pytest.raises(FormatError, match="truncated") as err:
        ply_source(tmp_path / "fused.ply", cut, chunk=3_001)
    assert "cut.vis" in str(err.value)


def test_paper_mean_spacing_and_opacity_filter(tmp_path: Path):
    cloud = _cloud(20_000, 5)
    options = ConvertOptions(opacity_logit_min=-9.0)  # lets α fall below the export's 1/255
    expected = _quiet(convert_points, cloud, "adaptive", options)
    cut = expected.gaussians.opacities >= np.float32(1 / 255)
    assert 0 < cut.sum() < len(cloud)
    r = _quiet(convert_stream, cloud_source(cloud, 5_000), "adaptive", options, SMALL, las_path=tmp_path / "s.las")
    assert r.las_points == cut.sum() and r.dropped_opacity == len(cloud) - cut.sum()
    export_points(tmp_path / "memory.las", expected.gaussians)
    np.testing.assert_array_equal(read_las(tmp_path / "s.las").positions, read_las(tmp_path / "memory.las").positions)
    paper = _quiet(convert_stream, cloud_source(cloud, 5_000), "paper", stream=SMALL)
    assert paper.stats.mean_nn_spacing == pytest.approx(
        _quiet(convert_points, cloud, "paper").stats.mean_nn_spacing, rel=1e-12
    )


@pytest.mark.parametrize("n", [1, 2, 5])
def test_tiny_clouds(n: int, tmp_path: Path):
    cloud = PointCloud(np.random.default_rng(n).normal(size=(n, 3)), colors=np.full((n, 3), 200, np.uint8))
    for mode in ("adaptive", "paper"):
        r = _quiet(convert_stream, cloud_source(cloud), mode, ply_path=tmp_path / "s.ply")
        assert r.num_points == n
        _same_ply(tmp_path / "s.ply", _quiet(convert_points, cloud, mode).gaussians, tmp_path)


def test_warnings_match_the_in_memory_counts():
    cloud = _cloud(5_000, 6)
    cloud.colors = None
    options = ConvertOptions(min_spacing=0.05)  # clamps many spacings
    with pytest.warns(Warning) as memory:
        expected = convert_points(cloud, "adaptive", options).stats
    with pytest.warns(Warning) as streamed:
        r = convert_stream(cloud_source(cloud), "adaptive", options, SMALL)
    assert r.stats.missing_colors and r.stats.clamped_spacing == expected.clamped_spacing > 0
    assert r.stats.clamped_opacity == expected.clamped_opacity
    counts = [f"{expected.clamped_spacing} of 5000", "5000 Gaussians get mid grey"]
    for text in counts:
        assert any(text in str(w.message) for w in memory) and any(text in str(w.message) for w in streamed)


def test_order_statistic_is_exact():
    rng = np.random.default_rng(8)
    parts = [rng.exponential(0.01, 3_000), np.full(2_000, 0.0125), rng.uniform(0, 1, 1_000), np.zeros(10)]
    values = np.sort(np.concatenate(parts))
    for rank in (0, 9, 10, 2_999, 3_000, 4_000, len(values) - 1):
        assert order_statistic(lambda: iter(parts), rank, 50) == values[rank]


def test_memory_limit_sets_the_sizes_and_refuses_too_little():
    small, big = plan_memory(1_024), plan_memory(4_096)
    assert 0 < small.points_per_cell < big.points_per_cell and 0 < small.chunk_size < big.chunk_size
    with pytest.raises(ConfigError, match="memory_limit_mb = 100 is too small"):
        plan_memory(100)
    with pytest.raises(ConfigError, match="memory_limit_mb = 100 is too small"):
        convert_stream(cloud_source(_cloud(1_000, 0)), stream=StreamOptions(memory_limit_mb=100))


def test_memory_limit_is_used_and_recorded(tmp_path: Path):
    cloud = _cloud(20_000, 14)
    r = _quiet(
        convert_stream, cloud_source(cloud), stream=StreamOptions(memory_limit_mb=600), ply_path=tmp_path / "s.ply"
    )
    assert r.plan == plan_memory(600) and r.peak_rss_mb > 0
    _same_ply(tmp_path / "s.ply", _quiet(convert_points, cloud).gaussians, tmp_path)


def test_a_failed_export_leaves_no_file_behind(tmp_path: Path):
    cloud = _cloud(5_000, 15)
    cloud.fields["classification"] = np.full(len(cloud), 300, np.uint16)  # not a LAS class
    with pytest.raises(DataError, match="0..255"):
        _quiet(convert_stream, cloud_source(cloud, 1_000), stream=SMALL, ply_path=tmp_path / "s.ply",
               las_path=tmp_path / "s.laz")  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_bad_inputs_name_the_file(tmp_path: Path):
    missing = tmp_path / "nothing.laz"
    with pytest.raises(InputFileError, match="does not exist") as err:
        las_source(missing)
    assert "nothing.laz" in str(err.value)
    truncated = tmp_path / "cut.laz"
    write_las(tmp_path / "whole.laz", _cloud(5_000, 9))
    truncated.write_bytes((tmp_path / "whole.laz").read_bytes()[:3_000])
    with pytest.raises((InputFileError, FormatError)) as err:
        convert_stream(las_source(truncated), stream=SMALL)
    assert "cut.laz" in str(err.value)
    bad = _cloud(1_000, 10)
    bad.positions[500, 1] = np.nan
    with pytest.raises(DataError, match=r"NaN or infinite coordinates \(first: point 500\)") as err:
        convert_stream(PointSource(lambda: bad.chunks(300), tmp_path / "fused.ply"), stream=SMALL)
    assert "fused.ply" in str(err.value)
    with pytest.raises(DataError, match="empty"):
        convert_stream(PointSource(lambda: iter(()), tmp_path / "empty.ply"))
    mixed = [_cloud(1_000, 11), _cloud(1_000, 12, normals=True)]
    with pytest.raises(DataError, match="other attributes"):
        convert_stream(PointSource(lambda: iter(mixed), tmp_path / "mixed.ply"))
    with pytest.raises(FormatError, match="suffix"):
        convert_stream(cloud_source(_cloud(1_000, 0)), las_path=tmp_path / "out.txt")
    with pytest.raises(ConfigError, match="halo"):
        convert_stream(cloud_source(_cloud(1_000, 0)), stream=StreamOptions(halo=-1.0))
