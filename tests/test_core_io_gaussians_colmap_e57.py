"""3DGS PLY, COLMAP models and E57: round trips, files written independently, bad input."""

import json

import numpy as np
import plyfile
import pycolmap
import pytest

from core import Camera, Cameras, DataError, FormatError, GaussianSet, InputFileError, PointCloud, View
from core.io.colmap import from_reconstruction, read_model, write_model
from core.io.e57 import read_e57
from core.io.gaussian_ply import gaussian_property_names, read_gaussian_ply, write_gaussian_ply

UTM = np.array([500_000.25, 5_000_000.75, 250.0])


def _gaussians(n=40, degree=3, origin=UTM, seed=0):
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1
    return GaussianSet(
        rng.uniform(-30, 30, (n, 3)),
        rng.normal(size=(n, 3)) - 3,
        rng.normal(size=(n, 4)),
        rng.normal(size=n),
        rng.normal(size=(n, 3)),
        rng.normal(size=(n, k, 3)),
        origin=origin,
    )


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_gaussian_ply_property_order_and_round_trip(tmp_path, degree):
    gs = _gaussians(degree=degree)
    path = tmp_path / "splats.ply"
    write_gaussian_ply(path, gs)
    ply = plyfile.PlyData.read(str(path))
    assert ply.header.splitlines()[1] == "format binary_little_endian 1.0"
    props = ply["vertex"].properties
    n_rest = 3 * ((degree + 1) ** 2 - 1)
    expected = (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(n_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )
    assert [p.name for p in props] == expected == gaussian_property_names(degree)
    assert all(p.val_dtype in ("f4", "float32", "float") for p in props)
    back = read_gaussian_ply(path)
    np.testing.assert_allclose(back.world_means, gs.world_means, atol=1e-3, rtol=0)
    for attr in ("log_scales", "quats", "logit_opacities", "sh_dc", "sh_rest"):
        np.testing.assert_array_equal(getattr(back, attr), getattr(gs, attr))
    assert np.abs(np.asarray(ply["vertex"]["x"])).max() < 100  # payload local
    assert json.loads((tmp_path / "splats.origin.json").read_text())["origin"] == list(UTM)


def test_f_rest_is_channel_major_in_the_file(tmp_path):
    gs = _gaussians(n=3, degree=1, origin=np.zeros(3))
    gs.sh_rest[:] = 0
    gs.sh_rest[:, 0, 1] = 7.0  # first rest coefficient of the green channel
    write_gaussian_ply(tmp_path / "g.ply", gs)
    v = plyfile.PlyData.read(str(tmp_path / "g.ply"))["vertex"]
    # channel-major: R coefficients f_rest_0..2, G f_rest_3..5, B f_rest_6..8
    assert (np.asarray(v["f_rest_3"]) == 7.0).all()
    assert all((np.asarray(v[f"f_rest_{i}"]) == 0).all() for i in range(9) if i != 3)
    assert not (tmp_path / "g.origin.json").exists()


def test_reads_a_file_in_the_original_3dgs_layout(tmp_path):
    """A file built by hand with plyfile as graphdeco's save_ply writes it (degree 3, zero normals)."""
    n = 5
    rng = np.random.default_rng(2)
    names = gaussian_property_names(3)
    values = rng.normal(size=(n, len(names))).astype("<f4")
    arr = np.empty(n, dtype=[(k, "<f4") for k in names])
    for i, k in enumerate(names):
        arr[k] = values[:, i]
    plyfile.PlyData([plyfile.PlyElement.describe(arr, "vertex")]).write(str(tmp_path / "orig.ply"))
    gs = read_gaussian_ply(tmp_path / "orig.ply")
    col = {k: values[:, i] for i, k in enumerate(names)}
    np.testing.assert_array_equal(gs.sh_rest[:, 4, 2], col["f_rest_34"])  # B channel (offset 30) coefficient 4
    np.testing.assert_array_equal(gs.quats[:, 0], col["rot_0"])
    np.testing.assert_array_equal(gs.logit_opacities, col["opacity"])


def test_gaussian_ply_missing_f_dc(tmp_path):
    names = [k for k in gaussian_property_names(0) if not k.startswith("f_dc")]
    arr = np.zeros(2, dtype=[(k, "<f4") for k in names])
    plyfile.PlyData([plyfile.PlyElement.describe(arr, "vertex")]).write(str(tmp_path / "nodc.ply"))
    with pytest.raises(FormatError, match=r"nodc.ply.*missing vertex properties f_dc_0, f_dc_1, f_dc_2"):
        read_gaussian_ply(tmp_path / "nodc.ply")


def test_gaussian_ply_refuses_nan(tmp_path):
    gs = _gaussians()
    gs.sh_dc[1, 1] = np.nan
    with pytest.raises(DataError, match="sh_dc"):
        write_gaussian_ply(tmp_path / "x.ply", gs)
    assert not list(tmp_path.iterdir())


def _cameras():
    cams = {
        1: Camera("OPENCV", 640, 480, [500, 505, 320, 240, -0.05, 0.01, 0.001, 0.0005], 1),
        2: Camera("SIMPLE_RADIAL", 320, 240, [250, 160, 120, 0.02], 2),
    }
    rng = np.random.default_rng(0)
    views = {}
    for i in range(1, 6):
        q = rng.normal(size=4)
        views[i] = View(i, f"img_{i:03d}.png", 1 + i % 2, q, rng.normal(size=3))
    return Cameras(cams, views)


@pytest.mark.parametrize("binary", [True, False], ids=["bin", "txt"])
def test_colmap_model_round_trip(tmp_path, binary):
    cams = _cameras()
    write_model(tmp_path / "sparse", cams, binary=binary)
    assert (tmp_path / "sparse" / ("images.bin" if binary else "images.txt")).is_file()
    back, points = read_model(tmp_path / "sparse")
    assert len(points) == 0
    for cid, cam in cams.cameras.items():
        assert back.cameras[cid].model == cam.model
        np.testing.assert_allclose(back.cameras[cid].params, cam.params, rtol=1e-12)
    for vid, view in cams.views.items():
        b = back.views[vid]
        assert (b.name, b.camera_id) == (view.name, view.camera_id)
        np.testing.assert_allclose(b.rotation, view.rotation, atol=1e-12)
        np.testing.assert_allclose(b.translation, view.translation, atol=1e-12)


def test_colmap_model_from_pycolmap_synthetic_dataset(tmp_path):
    """A model written by pycolmap itself (synthetic cameras, points with tracks)."""
    options = pycolmap.SyntheticDatasetOptions()
    options.num_points3D = 50
    rec = pycolmap.synthesize_dataset(options)
    rec.write_binary(str(tmp_path))
    cams, points = read_model(tmp_path)
    assert len(cams) == rec.num_reg_images() and len(points) == rec.num_points3D()
    for image_id, view in cams.views.items():
        image = rec.image(image_id)
        np.testing.assert_allclose(view.center, image.projection_center(), atol=1e-9)
        # projecting a tracked point with our camera model reproduces pycolmap's projection
        pid = next(p.point3D_id for p in image.points2D if p.has_point3D())
        xyz = rec.point3D(pid).xyz
        px, _ = cams.project(image_id, xyz)
        np.testing.assert_allclose(px, image.project_point(xyz), atol=1e-6)
        break
    assert all(len(v) >= 2 for v in points.visibility)
    again, _ = from_reconstruction(rec)
    assert set(again.views) == set(cams.views)


def test_colmap_missing_folder(tmp_path):
    with pytest.raises(InputFileError, match="does not exist"):
        read_model(tmp_path / "nothing")
    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "cameras.bin").write_bytes(b"")
    with pytest.raises(InputFileError, match="not a COLMAP model"):
        read_model(tmp_path / "half")


def test_e57_written_by_pye57_is_read(tmp_path):
    pye57 = pytest.importorskip("pye57")
    rng = np.random.default_rng(3)
    local = rng.uniform(0, 10, (300, 3))
    world = local + UTM  # scanners store station-local points plus a float64 pose, as here
    data = {
        "cartesianX": local[:, 0],
        "cartesianY": local[:, 1],
        "cartesianZ": local[:, 2],
        "colorRed": rng.integers(0, 256, 300).astype(np.uint8),
        "colorGreen": rng.integers(0, 256, 300).astype(np.uint8),
        "colorBlue": rng.integers(0, 256, 300).astype(np.uint8),
        "intensity": rng.random(300).astype(np.float32),
    }
    e57 = pye57.E57(str(tmp_path / "scan.e57"), mode="w")
    e57.write_scan_raw(data, translation=UTM, rotation=np.array([1.0, 0.0, 0.0, 0.0]))
    e57.close()
    pc = read_e57(tmp_path / "scan.e57")
    # pye57's writer stores point coordinates in single precision: 10 m -> ~1e-6 m steps
    np.testing.assert_allclose(pc.world_positions, world, atol=1e-5, rtol=0)
    assert np.abs(pc.positions).max() < 100
    np.testing.assert_array_equal(pc.colors[:, 0], data["colorRed"])
    (tmp_path / "bad.e57").write_bytes(b"garbage" * 100)
    with pytest.raises(FormatError, match="bad.e57"):
        read_e57(tmp_path / "bad.e57")


def test_point_cloud_sparse_points_written_and_read(tmp_path):
    cams = _cameras()
    pts = PointCloud(np.random.default_rng(0).normal(size=(10, 3)), colors=np.full((10, 3), 9, np.uint8))
    write_model(tmp_path / "m", cams, pts)
    _, back = read_model(tmp_path / "m")
    np.testing.assert_allclose(back.positions, pts.positions, atol=1e-12)
    assert (back.colors == 9).all()


def test_empty_gaussian_set_round_trip(tmp_path):
    empty = GaussianSet(
        np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 8, 3))
    )
    assert len(empty) == 0 and empty.sh_degree == 2
    write_gaussian_ply(tmp_path / "empty.ply", empty)
    back = read_gaussian_ply(tmp_path / "empty.ply")
    assert len(back) == 0 and back.sh_degree == 2
    with pytest.raises(DataError, match="empty Gaussian set"):
        GaussianSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3)), np.zeros(0))
