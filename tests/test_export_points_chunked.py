"""Survey point exports in chunks (issue 34): fusion.export_stream writes the bytes fusion.export.export_points
writes whole (the truth here), for PLY (with its origin sidecar), LAS and LAZ, with and without a CRS, with chunks
cut across the filters and an int64 field that fits int32 in one chunk but not in another."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import ConfigError
from core.gaussians import GaussianSet
from core.io.origin import sidecar_path
from fusion.export import ExportOptions, export_points
from fusion.export_stream import export_chunk_points

UTM = np.array([500_000.0, 5_200_000.0, 300.0])


def _gaussians(n: int = 2_500, seed: int = 3) -> GaussianSet:
    rng = np.random.default_rng(seed)
    ids = rng.integers(0, 1_000, n).astype(np.int64)
    ids[-5:] = 2**40  # float64 in PLY for the whole cloud, though the first chunks fit int32
    fields = {"source": rng.integers(0, 4, n).astype(np.uint8), "classification": rng.integers(0, 3, n),
              "tile": ids, "weight": rng.random(n).astype(np.float32)}  # fmt: skip
    return GaussianSet(
        rng.uniform(-50, 50, (n, 3)), rng.normal(-3, 0.5, (n, 3)), rng.normal(size=(n, 4)),
        rng.normal(0, 3, n), rng.normal(size=(n, 3)), rng.normal(0, 0.1, (n, 3, 3)), UTM, fields,
    )  # fmt: skip


@pytest.mark.parametrize("suffix", [".ply", ".las", ".laz"])
@pytest.mark.parametrize("crs", [None, "EPSG:32632"])
def test_chunked_point_exports_are_byte_identical(tmp_path, suffix, crs):
    gaussians = _gaussians()
    options = ExportOptions(crop_min=tuple(UTM - 40), crop_max=tuple(UTM + 45), min_opacity=0.1, crs=crs)
    whole = export_points(tmp_path / f"whole{suffix}", gaussians, options)
    chunked = export_points(tmp_path / f"chunked{suffix}", gaussians, options, chunk=333)
    assert chunked == whole.__class__(**{**whole.__dict__, "path": chunked.path}) and whole.num_written > 1_000
    assert (tmp_path / f"chunked{suffix}").read_bytes() == (tmp_path / f"whole{suffix}").read_bytes()
    side_w, side_c = sidecar_path(tmp_path / f"whole{suffix}"), sidecar_path(tmp_path / f"chunked{suffix}")
    assert side_w.is_file() == side_c.is_file()
    if side_w.is_file():
        assert side_c.read_bytes() == side_w.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(  # nothing temporary left behind
        [p.name.replace("whole", "chunked") for p in tmp_path.iterdir() if "whole" in p.name]
        + [p.name for p in tmp_path.iterdir() if "whole" in p.name]
    )


def test_the_chunk_follows_the_limit_and_too_little_is_refused():
    assert export_chunk_points(1024) > export_chunk_points(600) >= 1000
    with pytest.raises(ConfigError, match="memory_limit_mb = 100 is too small for the chunked point export"):
        export_chunk_points(100)


def test_the_export_command_with_a_memory_limit_writes_the_same_files(tmp_path, monkeypatch):
    import fusion.export_stream as export_stream
    from core.io.gaussian_ply import write_gaussian_ply
    from hybridsplat.cli import main

    source = tmp_path / "g.ply"
    write_gaussian_ply(source, _gaussians(), extra_fields=True)
    outs = {}
    for name, limit in (("whole", []), ("chunked", ["--memory-limit", "1024"])):
        monkeypatch.setattr(export_stream, "export_chunk_points", lambda limit: 401)  # several chunks
        folder = tmp_path / name
        folder.mkdir()
        args = ["export", str(source), "--points", "--out", str(folder / "p.ply"), "--out", str(folder / "p.laz")]
        try:
            main([*args, *limit])
        except SystemExit as ex:
            assert not ex.code
        outs[name] = {p.name: p.read_bytes() for p in sorted(folder.iterdir())}
    assert outs["chunked"] == outs["whole"] and {"p.ply", "p.laz"} <= set(outs["whole"])


@pytest.mark.parametrize("crs", [None, "EPSG:32632"])
def test_the_merge_stage_with_a_memory_limit_writes_the_same_survey_points(tmp_path, monkeypatch, crs):
    """merged_points.ply (+ sidecar) and .las of the merge stage (the converted MVS set alone: no splats) with
    ``memory_limit_mb`` equal those without, and the stage records the limit only when given."""
    import fusion.export_stream as export_stream
    from core.io.gaussian_ply import write_gaussian_ply
    from fusion.merge_options import MergeOptions
    from hybridsplat.config import InputOptions, ProjectConfig
    from hybridsplat.layout import ProjectLayout
    from hybridsplat.stages.base import StageContext
    from hybridsplat.stages.merge import MergeStage

    monkeypatch.setattr(export_stream, "export_chunk_points", lambda limit: 377)
    files = {}
    for name, limit in (("whole", None), ("chunked", 1024.0)):
        layout = ProjectLayout(tmp_path / name)
        layout.mvs_gaussians.parent.mkdir(parents=True)
        write_gaussian_ply(layout.mvs_gaussians, _gaussians(), extra_fields=True)
        config = ProjectConfig(input=InputOptions(crs=crs)).with_stage_options(
            "merge", MergeOptions(memory_limit_mb=limit)
        )
        counts = MergeStage().run(StageContext(layout=layout, config=config, source=None))  # type: ignore[arg-type]
        assert counts.memory_limit_mb == limit
        paths = (layout.merged_points_ply, layout.merged_points_las, sidecar_path(layout.merged_points_ply))
        files[name] = [p.read_bytes() for p in paths]
    assert files["chunked"] == files["whole"]
