"""`hybridsplat convert` and `hybridsplat merge` end to end on small files (in-process)."""

from __future__ import annotations

import numpy as np
import plyfile
import pytest

from core.io.gaussian_ply import read_gaussian_ply
from core.io.ply import write_ply
from core.pointcloud import PointCloud
from hybridsplat.cli import main


def _cloud(tmp_path, n=500, with_vis=False):
    rng = np.random.default_rng(4)
    world = np.c_[rng.random((n, 2)) * 2, np.zeros(n)] + [300000.0, 4100000.0, 50.0]
    cloud = PointCloud.from_world(
        world, colors=rng.integers(0, 256, (n, 3)), fields={"classification": (np.arange(n) % 2).astype(np.uint8)}
    )
    path = tmp_path / "fused.ply"
    write_ply(path, cloud)
    if with_vis:
        counts = np.arange(n) % 3 + 1
        words = [np.uint64(n).tobytes()]
        for c in counts:
            words.append(np.concatenate([[c], np.arange(c)]).astype("<u4").tobytes())
        (tmp_path / "fused.ply.vis").write_bytes(b"".join(words))
    return path, cloud


def _run(argv):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    return exc.value.code


def test_convert_cli_writes_ply_and_splat(tmp_path, capsys):
    path, cloud = _cloud(tmp_path, with_vis=True)
    for mode in ("paper", "adaptive"):
        out = tmp_path / f"{mode}.ply"
        try:
            main(["convert", str(path), "--mode", mode, "--out", str(out), "--min-opacity", "0"])
        except SystemExit as e:  # typer may exit 0
            assert e.code in (0, None)
        gs = read_gaussian_ply(out)
        assert len(gs) == len(cloud)
        np.testing.assert_allclose(gs.world_means, cloud.world_positions, atol=1e-3)
    adaptive = read_gaussian_ply(tmp_path / "adaptive.ply")
    views = np.arange(len(cloud)) % 3 + 1  # the .vis next to the cloud drives the adaptive opacity
    for k in (1, 2, 3):
        assert np.ptp(adaptive.opacities[views == k]) < 0.05
    assert adaptive.opacities[views == 1].mean() < adaptive.opacities[views == 3].mean()
    try:
        main(["convert", str(path), "--out", str(tmp_path / "p.splat")])
    except SystemExit as e:
        assert e.code in (0, None)
    assert (tmp_path / "p.splat").stat().st_size == 32 * len(cloud)
    assert "converted" in capsys.readouterr().out


def test_merge_cli_drops_classes_and_writes_points(tmp_path):
    path, cloud = _cloud(tmp_path)
    try:
        main(["convert", str(path), "--mode", "adaptive", "--out", str(tmp_path / "mvs.ply")])
        main(
            [
                "merge",
                "--mvs",
                str(path),
                "--splats",
                str(tmp_path / "mvs.ply"),
                "--drop-class",
                "1",
                "--prefer",
                "mvs",
                "--out",
                str(tmp_path / "merged.ply"),
                "--points-out",
                str(tmp_path / "merged_points.ply"),
            ]
        )
    except SystemExit as e:
        assert e.code in (0, None)
    merged = read_gaussian_ply(tmp_path / "merged.ply")
    # class-0 MVS points (half) are kept and win over the coincident splats; class-1 positions come from splats
    assert len(merged) == len(cloud)
    d = plyfile.PlyData.read(str(tmp_path / "merged_points.ply"))["vertex"].data
    assert sorted(np.unique(d["source"]).tolist()) == [1, 2]
    assert (d["source"] == 1).sum() == (cloud.fields["classification"] == 0).sum()


def test_cli_errors_are_one_line_exit_2(tmp_path, capsys):
    assert _run(["convert", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "x.ply")]) == 2
    err = capsys.readouterr().err
    assert "missing.ply" in err and len(err.strip().splitlines()) == 1
    path, _ = _cloud(tmp_path)
    assert _run(["convert", str(path), "--out", str(tmp_path / "x.obj")]) == 2
    assert _run(["convert", str(path), "--out", str(tmp_path / "x.ply"), "--crop-min", "0", "0", "0"]) == 2
    assert _run(["convert", str(path), "--out", str(tmp_path / "x.ply"), "--visibility", str(tmp_path / "no.vis")]) == 2
    (tmp_path / "short.vis").write_bytes(np.uint64(len(path.read_bytes())).tobytes())  # wrong count
    assert (
        _run(["convert", str(path), "--out", str(tmp_path / "x.ply"), "--visibility", str(tmp_path / "short.vis")]) == 2
    )
    assert not (tmp_path / "x.obj").exists() and not (tmp_path / "x.ply").exists()


def test_export_cli_crops_and_writes_points(tmp_path):
    path, cloud = _cloud(tmp_path)
    try:
        main(["convert", str(path), "--mode", "adaptive", "--out", str(tmp_path / "g.ply")])
        main(
            [
                "export",
                str(tmp_path / "g.ply"),
                "-o",
                str(tmp_path / "c.splat"),
                "-o",
                str(tmp_path / "c_points.ply"),
                "--points",
                "--crop-min",
                "300000",
                "4100000",
                "0",
                "--crop-max",
                "300001",
                "4100001",
                "100",
            ]
        )
    except SystemExit as e:
        assert e.code in (0, None)
    world = cloud.world_positions
    inside = int(np.all((world[:, :2] >= [300000, 4100000]) & (world[:, :2] <= [300001, 4100001]), axis=1).sum())
    assert (tmp_path / "c.splat").stat().st_size == 32 * inside
    d = plyfile.PlyData.read(str(tmp_path / "c_points.ply"))["vertex"].data
    assert len(d) == inside and "source" in d.dtype.names and "classification" in d.dtype.names
