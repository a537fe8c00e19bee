"""The shared JSON writer/reader and the one ``fused.ply.vis`` reader/writer."""

from __future__ import annotations

import dataclasses
import enum
import json
from pathlib import Path

import numpy as np
import pytest

from core.errors import FormatError, InputFileError
from core.io import colmap_vis
from core.io.json_io import read_json, to_jsonable, write_json_atomic


class Mode(enum.Enum):
    A = "a"


@dataclasses.dataclass(frozen=True)
class Rec:
    x: float
    p: Path
    m: Mode


def test_to_jsonable_converts_and_nulls_non_finite(tmp_path: Path) -> None:
    obj = {
        "nan": float("nan"),
        "inf": np.float32(np.inf),
        "arr": np.array([1.0, np.nan, -np.inf]),
        "i": np.int64(7),
        "rec": Rec(2.5, Path("/a/b"), Mode.A),
        1: (np.bool_(True),),
    }
    got = to_jsonable(obj)
    assert got == {
        "nan": None,
        "inf": None,
        "arr": [1.0, None, None],
        "i": 7,
        "rec": {"x": 2.5, "p": "/a/b", "m": "a"},
        "1": [True],
    }
    path = write_json_atomic(tmp_path / "o.json", obj)
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == got  # strict JSON, same data
    assert read_json(path) == got


def test_to_jsonable_refuses_unknown_types() -> None:
    with pytest.raises(TypeError, match="object"):
        to_jsonable(object())


@pytest.mark.parametrize(
    ("content", "match"),
    [(b"{", "not valid JSON"), (b'{"a": NaN}', "NaN"), (b"\xff\xfe", "UTF-8"), (b"", "not valid JSON")],
)
def test_read_json_bad_content_names_file(tmp_path: Path, content: bytes, match: str) -> None:
    path = tmp_path / "bad.json"
    path.write_bytes(content)
    with pytest.raises(FormatError, match=match) as info:
        read_json(path)
    assert info.value.path == path


def test_read_json_folder_and_missing(tmp_path: Path) -> None:
    with pytest.raises(InputFileError, match="folder"):
        read_json(tmp_path)
    with pytest.raises(InputFileError, match="does not exist"):
        read_json(tmp_path / "none.json")


def _vis_bytes(vis: list[list[int]]) -> bytes:
    """An independent writer of the documented layout, for the reader's tests."""
    out = np.array([len(vis)], "<u8").tobytes()
    for v in vis:
        out += np.array([len(v), *v], "<u4").tobytes()
    return out


def test_vis_round_trip_and_layout(tmp_path: Path) -> None:
    vis = [[0, 2], [], [1]]
    path = tmp_path / "fused.ply.vis"
    colmap_vis.write_vis(path, [np.array(v) for v in vis])
    assert path.read_bytes() == _vis_bytes(vis)
    got = colmap_vis.read_vis(path, num_points=3, num_images=3)
    assert [v.tolist() for v in got] == vis
    assert all(v.dtype == np.int64 for v in got)
    ids = colmap_vis.positions_to_image_ids(got, [7, 3, 9])
    assert [v.tolist() for v in ids] == [[3, 9], [], [7]]


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (b"", "truncated"),
        (b"\x01\x00\x00", "truncated"),
        (_vis_bytes([[0, 1], [2]])[:-4], "truncated in point 1"),
        (_vis_bytes([[0]]) + b"\x00\x00\x00\x00", "after its 1 points"),
        (np.array([2**40], "<u8").tobytes() + b"\x00" * 8, "declares 1099511627776 points"),
        (_vis_bytes([[0]]) + b"\x00", "multiple of 4"),
        (np.array([1], "<u8").tobytes() + np.array([2**31], "<u4").tobytes(), "truncated in point 0"),
    ],
)
def test_vis_malformed(tmp_path: Path, data: bytes, match: str) -> None:
    path = tmp_path / "x.vis"
    path.write_bytes(data)
    with pytest.raises(FormatError, match=match) as info:
        colmap_vis.read_vis(path)
    assert info.value.path == path


def test_vis_counts_checked(tmp_path: Path) -> None:
    path = tmp_path / "x.vis"
    path.write_bytes(_vis_bytes([[0, 5]]))
    with pytest.raises(FormatError, match="the cloud has 2"):
        colmap_vis.read_vis(path, num_points=2)
    with pytest.raises(FormatError, match="out of range for the 3"):
        colmap_vis.read_vis(path, num_images=3)
    with pytest.raises(InputFileError, match="folder"):
        colmap_vis.read_vis(tmp_path)


def test_recon_workspace_wraps_core_reader(tmp_path: Path) -> None:
    from recon import workspace

    path = tmp_path / "fused.ply.vis"
    workspace.write_vis(path, [np.array([1, 0])])
    assert [v.tolist() for v in workspace.read_vis(path, 1)] == [[1, 0]]
    path.write_bytes(_vis_bytes([[0]])[:-2])
    with pytest.raises(FormatError):
        workspace.read_vis(path)
