"""The convert stage with ``memory_limit_mb`` (``run --memory-limit``): the fused cloud converted in chunks
(fusion.convert_stream) gives export/mvs_gaussians.ply byte for byte as the in-memory conversion, and the stage
records the limit, the peak memory and the cells.

The stage's own plan cannot make several cells of a small cloud (the least limit, 576 MiB, plans ~96 000 points a
cell), so the multi-cell run patches the plan to 500 points a cell: the stage path is the same, only the sizes
differ. tests/test_convert_stream.py holds the streamed conversion itself against the in-memory one.
"""

from __future__ import annotations

import numpy as np
import pytest

import fusion.convert_stream as convert_stream
from core.cameras import Camera, Cameras, View
from core.io.colmap import write_model
from core.io.origin import sidecar_path
from core.io.ply import write_ply
from core.pointcloud import PointCloud
from hybridsplat.config import ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.stages.base import StageContext
from hybridsplat.stages.convert import ConvertResult, ConvertStage, ConvertStageOptions
from recon.workspace import DenseWorkspace, write_vis

UTM = np.array([500_000.0, 5_200_000.0, 300.0])


def _project(root, n: int = 4_000, seed: int = 5) -> ProjectLayout:  # noqa: ANN001
    """A project whose dense/ holds a sparse model of 3 registered images (ids 2, 5, 9) and a fused cloud of n
    points on a wavy 2 m × 1.5 m surface at a UTM origin (sidecar), with colours, normals (20 unusable: PCA), 10
    exact duplicates, 3 isolated outliers and per-point visibility of 0 to 3 of the images."""
    layout = ProjectLayout(root)
    ws = DenseWorkspace(layout.dense)
    ws.make_dirs()
    cam = Camera.pinhole(50.0, 50.0, 32.0, 24.0, 64, 48)
    views = {i: View.from_matrix(i, f"v{i}.png", 1, np.c_[np.eye(3), [0.1 * i, 0.0, 2.0]]) for i in (2, 5, 9)}
    write_model(ws.sparse, Cameras({1: cam}, views))
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0, 0], [2, 1.5], (n, 2))
    pos = np.column_stack([xy, 0.1 * np.sin(3 * xy[:, 0]) + rng.normal(0, 0.002, n)])
    pos[50:60] = pos[70:80]
    pos[90:93, 2] += 2.0
    normals = rng.normal(size=(n, 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[200:220] = 0.0
    colors = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    write_ply(ws.fused_ply, PointCloud(pos, UTM, colors, normals))
    write_vis(ws.fused_vis, [rng.choice(3, rng.integers(0, 4), replace=False) for _ in range(n)])
    return layout


def _convert(layout: ProjectLayout, **options) -> tuple[ConvertResult, bytes, bytes]:  # noqa: ANN003
    """Run the convert stage with these options; its result, the PLY's bytes and its origin sidecar's bytes."""
    config = ProjectConfig().with_stage_options("convert", ConvertStageOptions(**options))
    counts = ConvertStage().run(StageContext(layout=layout, config=config, source=None))  # type: ignore[arg-type]
    ply = layout.mvs_gaussians
    return counts, ply.read_bytes(), sidecar_path(ply).read_bytes()


@pytest.mark.parametrize("mode", ["adaptive", "paper"])
def test_memory_limit_gives_the_same_file_in_several_cells_and_records_limit_and_peak(tmp_path, monkeypatch, mode):
    layout = _project(tmp_path / "p")
    memory, ply, sidecar = _convert(layout, mode=mode)
    assert memory.memory_limit_mb is None and "memory_limit_mb" not in memory.as_dict()
    layout.mvs_gaussians.unlink()
    small = convert_stream.StreamPlan(600.0, 500, 1_999)  # 500 points a cell: ≥ 8 cells; chunks cut across cells
    monkeypatch.setattr(convert_stream, "plan_memory", lambda limit, k=8: small)
    streamed, ply_s, sidecar_s = _convert(layout, mode=mode, memory_limit_mb=600.0)
    assert ply_s == ply and sidecar_s == sidecar
    assert streamed.memory_limit_mb == 600.0 and streamed.peak_rss_mb > 0 and streamed.cells >= 8
    assert streamed.gaussians == memory.gaussians == 4_000
    assert streamed.median_spacing_m == pytest.approx(memory.median_spacing_m, rel=1e-12)
    assert not [p for p in layout.mvs_gaussians.parent.iterdir() if p.is_dir()]  # the cell files are gone
    assert "streamed in" in ConvertStage().summary(streamed)


def test_memory_limit_with_the_real_plan_gives_the_same_file(tmp_path):
    layout = _project(tmp_path / "p", n=1_500, seed=6)
    _, ply, _ = _convert(layout)
    layout.mvs_gaussians.unlink()
    streamed, ply_s, _ = _convert(layout, memory_limit_mb=1024.0)
    assert ply_s == ply and streamed.cells >= 1 and streamed.memory_limit_mb == 1024.0


def test_visibility_positions_are_checked_against_the_registered_images(tmp_path):
    from core.errors import FormatError

    layout = _project(tmp_path / "p", n=500)
    write_vis(layout.fused_vis, [np.array([0, 3])] * 500)  # position 3 of 3 registered images
    with pytest.raises(FormatError, match="out of range"):
        _convert(layout, memory_limit_mb=1024.0)


def test_too_small_memory_limit_is_one_config_error_line(tmp_path, capsys):
    from hybridsplat.cli import main

    try:
        main(["run", str(tmp_path / "photos"), "--out", str(tmp_path / "p"), "--memory-limit", "100"])
        code = 0
    except SystemExit as ex:
        code = int(ex.code or 0)
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if line.startswith("hybridsplat: error:")]
    assert code != 0 and "Traceback" not in err, err
    assert len(lines) == 1 and "memory_limit_mb = 100 is too small" in lines[0], err
    assert not (tmp_path / "p").exists()
