"""Strecha ``.camera`` reader: our Camera/View reproduce x = K·[Rᵀ | −Rᵀ·C]·X (the format's definition)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.errors import FormatError
from recon.reference import read_strecha_camera, read_strecha_cameras


def _write(path: Path, K, R, C, w=640, h=480) -> None:
    rows = [*K.tolist(), [0.0, 0.0, 0.0], *R.tolist(), C.tolist(), [w, h]]
    path.write_text("\n".join(" ".join(f"{v:.12g}" for v in r) for r in rows) + "\n")


def test_projection_matches_the_format_definition(tmp_path: Path):
    from scipy.spatial.transform import Rotation

    K = np.array([[500.0, 0, 320.5], [0, 510.0, 240.25], [0, 0, 1]])
    R = Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix()  # camera-to-world
    C = np.array([1.5, -2.0, 0.7])
    _write(tmp_path / "0000.jpg.camera", K, R, C)
    cam, view = read_strecha_camera(tmp_path / "0000.jpg.camera")
    assert view.name == "0000.jpg" and (cam.width, cam.height) == (640, 480)
    np.testing.assert_allclose(view.center, C, atol=1e-9)
    X = np.random.default_rng(0).normal(size=(20, 3)) + C + R @ np.array([0, 0, 5.0])
    P = K @ np.c_[R.T, -R.T @ C]
    x = (P @ np.c_[X, np.ones(20)].T).T
    expected = x[:, :2] / x[:, 2:]
    got = cam.project(view.world_to_camera(X))
    np.testing.assert_allclose(got, expected, atol=1e-8)
    assert len(read_strecha_cameras(tmp_path)) == 1


def test_bad_camera_file(tmp_path: Path):
    (tmp_path / "x.camera").write_text("1 2 3\nnot numbers\n")
    with pytest.raises(FormatError):
        read_strecha_camera(tmp_path / "x.camera")


def test_fountain_ground_truth_files_parse():
    folder = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "fountain-P11" / "gt_dense_cameras"
    if not folder.is_dir():
        pytest.skip(f"{folder} is absent")
    cams = read_strecha_cameras(folder)
    assert len(cams) == 11
    assert all((c.width, c.height) == (3072, 2048) for c in cams.cameras.values())
