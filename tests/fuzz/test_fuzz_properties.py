"""Hypothesis properties of the readers, in-process: whatever bytes a file holds (valid files truncated
anywhere, bytes flipped, counts overwritten), a reader either returns a valid object or raises one of the
toolkit's errors naming that file — never another exception, never NaN/inf in what it returns."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core.errors import HybridSplatError
from fuzz.cases import cloud_ply, colmap_model, gaussian_ply, las_file

SETTINGS = settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture], derandomize=True
)


@pytest.fixture(scope="module")
def bases(tmp_path_factory) -> dict[str, bytes]:
    d = tmp_path_factory.mktemp("bases")
    model = colmap_model(d / "sparse")
    out = {
        "cloud.ply": cloud_ply(d / "c.ply").read_bytes(),
        "ascii.ply": cloud_ply(d / "a.ply", binary=False).read_bytes(),
        "gs.ply": gaussian_ply(d / "g.ply").read_bytes(),
        "cloud.las": las_file(d / "c.las").read_bytes(),
        "cloud.laz": las_file(d / "c.laz", n=500).read_bytes(),
    }
    for name in ("cameras", "images", "points3D", "rigs", "frames"):
        out[f"{name}.bin"] = (model / f"{name}.bin").read_bytes()
    return out


def _mutate(data: bytes, cut: int, flips: list[tuple[int, int]]) -> bytes:
    b = bytearray(data[: min(cut, len(data))])
    for pos, value in flips:
        if b:
            b[pos % len(b)] = value
    return bytes(b)


mutations = st.tuples(
    st.integers(0, 1 << 16), st.lists(st.tuples(st.integers(0, 1 << 16), st.integers(0, 255)), max_size=4)
)


def _check_reader(read, path: Path) -> object | None:
    try:
        result = read(path)
    except HybridSplatError as err:
        assert err.path is not None and err.path.name == path.name or path.name in str(err), str(err)
        assert "\n" not in err.one_line()
        return None
    return result


@pytest.mark.parametrize("name", ["cloud.ply", "ascii.ply", "cloud.las", "cloud.laz"])
@SETTINGS
@given(m=mutations)
def test_point_cloud_readers_fail_cleanly(bases, tmp_path, name, m) -> None:
    from core.io import read_point_cloud

    path = tmp_path / name
    path.write_bytes(_mutate(bases[name], *m))
    cloud = _check_reader(read_point_cloud, path)
    if cloud is not None:
        assert np.isfinite(cloud.positions).all() and np.isfinite(cloud.origin).all()


@SETTINGS
@given(m=mutations)
def test_gaussian_reader_fails_cleanly(bases, tmp_path, m) -> None:
    from core.io.gaussian_ply import read_gaussian_ply

    path = tmp_path / "gs.ply"
    path.write_bytes(_mutate(bases["gs.ply"], *m))
    gs = _check_reader(read_gaussian_ply, path)
    if gs is not None:
        for values in (gs.means, gs.log_scales, gs.quats, gs.logit_opacities, gs.sh_dc):
            assert np.isfinite(values).all()


@pytest.mark.parametrize("name", ["cameras", "images", "points3D", "rigs", "frames"])
@SETTINGS
@given(m=mutations)
def test_colmap_reader_fails_cleanly(bases, tmp_path, name, m) -> None:
    from core.io.colmap import read_model

    folder = tmp_path / "model"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    for key, data in bases.items():
        if key.endswith(".bin"):
            (folder / key).write_bytes(data)
    (folder / f"{name}.bin").write_bytes(_mutate(bases[f"{name}.bin"], *m))
    try:
        cameras, points = read_model(folder)
    except HybridSplatError as err:
        assert "\n" not in err.one_line()
        return
    for cam in cameras.cameras.values():
        assert np.isfinite(cam.params).all() and cam.params[0] > 0
    assert np.isfinite(points.positions).all()


@SETTINGS
@given(
    count=st.integers(0, 2**64 - 1),
    words=st.lists(st.integers(0, 2**32 - 1), max_size=12),
    tail=st.binary(max_size=3),
)
def test_vis_reader_fails_cleanly(tmp_path, count, words, tail) -> None:
    from core.io.colmap_vis import read_vis

    path = tmp_path / "fused.ply.vis"
    path.write_bytes(struct.pack("<Q", count) + np.asarray(words, "<u4").tobytes() + tail)
    vis = _check_reader(read_vis, path)
    if vis is not None:
        assert len(vis) == count and sum(len(v) + 1 for v in vis) == len(words)


@SETTINGS
@given(text=st.text(max_size=60))
def test_json_reader_fails_cleanly(tmp_path, text) -> None:
    import json

    from core.io.json_io import read_json

    path = tmp_path / "x.json"
    path.write_text(text, encoding="utf-8")
    data = _check_reader(read_json, path)
    if data is not None or text.strip() == "null":
        json.dumps(data, allow_nan=False)  # raises ValueError on NaN/inf: the reader returns strict JSON only
