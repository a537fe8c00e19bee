"""PLY and LAS/LAZ point clouds: round trips in every encoding, real files from other writers, bad input."""

import json

import laspy
import numpy as np
import open3d as o3d
import plyfile
import pytest

from core import DataError, FormatError, InputFileError, PointCloud
from core.io import read_point_cloud, write_point_cloud
from core.io.las import read_las, write_las
from core.io.ply import read_ply, write_ply

UTM = np.array([500_123.456, 5_000_987.654, 312.5])


def _cloud(n=500, origin=UTM, seed=0):
    rng = np.random.default_rng(seed)
    world = rng.uniform(-40, 40, (n, 3)) + origin
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return world, PointCloud.from_world(
        world,
        colors=rng.integers(0, 256, (n, 3)),
        normals=normals,
        fields={
            "classification": rng.integers(0, 20, n).astype(np.uint8),
            "c2c": rng.random(n),
            "confidence": rng.random(n).astype(np.float32),
            "material": rng.integers(-3, 9, n).astype(np.int32),
        },
    )


@pytest.mark.parametrize(
    "binary,byte_order,position_dtype,color_dtype",
    [(True, "<", "f4", "u1"), (True, ">", "f8", "f4"), (False, "<", "f8", "u1"), (False, "<", "f4", "f4")],
    ids=["binary_le_float", "binary_be_double_floatrgb", "ascii_double", "ascii_float_floatrgb"],
)
def test_ply_round_trip_keeps_everything(tmp_path, binary, byte_order, position_dtype, color_dtype):
    world, pc = _cloud()
    path = tmp_path / "cloud.ply"
    write_ply(path, pc, binary=binary, byte_order=byte_order, position_dtype=position_dtype, color_dtype=color_dtype)
    header = path.read_bytes()[:400]
    assert (b"binary_big_endian" in header) == (binary and byte_order == ">")
    assert (b"format ascii" in header) == (not binary)
    back = read_ply(path)
    np.testing.assert_allclose(back.world_positions, world, atol=1e-3, rtol=0)  # within 1 mm
    np.testing.assert_array_equal(back.colors, pc.colors)
    np.testing.assert_allclose(back.normals, pc.normals, atol=1e-6)
    for name, values in pc.fields.items():
        np.testing.assert_allclose(back.fields[name], values, rtol=1e-6 if values.dtype == np.float32 else 1e-12)
    # the payload stays local: float32 values are small, the origin is in the sidecar
    raw = plyfile.PlyData.read(str(path))["vertex"]
    assert np.abs(np.asarray(raw["x"])).max() < 100
    assert json.loads((tmp_path / "cloud.origin.json").read_text())["origin"] == pytest.approx(list(pc.origin), abs=0)


def test_ply_world_coordinates_mode(tmp_path):
    world, pc = _cloud()
    write_ply(tmp_path / "w.ply", pc, coordinates="world")
    assert not (tmp_path / "w.origin.json").exists()
    back = read_ply(tmp_path / "w.ply")
    np.testing.assert_allclose(back.world_positions, world, atol=1e-9, rtol=0)
    assert np.abs(back.positions).max() < 1e3  # the reader chose a local origin itself


def test_ply_written_by_open3d_is_read(tmp_path):
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(200, 3))
    cols = rng.random((200, 3))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.colors = o3d.utility.Vector3dVector(cols)
    pcd.normals = o3d.utility.Vector3dVector(pts / np.linalg.norm(pts, axis=1, keepdims=True))
    o3d.io.write_point_cloud(str(tmp_path / "o3d.ply"), pcd, write_ascii=False)
    back = read_ply(tmp_path / "o3d.ply")
    np.testing.assert_allclose(back.positions, pts, atol=1e-12)
    np.testing.assert_allclose(back.colors / 255.0, cols, atol=1 / 255)
    # and the reverse: open3d reads ours
    write_ply(tmp_path / "ours.ply", back)
    again = o3d.io.read_point_cloud(str(tmp_path / "ours.ply"))
    np.testing.assert_allclose(np.asarray(again.points), pts, atol=1e-6)


def test_truncated_ply_names_file(tmp_path):
    _, pc = _cloud()
    path = tmp_path / "cut.ply"
    write_ply(path, pc)
    path.write_bytes(path.read_bytes()[:-1000])
    with pytest.raises(InputFileError, match="cut.ply.*truncated"):
        read_ply(path)


def test_ply_without_xyz(tmp_path):
    v = np.zeros(3, dtype=[("a", "f4"), ("b", "f4")])
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")]).write(str(tmp_path / "noxyz.ply"))
    with pytest.raises(FormatError, match="noxyz.ply.*lacks x, y, z"):
        read_ply(tmp_path / "noxyz.ply")


def test_ply_with_nan_coordinates(tmp_path):
    v = np.array([(0.0, 0.0, 0.0), (np.nan, 1.0, 2.0)], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")]).write(str(tmp_path / "nan.ply"))
    with pytest.raises(DataError, match="nan.ply.*NaN"):
        read_ply(tmp_path / "nan.ply")


def test_missing_and_empty_files(tmp_path):
    with pytest.raises(InputFileError, match="does not exist"):
        read_ply(tmp_path / "nope.ply")
    (tmp_path / "empty.ply").write_bytes(b"")
    with pytest.raises(InputFileError, match="empty"):
        read_ply(tmp_path / "empty.ply")
    (tmp_path / "junk.ply").write_bytes(b"this is not a ply file\n")
    with pytest.raises(FormatError, match="junk.ply"):
        read_ply(tmp_path / "junk.ply")


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_round_trip_keeps_millimetres(tmp_path, suffix):
    world, pc = _cloud()
    path = tmp_path / f"cloud{suffix}"
    write_las(path, pc)
    back = read_las(path)
    np.testing.assert_allclose(back.world_positions, world, atol=0.5e-3 + 1e-9, rtol=0)
    np.testing.assert_array_equal(back.colors, pc.colors)
    np.testing.assert_array_equal(back.fields["classification"], pc.fields["classification"])
    np.testing.assert_allclose(back.fields["c2c"], pc.fields["c2c"])
    np.testing.assert_array_equal(back.fields["material"], pc.fields["material"])
    np.testing.assert_allclose(back.normals, pc.normals, atol=1e-6)
    # independent reader: laspy's own scaled coordinates, offsets at the origin, 16-bit RGB
    las = laspy.read(path)
    np.testing.assert_allclose(np.stack([las.x, las.y, las.z], 1), world, atol=0.5e-3 + 1e-9, rtol=0)
    np.testing.assert_allclose(las.header.offsets, pc.origin, atol=1e-3)
    assert las.header.scales.tolist() == [0.001] * 3
    np.testing.assert_array_equal(np.asarray(las.red), pc.colors[:, 0].astype(np.uint16) * 257)
    assert (tmp_path / f"cloud{suffix}").stat().st_size > 0 and not list(tmp_path.glob(".*tmp*"))


def test_las_written_by_laspy_with_own_scale_and_offset(tmp_path):
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.001])
    header.offsets = np.array([600000.0, 4000000.0, 0.0])
    las = laspy.LasData(header)
    rng = np.random.default_rng(5)
    xyz = np.round((rng.uniform(0, 100, (50, 3)) + [600000, 4000000, 0]) / [0.01, 0.01, 0.001]) * [0.01, 0.01, 0.001]
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.classification = np.full(50, 6, np.uint8)
    las.red = las.green = las.blue = np.full(50, 200, np.uint16)  # 8-bit values stored in 16-bit fields
    las.write(str(tmp_path / "ext.las"))
    back = read_las(tmp_path / "ext.las")
    np.testing.assert_allclose(back.world_positions, xyz, atol=1e-6, rtol=0)
    assert (back.fields["classification"] == 6).all()
    assert (back.colors == 200).all()


def test_las_with_bad_header(tmp_path):
    _, pc = _cloud(20)
    write_las(tmp_path / "ok.las", pc)
    data = bytearray((tmp_path / "ok.las").read_bytes())
    data[0:4] = b"XXXX"  # file signature must be LASF
    (tmp_path / "bad.las").write_bytes(bytes(data))
    with pytest.raises(FormatError, match="bad.las"):
        read_las(tmp_path / "bad.las")
    (tmp_path / "short.las").write_bytes(bytes(data[:50]))
    with pytest.raises((FormatError, InputFileError), match="short.las"):
        read_las(tmp_path / "short.las")


def test_dispatch_by_suffix(tmp_path):
    world, pc = _cloud(30)
    for name in ("a.ply", "a.las", "a.laz"):
        write_point_cloud(tmp_path / name, pc)
        np.testing.assert_allclose(read_point_cloud(tmp_path / name).world_positions, world, atol=1e-3)
    with pytest.raises(FormatError, match="unknown point cloud format"):
        read_point_cloud(tmp_path / "a.xyz")


def test_failed_write_leaves_nothing(tmp_path):
    pc = PointCloud(np.array([[0.0, 0, 0], [np.nan, 0, 0]]))
    with pytest.raises(DataError):
        write_las(tmp_path / "x.las", pc)
    assert list(tmp_path.iterdir()) == []


def test_atomic_writes_get_normal_permissions(tmp_path):
    import os

    _, pc = _cloud(10)
    write_ply(tmp_path / "perm.ply", pc)
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "perm.ply").stat().st_mode & 0o777 == 0o666 & ~mask


def test_las_written_chunk_by_chunk_reads_back_at_utm_coordinates(tmp_path):
    """write_las_chunks: three chunks around a UTM origin, read back to the 1 mm integer step (±0.5 mm), in order."""
    from core.io.las import write_las_chunks

    rng = np.random.default_rng(3)
    origin = np.array([2_600_123.4567, 1_200_456.789, 432.1])
    local = rng.uniform(-500, 500, (25_000, 3))
    count = write_las_chunks(tmp_path / "c.laz", (local[i : i + 10_000] for i in range(0, len(local), 10_000)), origin)
    back = read_las(tmp_path / "c.laz")
    assert count == len(back) == len(local)
    np.testing.assert_allclose(back.world_positions, local + origin, atol=0.5e-3 + 1e-9, rtol=0)
    with pytest.raises(DataError, match=".las or .laz"):
        write_las_chunks(tmp_path / "c.ply", iter([local]), origin)
    assert not (tmp_path / "c.ply").exists()
