"""fusion.export and fusion.splat_format: files read back with plyfile / laspy / raw bytes alone (independent of our
readers), the exact 3DGS property order, the 32-byte .splat layout, and georeferenced payloads."""

from __future__ import annotations

import json
import struct

import laspy
import numpy as np
import plyfile
import pytest
from scipy.spatial import cKDTree

from core.errors import ConfigError, DataError, FormatError
from core.gaussians import GaussianSet, logit
from core.pointcloud import PointCloud
from fusion.convert import Source, points_to_gaussians
from fusion.export import (
    ExportOptions,
    export_gaussian_ply,
    export_gaussians,
    export_points,
    export_splat,
    gaussians_to_points,
)
from fusion.splat_format import read_splat

C0 = 0.28209479177387814


def _random_set(n: int = 50, degree: int = 3, origin=(0.0, 0.0, 0.0), seed: int = 0) -> GaussianSet:
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1
    return GaussianSet(
        means=rng.normal(size=(n, 3)),
        log_scales=rng.uniform(-5, -1, (n, 3)),
        quats=rng.normal(size=(n, 4)),
        logit_opacities=rng.uniform(-4, 6, n),
        sh_dc=rng.uniform(-1.7, 1.7, (n, 3)),
        sh_rest=rng.normal(size=(n, k, 3)) * 0.1,
        origin=np.asarray(origin, float),
        fields={"source": np.full(n, Source.SPLAT, np.uint8), "classification": rng.integers(0, 6, n).astype(np.uint8)},
    )


def test_3dgs_ply_property_order_and_values_read_with_plyfile_alone(tmp_path):
    gs = _random_set(degree=3)
    export_gaussian_ply(tmp_path / "g.ply", gs, ExportOptions(min_opacity=0))
    ply = plyfile.PlyData.read(str(tmp_path / "g.ply"))
    assert not ply.text and ply.byte_order == "<"
    v = ply["vertex"]
    names = [p.name for p in v.properties]
    expected = (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(45)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )
    assert names == expected
    assert all(p.val_dtype in ("f4", "float32", "float") for p in v.properties)
    d = v.data
    np.testing.assert_array_equal(np.c_[d["x"], d["y"], d["z"]], gs.means.astype(np.float32))
    np.testing.assert_array_equal(np.c_[d["nx"], d["ny"], d["nz"]], 0.0)
    np.testing.assert_array_equal(np.c_[d["f_dc_0"], d["f_dc_1"], d["f_dc_2"]], gs.sh_dc)
    # channel-major: f_rest_{c*15 + j} = coefficient j of channel c
    for c in range(3):
        for j in range(15):
            np.testing.assert_array_equal(d[f"f_rest_{c * 15 + j}"], gs.sh_rest[:, j, c])
    np.testing.assert_array_equal(d["opacity"], gs.logit_opacities)
    np.testing.assert_array_equal(np.c_[d["scale_0"], d["scale_1"], d["scale_2"]], gs.log_scales)
    np.testing.assert_array_equal(np.c_[d["rot_0"], d["rot_1"], d["rot_2"], d["rot_3"]], gs.quats)  # w first
    assert not (tmp_path / "g.origin.json").exists()  # zero origin: no sidecar


def test_sh_degree_reduction_and_extra_fields(tmp_path):
    gs = _random_set(degree=3)
    export_gaussian_ply(tmp_path / "g1.ply", gs, ExportOptions(min_opacity=0, sh_degree=1, extra_fields=True))
    d = plyfile.PlyData.read(str(tmp_path / "g1.ply"))["vertex"].data
    assert [n for n in d.dtype.names if n.startswith("f_rest_")] == [f"f_rest_{i}" for i in range(9)]
    for c in range(3):
        for j in range(3):
            np.testing.assert_array_equal(d[f"f_rest_{c * 3 + j}"], gs.sh_rest[:, j, c])
    assert d.dtype.names[-2:] == ("classification", "source")
    np.testing.assert_array_equal(d["classification"], gs.fields["classification"])
    np.testing.assert_array_equal(d["source"], Source.SPLAT)


def test_splat_file_is_32_bytes_per_gaussian_decoded_by_hand(tmp_path):
    gs = _random_set(n=37, degree=1)
    gs.sh_dc[0] = (3.0, -3.0, 0.0)  # out of [0, 1] after 0.5 + C0·f_dc: must clip
    report = export_splat(tmp_path / "g.splat", gs, ExportOptions(min_opacity=0))
    raw = (tmp_path / "g.splat").read_bytes()
    assert len(raw) == 32 * 37 and report.num_written == 37
    pos, scale, rgba, rot = [], [], [], []
    for i in range(37):  # decode with struct, independent of the writer's numpy dtype
        rec = raw[32 * i : 32 * (i + 1)]
        pos.append(struct.unpack("<3f", rec[0:12]))
        scale.append(struct.unpack("<3f", rec[12:24]))
        rgba.append(tuple(rec[24:28]))
        rot.append(tuple(rec[28:32]))
    pos, scale, rgba, rot = map(np.array, (pos, scale, rgba, rot))
    # records are sorted by importance; match them back by position
    order = [int(np.flatnonzero((gs.means.astype(np.float32) == p).all(axis=1))[0]) for p in pos.astype(np.float32)]
    g = gs.subset(np.array(order))
    importance = np.exp(g.log_scales.astype(np.float64).sum(1)) * g.opacities
    assert np.all(np.diff(importance) <= 1e-12)
    np.testing.assert_allclose(scale, np.exp(g.log_scales.astype(np.float64)), rtol=1e-6)
    rgb = np.clip(np.rint((0.5 + C0 * g.sh_dc.astype(np.float64)) * 255), 0, 255)
    np.testing.assert_array_equal(rgba[:, :3], rgb)
    np.testing.assert_array_equal(rgba[:, 3], np.rint(255 / (1 + np.exp(-g.logit_opacities.astype(np.float64)))))
    q = g.quats.astype(np.float64) / np.linalg.norm(g.quats, axis=1, keepdims=True)
    np.testing.assert_array_equal(rot, np.clip(np.rint(q * 128 + 128), 0, 255))
    # our reader agrees
    data = read_splat(tmp_path / "g.splat")
    np.testing.assert_array_equal(data.rgba, rgba)
    np.testing.assert_allclose(data.quats, (rot - 128) / 128.0)


def test_mvs_colours_survive_the_splat_round_trip_exactly(tmp_path):
    rng = np.random.default_rng(2)
    rgb = np.stack(np.meshgrid(np.arange(256), np.arange(256)[::-1], [7], indexing="ij"), -1).reshape(-1, 3)
    pos = rng.random((len(rgb), 3))
    gs = points_to_gaussians(PointCloud(pos, colors=rgb.astype(np.uint8)), "paper")
    export_splat(tmp_path / "c.splat", gs, ExportOptions(min_opacity=0))
    rec = np.frombuffer((tmp_path / "c.splat").read_bytes(), np.uint8).reshape(-1, 32)
    xyz = rec[:, :12].copy().view("<f4")
    back = {tuple(p): tuple(c) for p, c in zip(map(tuple, xyz), map(tuple, rec[:, 24:27]), strict=True)}
    got = np.array([back[tuple(p)] for p in pos.astype(np.float32)])
    np.testing.assert_array_equal(got, rgb)


def test_georeferenced_export_float32_near_origin_and_sidecar_restores_1mm(tmp_path):
    rng = np.random.default_rng(9)
    world = rng.random((2000, 3)) * [300, 200, 40] + [498765.4321, 5432109.8765, 876.5432]  # UTM-like
    cloud = PointCloud.from_world(world, colors=rng.integers(0, 256, (2000, 3)))
    gs = points_to_gaussians(cloud, "adaptive")
    for name, exporter in (("g.ply", export_gaussian_ply), ("g.splat", export_splat)):
        exporter(tmp_path / name, gs, ExportOptions(min_opacity=0))
    # 3DGS PLY: float32 payload within the scene extent of the origin
    d = plyfile.PlyData.read(str(tmp_path / "g.ply"))["vertex"].data
    local = np.c_[d["x"], d["y"], d["z"]].astype(np.float64)
    assert d["x"].dtype == np.float32 and np.abs(local).max() < 200
    side = json.loads((tmp_path / "g.origin.json").read_text())
    restored = local + np.asarray(side["origin"], np.float64)
    assert np.abs(restored - world).max() < 1e-3  # 1 mm (float32 near the origin: ~1e-5 m)
    # .splat: same payload, same sidecar
    rec = np.frombuffer((tmp_path / "g.splat").read_bytes(), np.uint8).reshape(-1, 32)
    origin = np.asarray(json.loads((tmp_path / "g.origin.json").read_text())["origin"], np.float64)
    xyz = rec[:, :12].copy().view("<f4").astype(np.float64) + origin
    dist, _ = cKDTree(world).query(xyz)  # .splat records are reordered by importance
    assert dist.max() < 1e-3
    # LAS: integer records at 1 mm with the offset in the header
    export_points(tmp_path / "g.las", gs, ExportOptions(min_opacity=0))
    las = laspy.read(str(tmp_path / "g.las"))
    xyz_las = np.c_[las.x, las.y, las.z]
    np.testing.assert_allclose(xyz_las, world, atol=5e-4 + 1e-9, rtol=0)  # order kept


def test_point_cloud_exports_keep_class_and_source(tmp_path):
    gs = _random_set(n=40, degree=0)
    gs.fields["source"][:15] = Source.MVS
    export_points(tmp_path / "p.ply", gs, ExportOptions(min_opacity=0))
    export_points(tmp_path / "p.las", gs, ExportOptions(min_opacity=0))
    d = plyfile.PlyData.read(str(tmp_path / "p.ply"))["vertex"].data
    np.testing.assert_array_equal(d["source"], gs.fields["source"])
    np.testing.assert_array_equal(d["classification"], gs.fields["classification"])
    assert d["source"].dtype == np.uint8
    rgb = np.clip(np.rint((0.5 + C0 * gs.sh_dc.astype(np.float64)) * 255), 0, 255)
    np.testing.assert_array_equal(np.c_[d["red"], d["green"], d["blue"]], rgb)
    np.testing.assert_allclose(d["opacity"], 1 / (1 + np.exp(-gs.logit_opacities.astype(np.float64))), rtol=1e-6)
    las = laspy.read(str(tmp_path / "p.las"))
    np.testing.assert_array_equal(np.asarray(las.classification), gs.fields["classification"])
    np.testing.assert_array_equal(np.asarray(las["source"]), gs.fields["source"])
    np.testing.assert_allclose(np.c_[las.x, las.y, las.z], gs.means, atol=5e-4 + 1e-9)


def test_crop_and_opacity_filters_count_what_they_drop(tmp_path):
    gs = _random_set(n=400, degree=0, origin=(1000.0, 2000.0, 0.0))
    gs.logit_opacities[:10] = logit(np.full(10, 0.5 / 255))  # invisible
    opts = ExportOptions(crop_min=(999.5, 1999.0, -1.0), crop_max=(1001.0, 2001.0, 1.0))
    report = export_gaussian_ply(tmp_path / "c.ply", gs, opts)
    world = gs.world_means
    inside = np.all((world >= opts.crop_min) & (world <= opts.crop_max), axis=1)
    visible = gs.opacities >= np.float32(1 / 255)
    assert report.dropped_crop == int((~inside).sum())
    assert report.dropped_opacity == int((inside & ~visible).sum())
    assert report.num_written == int((inside & visible).sum())
    d = plyfile.PlyData.read(str(tmp_path / "c.ply"))["vertex"].data
    assert len(d) == report.num_written
    np.testing.assert_array_equal(np.c_[d["x"], d["y"], d["z"]], gs.means[inside & visible].astype(np.float32))


def test_gaussians_to_points_defaults_and_dispatch(tmp_path):
    gs = _random_set(n=5, degree=0)
    gs.fields = {}
    pts = gaussians_to_points(gs)
    np.testing.assert_array_equal(pts.fields["source"], Source.UNKNOWN)
    np.testing.assert_array_equal(pts.fields["classification"], 0)
    assert export_gaussians(tmp_path / "a.splat", gs).format == "splat"
    assert export_gaussians(tmp_path / "a.ply", gs).format == "3dgs-ply"
    assert export_gaussians(tmp_path / "a.laz", gs).format == "laz"
    with pytest.raises(FormatError):
        export_gaussians(tmp_path / "a.obj", gs)
    with pytest.raises(ConfigError):
        ExportOptions(crop_min=(0, 0, 0))
    with pytest.raises(ConfigError):
        ExportOptions(crop_min=(1, 0, 0), crop_max=(0, 1, 1))
    with pytest.raises(ConfigError):
        ExportOptions(sh_degree=4)


def test_exporting_nothing_is_a_clear_error_and_writes_no_file(tmp_path):
    gs = _random_set(n=10, degree=0, origin=(100.0, 0.0, 0.0))
    opts = ExportOptions(crop_min=(0, 0, 0), crop_max=(1, 1, 1))  # the set lies around x = 100
    with pytest.raises(DataError, match="10 lie outside the crop box"):
        export_gaussian_ply(tmp_path / "none.ply", gs, opts)
    assert not any(tmp_path.iterdir())
