"""Strecha ``.camera`` reader: our Camera/View reproduce x = K·[Rᵀ | −Rᵀ·C]·X (the format's definition)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.cameras import Camera, Cameras, View
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
    import os

    data = Path(os.environ.get("HYBRIDSPLAT_SHARED_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data")
    folder = data / "real" / "fountain-P11" / "gt_dense_cameras"
    if not folder.is_dir():
        pytest.skip(f"{folder} is absent")
    cams = read_strecha_cameras(folder)
    assert len(cams) == 11
    assert all((c.width, c.height) == (3072, 2048) for c in cams.cameras.values())


# -- reference camera centres (--reference) and units -------------------------------------------------------------
def test_units_convert_and_format():
    from core.errors import ConfigError
    from core.units import Units

    assert Units.parse("MM") is Units.MM and Units.parse("feet") is Units.FT and Units.parse(Units.CM) is Units.CM
    assert Units.FT.to_metres(10.0) == pytest.approx(3.048, abs=1e-15)  # international foot, exact
    assert Units.MM.from_metres(0.0123) == pytest.approx(12.3, abs=1e-12)
    assert Units.MM.format(0.00123) == "1.23 mm" and Units.M.format(0.00123) == "0.00123 m"
    assert Units.CM.format(12.3456) == "1235 cm"  # large values keep their integer digits
    assert Units.M.format(0.0) == "0 m" and Units.M.format(float("nan")) == "n/a"
    with pytest.raises(ConfigError, match="unknown length unit 'yd'"):
        Units.parse("yd")


def test_reference_text_in_millimetres_is_read_in_metres(tmp_path: Path):
    from recon.reference import ReferenceKind, Units, read_reference

    path = tmp_path / "ref.txt"
    path.write_text(
        "# GNSS camera centres\n\n"
        "0000.jpg 500000123.5 5400000456.25 312125.0\n"
        "my photo 1.jpg  -1.5\t2e3 0   # trailing comment\n"
    )
    ref = read_reference(path, "mm")
    assert ref.kind is ReferenceKind.TEXT and ref.units is Units.MM
    assert ref.names == ("0000.jpg", "my photo 1.jpg")
    # float64 keeps the 0.1 mm digits of a 500 km coordinate: 500000123.5 mm = 500000.1235 m
    np.testing.assert_array_equal(ref.centers["0000.jpg"], np.array([500000123.5, 5400000456.25, 312125.0]) * 1e-3)
    np.testing.assert_allclose(ref.centers["my photo 1.jpg"], [-0.0015, 2.0, 0.0], atol=0, rtol=1e-15)
    assert ref.centers["0000.jpg"].dtype == np.float64


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("a.jpg 1 2 3\nb.jpg 1 2\n", "line 2: expected 'NAME X Y Z'"),
        ("a.jpg 1 2 3\n\nb.jpg 1 x 3\n", "line 3: coordinates must be numbers"),
        ("a.jpg 1 nan 3\n", "line 1: coordinates must be finite"),
        ("a.jpg 1 2 3\na.jpg 4 5 6\n", "line 2: image 'a.jpg' is listed twice \\(first on line 1\\)"),
        ("# only a comment\n\n", "holds no 'NAME X Y Z' line"),
    ],
)
def test_reference_text_errors_name_the_line(tmp_path: Path, content: str, message: str):
    from recon.reference import read_reference

    path = tmp_path / "ref.txt"
    path.write_text(content)
    with pytest.raises(FormatError, match=message) as err:
        read_reference(path)
    assert err.value.path == path


def test_reference_missing_and_bad_unit(tmp_path: Path):
    from core.errors import ConfigError, InputFileError
    from recon.reference import read_reference

    with pytest.raises(InputFileError, match="does not exist"):
        read_reference(tmp_path / "nothing.txt")
    (tmp_path / "r.txt").write_text("a 1 2 3\n")
    with pytest.raises(ConfigError, match="unit"):
        read_reference(tmp_path / "r.txt", "inch")


def test_reference_from_colmap_model_and_text_round_trip(tmp_path: Path):
    """A COLMAP model's centres equal the defining C of the cameras; written as text in ft and read back."""
    from scipy.spatial.transform import Rotation

    from core.io.colmap import write_model
    from recon.reference import ReferenceKind, read_reference, write_reference_text

    rng = np.random.default_rng(4)
    cam = Camera.pinhole(500.0, 500.0, 320.0, 240.0, 640, 480, 1)
    centers = rng.normal(scale=10.0, size=(5, 3))
    views = {}
    for i, C in enumerate(centers, start=1):
        Rcw = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
        views[i] = View.from_matrix(i, f"{i:03d}.png", 1, np.c_[Rcw, -Rcw @ C])
    write_model(tmp_path / "model", Cameras({1: cam}, views))
    ref = read_reference(tmp_path / "model")
    assert ref.kind is ReferenceKind.MODEL and ref.names == tuple(f"{i:03d}.png" for i in range(1, 6))
    np.testing.assert_allclose(ref.positions(ref.names), centers, atol=1e-9)
    in_cm = read_reference(tmp_path / "model", "cm")  # a model in centimetres: metres = cm / 100
    np.testing.assert_allclose(in_cm.positions(in_cm.names), centers / 100, atol=1e-11)
    write_reference_text(tmp_path / "ref_ft.txt", ref.centers, "ft")
    back = read_reference(tmp_path / "ref_ft.txt", "ft")
    np.testing.assert_allclose(back.positions(back.names), centers, atol=1e-12)
    assert back.extent_m() == pytest.approx(float(np.linalg.norm(centers.max(0) - centers.min(0))))


def test_align_to_a_georeferenced_reference_in_millimetres(tmp_path: Path):
    """SfM-like model (arbitrary frame and scale) + GNSS centres in mm at UTM coordinates → aligned in a local
    frame whose origin restores the UTM coordinates to 1e-6 m; a wrong centre (0.5 m off) is an outlier."""
    from scipy.spatial.transform import Rotation

    from recon.align import Similarity, align_to_reference
    from recon.model import to_reconstruction
    from recon.reference import read_reference, write_reference_text

    rng = np.random.default_rng(8)
    utm = np.array([512_345.678, 5_401_234.567, 412.345])
    true_centers = utm + rng.uniform(-40, 40, (12, 3)) * [1, 1, 0.1]  # a 80 m block of GNSS-tagged photos
    to_model = Similarity(0.05, Rotation.random(random_state=3).as_matrix(), np.array([1.0, -2.0, 0.5]))
    model_centers = to_model.apply(true_centers - utm)  # what SfM would give: its own frame and scale
    cams = Cameras({1: Camera.pinhole(500.0, 500.0, 320.0, 240.0, 640, 480, 1)}, {})
    for i, c in enumerate(model_centers, start=1):
        R = Rotation.random(random_state=100 + i).as_matrix()
        cams.views[i] = View.from_matrix(i, f"{i:04d}.jpg", 1, np.c_[R, -R @ c])
    rec = to_reconstruction(cams)
    reported = {f"{i:04d}.jpg": c.copy() for i, c in enumerate(true_centers, start=1)}
    reported["0005.jpg"] = reported["0005.jpg"] + [0.5, 0.0, 0.0]  # one bad GNSS fix
    write_reference_text(tmp_path / "gnss_mm.txt", reported, "mm")
    ref = read_reference(tmp_path / "gnss_mm.txt", "mm")
    aligned = align_to_reference(rec, ref.centers, threshold_m=0.1)
    np.testing.assert_array_equal(aligned.origin, np.round(true_centers[:, :].mean(axis=0)))
    assert aligned.result.num_inliers == 11 and not aligned.result.inliers[4]
    got = np.stack([np.asarray(rec.image(i).projection_center()) for i in range(1, 13)]) + aligned.origin
    np.testing.assert_allclose(got, true_centers, atol=1e-6, rtol=0)
    assert aligned.result.residuals[4] == pytest.approx(0.5, abs=1e-6)


def test_read_reference_centers_needs_three(tmp_path: Path):
    from core.units import Units
    from recon.reference import read_reference_centers

    (tmp_path / "r.txt").write_text("a 1 2 3\nb 4 5 6\n")
    with pytest.raises(FormatError, match="at least 3 camera centres"):
        read_reference_centers(tmp_path / "r.txt")
    (tmp_path / "r.txt").write_text("a 1000 2000 3000\nb 4 5 6\nc 7 8 9\n")
    centers = read_reference_centers(tmp_path / "r.txt", "mm")
    np.testing.assert_allclose(centers["a"], [1.0, 2.0, 3.0], rtol=1e-15)
    assert Units.parse("ft").metres == 0.3048
