"""recon.inputs: what INPUT is (photos, images/ one level down, COLMAP workspace, data_synth scene) and holdout."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from core.cameras import Camera, Cameras, View
from core.errors import ConfigError, FormatError, InputFileError
from core.io.colmap import write_model
from recon.inputs import InputKind, choose_holdout, resolve_input, select_holdout


def _touch_photos(folder: Path, names: list[str]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for n in names:
        (folder / n).write_bytes(b"x")  # content is not read by resolve_input


def _model(folder: Path, n: int, binary: bool = True) -> None:
    cam = Camera.pinhole(100.0, 100.0, 50.0, 40.0, 100, 80, 1)
    views = {i: View.from_matrix(i, f"{i:04d}.jpg", 1, np.c_[np.eye(3), [0.0, 0.0, float(i)]]) for i in range(1, n + 1)}
    write_model(folder, Cameras({1: cam}, views), binary=binary)


def test_photos_directly_sorted_case_insensitive(tmp_path: Path):
    _touch_photos(tmp_path, ["b.JPG", "a.jpeg", "c.Png", "notes.txt", "d.tif"])
    (tmp_path / "sub").mkdir()
    _touch_photos(tmp_path / "sub", ["z.jpg"])  # sub-folders are not searched
    spec = resolve_input(tmp_path)
    assert spec.kind is InputKind.PHOTOS and spec.image_dir == tmp_path
    assert spec.image_names == ("a.jpeg", "b.JPG", "c.Png", "d.tif")
    assert spec.known_cameras is None and spec.test_names == () and spec.reference_cloud is None


def test_photos_one_level_down_in_images(tmp_path: Path):
    _touch_photos(tmp_path / "images", ["0001.jpg", "0000.jpg"])
    spec = resolve_input(tmp_path)
    assert spec.kind is InputKind.PHOTOS and spec.image_dir == tmp_path / "images"
    assert spec.image_names == ("0000.jpg", "0001.jpg")


def test_no_photos_and_bad_folders(tmp_path: Path):
    (tmp_path / "images").mkdir()
    (tmp_path / "readme.txt").write_text("x")
    with pytest.raises(InputFileError, match="found no photos here nor in its images/ folder") as err:
        resolve_input(tmp_path)
    assert err.value.path == tmp_path
    with pytest.raises(InputFileError, match="does not exist"):
        resolve_input(tmp_path / "missing")
    with pytest.raises(InputFileError, match="not a folder"):
        resolve_input(tmp_path / "readme.txt")
    with pytest.raises(ConfigError, match="model 2"):
        _touch_photos(tmp_path, ["a.jpg"])
        resolve_input(tmp_path, model=2)


def test_unreadable_folder(tmp_path: Path, monkeypatch):
    folder = tmp_path / "locked"
    folder.mkdir()
    real_iterdir = Path.iterdir

    def iterdir(self):  # chmod 0 does not stop root, so the refusal is simulated
        if self == folder:
            raise PermissionError(13, "Permission denied")
        return real_iterdir(self)

    monkeypatch.setattr(Path, "iterdir", iterdir)
    with pytest.raises(InputFileError, match="cannot read the folder") as err:
        resolve_input(folder)
    assert err.value.path == folder


def test_colmap_workspace_picks_largest_model_or_the_asked_one(tmp_path: Path):
    _touch_photos(tmp_path / "images", ["0001.jpg", "0002.jpg", "0003.jpg"])
    _model(tmp_path / "sparse" / "0", 2)
    _model(tmp_path / "sparse" / "1", 3, binary=False)  # text model, larger
    _model(tmp_path / "sparse" / "2", 1)
    (tmp_path / "sparse" / "notes").mkdir()  # not a numbered model: ignored
    spec = resolve_input(tmp_path)
    assert spec.kind is InputKind.COLMAP and spec.image_dir == tmp_path / "images"
    assert spec.known_cameras == tmp_path / "sparse" / "1"
    assert [m.name for m in spec.models] == ["0", "1", "2"] and spec.dense_dir is None
    assert resolve_input(tmp_path, model=2).known_cameras == tmp_path / "sparse" / "2"
    with pytest.raises(InputFileError, match=r"model 7 does not exist \(models here: 0, 1, 2\)"):
        resolve_input(tmp_path, model=7)


def test_colmap_workspace_model_directly_in_sparse_with_dense(tmp_path: Path):
    _touch_photos(tmp_path / "images", ["0001.jpg"])
    _model(tmp_path / "sparse", 1)
    (tmp_path / "dense").mkdir()
    spec = resolve_input(tmp_path)
    assert spec.known_cameras == tmp_path / "sparse" and spec.dense_dir == tmp_path / "dense"
    assert resolve_input(tmp_path, model=0).known_cameras == tmp_path / "sparse"


def test_colmap_dense_only_workspace(tmp_path: Path):
    _touch_photos(tmp_path / "dense" / "images", ["0001.jpg", "0002.jpg"])
    _model(tmp_path / "dense" / "sparse", 2)
    spec = resolve_input(tmp_path)
    assert spec.kind is InputKind.COLMAP and spec.image_dir == tmp_path / "dense" / "images"
    assert spec.known_cameras == tmp_path / "dense" / "sparse"


def test_colmap_workspace_errors(tmp_path: Path):
    (tmp_path / "sparse" / "0").mkdir(parents=True)
    _touch_photos(tmp_path / "images", ["a.jpg"])
    with pytest.raises(InputFileError, match="no COLMAP model here"):
        resolve_input(tmp_path)
    _model(tmp_path / "sparse" / "0", 1)
    (tmp_path / "sparse" / "0" / "images.bin").write_bytes(b"\x01")
    with pytest.raises(FormatError, match="truncated"):
        resolve_input(tmp_path)


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory) -> Path:
    from data_synth import generate_scene

    return generate_scene("tiny", tmp_path_factory.mktemp("synth") / "tiny", seed=0)


def test_data_synth_scene(tiny_scene: Path):
    spec = resolve_input(tiny_scene)
    meta = json.loads((tiny_scene / "scene.json").read_text())
    assert spec.kind is InputKind.SYNTH
    assert list(spec.image_names) == sorted(meta["views"]["train"])
    assert list(spec.test_names) == sorted(meta["views"]["test"])
    assert spec.known_cameras == tiny_scene / "sparse" / "0"
    assert spec.test_model == tiny_scene / "sparse" / "test" and spec.test_photos == tiny_scene / "test"
    assert spec.reference_cloud == tiny_scene / "gt" / "lidar.ply"
    assert spec.test_labels == tiny_scene / "gt" / "labels" / "test"
    assert spec.train_labels == tiny_scene / "gt" / "labels" / "train" and spec.kind == "synthetic"
    assert spec.has_own_holdout and spec.scene_json == tiny_scene / "scene.json"
    assert spec.gsd_m == meta["gsd_m"] and spec.origin == tuple(meta["origin"])
    expected = tuple(m["id"] for m in meta["materials"] if not m["collaborative"])
    assert spec.non_collaborative_ids == expected and expected
    # the default holdout is the scene's own test views; an explicit N picks from the training photos
    hold = choose_holdout(spec)
    assert hold.source == "input" and hold.names == spec.test_names and hold.model == spec.test_model
    hold = choose_holdout(spec, 4)
    assert hold.source == "every" and hold.names == (spec.image_names[3], spec.image_names[7]) and hold.model is None
    assert choose_holdout(spec, 0).names == ()


def test_select_holdout_every_nth_in_name_order():
    names = [f"{i:04d}.jpg" for i in range(20)][::-1]  # order given does not matter
    assert select_holdout(names) == ("0007.jpg", "0015.jpg")
    assert select_holdout(names, 5) == ("0004.jpg", "0009.jpg", "0014.jpg", "0019.jpg")
    assert select_holdout(names, 0) == ()
    assert select_holdout(names[:7]) == ()  # fewer photos than N: none held out
    for bad in (-1, 1):
        with pytest.raises(ConfigError, match="holdout"):
            select_holdout(names, bad)


def test_choose_holdout_defaults_to_every_8th_for_photos(tmp_path: Path):
    _touch_photos(tmp_path, [f"{i:04d}.jpg" for i in range(11)])
    hold = choose_holdout(resolve_input(tmp_path))
    assert hold.names == ("0007.jpg",) and hold.source == "every" and hold.image_dir == tmp_path
    assert choose_holdout(resolve_input(tmp_path), 0).source == "none"
