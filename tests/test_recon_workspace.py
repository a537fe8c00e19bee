"""COLMAP dense-workspace files: map I/O against pycolmap's own reader/writer, .vis round trip, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.errors import FormatError, InputFileError
from recon.workspace import DenseWorkspace, read_array, read_vis, write_array, write_vis


def test_depth_map_round_trip_and_pycolmap_reads_it(tmp_path: Path):
    import pycolmap

    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 4.0, (7, 11)).astype(np.float32)
    path = tmp_path / "a.png.geometric.bin"
    write_array(path, depth)
    np.testing.assert_array_equal(read_array(path), depth)
    dm = pycolmap.DepthMap()
    dm.read(str(path))
    assert (dm.width, dm.height) == (11, 7)
    np.testing.assert_array_equal(dm.to_array(), depth)
    # and we read what pycolmap writes
    out = tmp_path / "b.bin"
    pycolmap.DepthMap.from_array(depth * 2, 0.0, 10.0).write(str(out))
    np.testing.assert_array_equal(read_array(out), depth * 2)


def test_normal_map_is_planar_on_disk(tmp_path: Path):
    """Channel planes one after another (what COLMAP reads), not interleaved triples."""
    n = np.zeros((2, 3, 3), np.float32)
    n[..., 0], n[..., 1], n[..., 2] = 1.0, 2.0, 3.0
    path = tmp_path / "n.bin"
    write_array(path, n)
    raw = path.read_bytes()
    header, payload = raw.split(b"&", 3)[:3], raw.split(b"&", 3)[3]
    assert header == [b"3", b"2", b"3"]
    vals = np.frombuffer(payload, "<f4")
    np.testing.assert_array_equal(vals, np.repeat([1.0, 2.0, 3.0], 6))
    np.testing.assert_array_equal(read_array(path), n)


@pytest.mark.parametrize("payload", [b"", b"abc", b"4&4&1&" + b"\0" * 10])
def test_corrupt_map_raises(tmp_path: Path, payload: bytes):
    path = tmp_path / "bad.bin"
    path.write_bytes(payload)
    with pytest.raises(FormatError):
        read_array(path)


def test_missing_map_raises(tmp_path: Path):
    with pytest.raises(InputFileError):
        read_array(tmp_path / "nope.bin")


def test_vis_round_trip_and_truncation(tmp_path: Path):
    vis = [np.array([0, 2, 5]), np.array([], dtype=np.int64), np.array([1])]
    path = tmp_path / "fused.ply.vis"
    write_vis(path, vis)
    back = read_vis(path, 3)
    assert [v.tolist() for v in back] == [[0, 2, 5], [], [1]]
    path.write_bytes(path.read_bytes()[:-4])
    with pytest.raises(FormatError):
        read_vis(path)


def test_workspace_paths_keep_extension(tmp_path: Path):
    ws = DenseWorkspace(tmp_path)
    assert ws.depth_map("img_000.png").name == "img_000.png.geometric.bin"
    assert ws.normal_map("x.jpg", "photometric").parent.name == "normal_maps"
