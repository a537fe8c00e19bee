"""glTF ``KHR_gaussian_splatting`` tiles in a georeferenced 3D Tiles 1.1 tileset (fusion.gltf_splats, fusion.tiles3d).

The truth for placement is pyproj's ECEF (EPSG:4978) of origin + local, composed here independently of the writer:
tile transforms from tileset.json (column-major), the 3D Tiles y-up → z-up rotation as printed in the spec, and the
GLB node matrix as stored. GLBs are parsed by hand (header, chunks, accessors) as well as through our reader.
Tolerances: float32 positions round by ≤ 0.5 ulp (3e-5 m at 500 m); exact placement must stay below 1 mm over a
1 km set; grid placement is off by the earth's curvature, r² / 2R (a sagitta), which the test bounds.
"""

from __future__ import annotations

import json
import math
import os
import struct
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pyproj
import pytest
from npm_readers import gltf_tools_prefix

from core.errors import ConfigError, DataError, FormatError
from core.gaussians import SH_C0, GaussianSet, sigmoid
from fusion.gltf_splats import (
    EXTENSION,
    SPZ_EXTENSION,
    ColorSpace,
    GltfCompression,
    encode_splat_glb,
    read_splat_glb,
    rotate_sh_rest,
    srgb_to_linear,
)
from fusion.render.brute_force import _sh_rgb
from fusion.tiles3d import Placement, TilesetOptions, TilesetWarning, write_splat_tileset

UTM = "EPSG:32633"
ORIGIN = np.array([500000.0, 4000000.0, 100.0])  # on zone 33's central meridian: convergence 0, k = 0.9996
ORIGIN_EAST = np.array([600000.0, 4000000.0, 100.0])  # 100 km east of it: convergence ≈ 0.66°
Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])  # 3D Tiles 1.1, row-major
EARTH_RADIUS = 6.371e6
RAW = GltfCompression.NONE  # float32 tiles: exact values, and splat ids carried in the SH DC (SPZ clips them)
RAW_OPTIONS = TilesetOptions(compression=RAW)


def _splats(n: int, extent: float = 500.0, degree: int = 0, seed: int = 0, origin=ORIGIN, layers=True) -> GaussianSet:
    """Random splats in ±extent m horizontally, ±50 m vertically; sh_dc[:, 0] = the splat's index (its id)."""
    rng = np.random.default_rng(seed)
    means = np.c_[rng.uniform(-extent, extent, (n, 2)), rng.uniform(-50, 50, n)]
    sh_dc = rng.normal(size=(n, 3)).astype(np.float32)
    sh_dc[:, 0] = np.arange(n)
    fields = {"source": rng.choice(np.array([1, 2, 3], np.uint8), n)} if layers else {}
    return GaussianSet(
        means,
        rng.normal(-3.0, 1.0, (n, 3)),
        rng.normal(size=(n, 4)),
        rng.normal(0.0, 3.0, n),
        sh_dc,
        rng.normal(0.0, 0.2, (n, (degree + 1) ** 2 - 1, 3)),
        origin=np.array(origin, dtype=np.float64),  # a copy: tests change it
        fields=fields,
    )


def _glb(data: bytes) -> tuple[dict, bytes]:
    """JSON and BIN chunks of a GLB, parsed by hand (glTF 2.0 §4.4): header, 4-byte aligned chunks."""
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_len, json_type = struct.unpack_from("<I4s", data, 12)
    assert json_type == b"JSON" and json_len % 4 == 0
    doc = json.loads(data[20 : 20 + json_len])
    bin_len, bin_type = struct.unpack_from("<I4s", data, 20 + json_len)
    assert bin_type == b"BIN\0" and bin_len % 4 == 0 and 28 + json_len + bin_len == len(data)
    return doc, data[28 + json_len : 28 + json_len + bin_len]


def _accessor(doc: dict, blob: bytes, semantic: str) -> np.ndarray:
    """One float attribute of the first primitive, decoded by hand."""
    acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"][semantic]]
    view = doc["bufferViews"][acc["bufferView"]]
    comps = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc["type"]]
    assert acc["componentType"] == 5126 and "byteStride" not in view
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    return np.frombuffer(blob, "<f4", acc["count"] * comps, start).reshape(acc["count"], comps)


def _tiles(tileset: dict):
    """(tile, tile-frame → tileset-frame transform (row-major), ancestors) for every tile, depth first."""

    def walk(tile, parent, ancestors):
        t = parent @ np.asarray(tile.get("transform", np.eye(4).T.reshape(-1)), float).reshape(4, 4).T
        yield tile, t, ancestors
        for child in tile.get("children", []):
            yield from walk(child, t, ancestors + [tile])

    yield from walk(tileset["root"], np.eye(4), [])


def _contents(path: Path):
    """(tile, transform, ancestors, decoded primitive, gltf JSON) per leaf of the tileset at ``path``."""
    tileset = json.loads(path.read_text())
    for tile, t, ancestors in _tiles(tileset):
        if "content" in tile:
            data = (path.parent / tile["content"]["uri"]).read_bytes()
            yield tile, t, ancestors, read_splat_glb(data), _glb(data)[0]


def _ecef(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Splat ids and final ECEF positions: tile transforms · y-up→z-up · node matrix · POSITION (float32)."""
    ids, points = [], []
    for _tile, t, _anc, prim, _doc in _contents(path):
        chain = t @ Y_UP_TO_Z_UP @ prim.node_matrix
        p = np.c_[prim.positions.astype(np.float64), np.ones(len(prim))]
        points.append((p @ chain.T)[:, :3])
        ids.append(prim.sh[:, 0, 0].astype(np.int64))
    return np.concatenate(ids), np.concatenate(points)


def _truth(gs: GaussianSet, ids: np.ndarray, crs: str = UTM) -> np.ndarray:
    world = gs.origin + gs.means[ids]
    x, y, z = pyproj.Transformer.from_crs(crs, "EPSG:4978", always_xy=True).transform(*world.T)
    return np.c_[x, y, z]


# -- the GLB -------------------------------------------------------------------------------------------------------


def test_glb_holds_the_extension_and_round_trips_every_value(tmp_path):
    gs = _splats(500, extent=50.0, degree=3, layers=False)
    data = encode_splat_glb(gs)
    doc, blob = _glb(data)
    prim = doc["meshes"][0]["primitives"][0]
    assert EXTENSION in doc["extensionsUsed"] and EXTENSION not in doc.get("extensionsRequired", [])
    assert prim["mode"] == 0
    assert prim["extensions"][EXTENSION] == {
        "kernel": "ellipse",
        "colorSpace": "srgb_rec709_display",
        "projection": "perspective",
        "sortingMethod": "cameraDistance",
    }
    names = {f"{EXTENSION}:{a}" for a in ("ROTATION", "SCALE", "OPACITY")}
    names |= {f"{EXTENSION}:SH_DEGREE_{d}_COEF_{c}" for d in range(4) for c in range(2 * d + 1)}
    assert set(prim["attributes"]) == names | {"POSITION", "COLOR_0"}
    types = {doc["accessors"][i]["type"] for name, i in prim["attributes"].items() if "SH_DEGREE" in name}
    assert types == {"VEC3"}
    assert all(doc["accessors"][i]["count"] == 500 for i in prim["attributes"].values())
    # positions: exactly the float32 local means, decoded by hand; accessor bounds are the exact float32 bounds
    pos = _accessor(doc, blob, "POSITION")
    assert np.array_equal(pos, gs.means.astype(np.float32))
    acc = doc["accessors"][prim["attributes"]["POSITION"]]
    assert acc["min"] == pos.min(axis=0).tolist() and acc["max"] == pos.max(axis=0).tolist()
    # the node turns z-up into y-up: local up (0, 0, 1) → glTF up (0, 1, 0)
    node = np.asarray(doc["nodes"][0]["matrix"]).reshape(4, 4).T
    assert np.allclose(node[:3, :3] @ [0, 0, 1], [0, 1, 0]) and np.isclose(np.linalg.det(node[:3, :3]), 1.0)

    back = read_splat_glb(data)
    q = gs.quats.astype(np.float64) / np.linalg.norm(gs.quats.astype(np.float64), axis=1, keepdims=True)
    assert np.abs(back.rotations - q[:, [1, 2, 3, 0]]).max() < 1e-7  # glTF order x, y, z, w; unit length
    assert np.allclose(back.scales, np.exp(gs.log_scales.astype(np.float64)), rtol=1e-6, atol=0)  # linear σ
    assert np.abs(back.opacities - sigmoid(gs.logit_opacities)).max() < 1e-7  # α, not logit
    assert np.array_equal(back.sh, gs.sh_coeffs)  # float32 copies, our order (checked against the spec below)
    base = np.clip(0.5 + SH_C0 * gs.sh_dc.astype(np.float64), 0, 1)
    assert np.abs(back.colors[:, :3] - srgb_to_linear(base)).max() <= 0.5 / 255 + 1e-6  # fallback, linear
    again = back.to_gaussians()
    assert np.array_equal(again.means, gs.means.astype(np.float32))
    assert np.abs(again.log_scales - gs.log_scales).max() < 1e-6
    assert np.array_equal(again.sh_rest, gs.sh_rest)


def test_sh_attributes_follow_the_spec_formula(tmp_path):
    """The spec's colour formula over the named attributes equals our renderer's over our coefficients."""
    gs = _splats(40, extent=5.0, degree=3, seed=3, layers=False)
    doc, blob = _glb(encode_splat_glb(gs))

    def sh(d, c):
        return _accessor(doc, blob, f"{EXTENSION}:SH_DEGREE_{d}_COEF_{c}").astype(np.float64)

    rng = np.random.default_rng(5)
    for _ in range(5):
        v = rng.normal(size=3)
        x, y, z = v = v / np.linalg.norm(v)
        colour = (
            sh(0, 0) * 0.2820947917738781
            + (sh(1, 0) * y * -0.4886025119029199 + sh(1, 1) * z * 0.4886025119029199)
            + sh(1, 2) * x * -0.4886025119029199
            + sh(2, 0) * x * y * 1.092548430592079
            + sh(2, 1) * y * z * -1.092548430592079
            + sh(2, 2) * (2 * z * z - x * x - y * y) * 0.3153915652525200
            + sh(2, 3) * x * z * -1.092548430592079
            + sh(2, 4) * (x * x - y * y) * 0.5462742152960395
            + sh(3, 0) * y * (3 * x * x - y * y) * -0.5900435899266435
            + sh(3, 1) * x * y * z * 2.890611442640554
            + sh(3, 2) * y * (4 * z * z - x * x - y * y) * -0.4570457994644657
            + sh(3, 3) * z * (2 * z * z - 3 * x * x - 3 * y * y) * 0.3731763325901154
            + sh(3, 4) * x * (4 * z * z - x * x - y * y) * -0.4570457994644657
            + sh(3, 5) * z * (x * x - y * y) * 1.445305721320277
            + sh(3, 6) * x * (x * x - 3 * y * y) * -0.5900435899266435
            + 0.5
        )
        ours = np.array([_sh_rgb(c.astype(np.float64), v, 3) for c in gs.sh_coeffs])
        assert np.abs(np.maximum(colour, 0) - ours).max() < 1e-5


def test_rotated_sh_show_the_same_colour_along_the_rotated_direction():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(2)
    coeffs = rng.normal(0, 0.3, (6, 16, 3))
    rot = Rotation.from_rotvec([0.3, -0.2, 0.9]).as_matrix()
    rest = rotate_sh_rest(coeffs[:, 1:], rot).astype(np.float64)
    for d in rng.normal(size=(5, 3)):
        d /= np.linalg.norm(d)
        for c, r in zip(coeffs, rest, strict=True):
            before = _sh_rgb(c, d, 3)
            after = _sh_rgb(np.concatenate([c[:1], r]), rot @ d, 3)
            assert np.abs(before - after).max() < 1e-5  # float32 output


def test_reader_names_the_file_for_bad_glb(tmp_path):
    bad = tmp_path / "x.glb"
    bad.write_bytes(b"glTF" + b"\0" * 30)
    with pytest.raises(FormatError) as err:
        read_splat_glb(bad)
    assert err.value.path == bad
    data = bytearray(encode_splat_glb(_splats(3, layers=False)))
    (tmp_path / "cut.glb").write_bytes(bytes(data[:-8]))
    with pytest.raises(FormatError, match="truncated"):
        read_splat_glb(tmp_path / "cut.glb")
    with pytest.raises(DataError, match="empty"):
        encode_splat_glb(_splats(3, layers=False).subset(np.zeros(3, bool)))


# -- the SPZ-compressed GLB (KHR_gaussian_splatting_compression_spz_2) ----------------------------------------------
# Tolerances are SPZ v2's quantisation as fusion/spz_format.py states it (per component): position half a fixed-point
# step, α 1/510, SH DC 1/(2 · 0.15 · 255), log σ 1/32, rotation x, y, z 1/255 (w ≥ 0), SH rest 0.0352 (degree 1)
# and 17/256 = 0.0664 (degrees 2-3); each plus 1e-6 for float32 storage and arithmetic.
SPZ_BOUNDS = {"alpha": 1 / 510, "dc": 1 / (2 * 0.15 * 255), "log_scale": 1 / 32, "xyz": 1 / 255, "sh": 17 / 256}


def _spz_ready(n: int, extent: float, degree: int, seed: int = 1, origin=ORIGIN, layers=False) -> GaussianSet:
    """Splats whose values lie inside SPZ's ranges (SH DC |f| ≤ 3.33, SH rest |c| ≤ 1), so only rounding remains."""
    gs = _splats(n, extent=extent, degree=degree, seed=seed, origin=origin, layers=layers)
    rng = np.random.default_rng(seed + 100)
    gs.sh_dc = rng.uniform(-3.0, 3.0, (n, 3)).astype(np.float32)
    gs.sh_rest = np.clip(gs.sh_rest, -1.0, 1.0)
    return gs


def _spz_of(doc: dict, blob: bytes, tmp_path: Path):
    """The SPZ stream the primitive's compression extension points at, decoded by fusion.spz_format.read_spz."""
    from fusion.spz_format import read_spz

    ext = doc["meshes"][0]["primitives"][0]["extensions"][EXTENSION]["extensions"][SPZ_EXTENSION]
    view = doc["bufferViews"][ext["bufferView"]]
    start = view.get("byteOffset", 0)
    stream = blob[start : start + view["byteLength"]]
    (tmp_path / "stream.spz").write_bytes(stream)
    return stream, read_spz(tmp_path / "stream.spz")


def test_spz_glb_follows_the_extension_and_decodes_to_the_input_within_spz_precision(tmp_path):
    from fusion.spz_format import EXPORT_SH1_BITS, EXPORT_SH_REST_BITS, write_spz

    gs = _spz_ready(800, extent=50.0, degree=3)
    data = encode_splat_glb(gs, compression="spz")
    doc, blob = _glb(data)  # a GLB: JSON chunk + BIN chunk, both 4-byte aligned
    prim = doc["meshes"][0]["primitives"][0]
    assert prim["mode"] == 0 and set(doc["extensionsUsed"]) >= {EXTENSION, SPZ_EXTENSION}
    assert set(doc["extensionsRequired"]) == {EXTENSION, SPZ_EXTENSION}  # no float data to fall back on
    assert prim["extensions"][EXTENSION]["extensions"] == {SPZ_EXTENSION: {"bufferView": 0}}  # CesiumJS reads view 0
    assert prim["extensions"][EXTENSION]["kernel"] == "ellipse"
    # the attributes the extension's mapping lists (COLOR_0 holds DC and α; no OPACITY, no SH degree 0)
    sh_names = {f"{EXTENSION}:SH_DEGREE_{d}_COEF_{c}" for d in (1, 2, 3) for c in range(2 * d + 1)}
    assert set(prim["attributes"]) == {"POSITION", "COLOR_0", f"{EXTENSION}:SCALE", f"{EXTENSION}:ROTATION"} | sh_names
    for name, index in prim["attributes"].items():
        acc = doc["accessors"][index]
        assert acc["count"] == 800 and "bufferView" not in acc and "byteOffset" not in acc
        kind = {"POSITION": "VEC3", "COLOR_0": "VEC4", f"{EXTENSION}:ROTATION": "VEC4"}.get(name, "VEC3")
        assert acc["type"] == kind and acc["componentType"] == (5121 if name == "COLOR_0" else 5126)
    assert doc["accessors"][prim["attributes"]["COLOR_0"]]["normalized"] is True
    assert len(doc["bufferViews"]) == 1 and doc["buffers"][0]["byteLength"] == len(blob)

    stream, spz = _spz_of(doc, blob, tmp_path)
    bits = spz.header.fractional_bits
    assert (spz.header.version, spz.header.num_points, spz.header.sh_degree, bits) == (
        2,
        800,
        3,
        17,
    )  # ±50 m: 17 bits (±64 m)
    # our .spz writer, at the same fractional bits and SH buckets
    write_spz(
        tmp_path / "ref.spz", gs, fractional_bits=bits, sh1_bits=EXPORT_SH1_BITS, sh_rest_bits=EXPORT_SH_REST_BITS
    )
    assert (tmp_path / "ref.spz").read_bytes() == stream
    pos_acc = doc["accessors"][prim["attributes"]["POSITION"]]  # bounds of the decoded positions, as float32
    assert pos_acc["min"] == spz.positions.min(axis=0).astype(np.float32).tolist()
    assert pos_acc["max"] == spz.positions.max(axis=0).astype(np.float32).tolist()
    assert np.abs(spz.positions - gs.means).max() <= 2.0 ** -(bits + 1) + 1e-9  # 3.8 µm at 17 bits
    assert np.abs(spz.alphas - sigmoid(gs.logit_opacities)).max() <= SPZ_BOUNDS["alpha"] + 1e-6
    assert np.abs(spz.sh_dc - gs.sh_dc).max() <= SPZ_BOUNDS["dc"] + 1e-6
    assert np.abs(spz.log_scales - gs.log_scales).max() <= SPZ_BOUNDS["log_scale"] + 1e-6
    q = gs.quats / np.linalg.norm(gs.quats, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)  # SPZ v2 stores the sign with w ≥ 0
    assert np.abs(spz.quats[:, 1:] - q[:, 1:]).max() <= SPZ_BOUNDS["xyz"] + 1e-6
    assert np.abs(spz.sh_rest - gs.sh_rest).max() <= SPZ_BOUNDS["sh"] + 1e-6

    back = read_splat_glb(data)  # our reader: the stream's values in glTF conventions, the same node matrix
    assert back.compression == "spz" and back.spz_fractional_bits == bits
    assert np.array_equal(back.positions, spz.positions.astype(np.float32))
    assert np.allclose(back.rotations, spz.quats[:, [1, 2, 3, 0]], atol=1e-7)
    assert np.allclose(back.scales, np.exp(spz.log_scales), rtol=1e-6) and np.allclose(back.opacities, spz.alphas)
    assert np.allclose(back.colors[:, :3], np.clip(0.5 + SH_C0 * spz.sh_dc, 0, 1), atol=1e-6)
    assert np.array_equal(back.node_matrix, read_splat_glb(encode_splat_glb(gs)).node_matrix)
    assert len(data) < len(encode_splat_glb(gs)) / 4  # SPZ's point: here ~7× smaller than float32


def test_spz_glb_refuses_what_it_cannot_hold_or_read(tmp_path):
    far = _spz_ready(10, extent=5.0, degree=0)
    far.means[0] = [9e6, 0.0, 0.0]  # beyond SPZ's 24-bit range even in whole metres
    with pytest.raises(FormatError, match="24-bit"):
        encode_splat_glb(far, compression="spz")
    with pytest.raises(ValueError):
        encode_splat_glb(far, compression="draco")
    data = bytearray(encode_splat_glb(_spz_ready(10, extent=5.0, degree=0), compression="spz"))
    doc, blob = _glb(bytes(data))
    json_len = struct.unpack_from("<I", data, 12)[0]
    data[28 + json_len : 28 + json_len + 4] = b"XXXX"  # break the gzip magic of the stream
    with pytest.raises(FormatError, match=SPZ_EXTENSION):
        read_splat_glb(bytes(data))


# -- the tileset ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("crs", [UTM, None], ids=["utm", "no-crs"])
def test_tileset_structure_boxes_and_layers(tmp_path, crs):
    gs = _splats(5000)
    out = tmp_path / "tiles" / "tileset.json"
    summary = write_splat_tileset(gs, out, crs, TilesetOptions(compression=RAW, max_splats_per_tile=700))
    tileset = json.loads(out.read_text())
    assert tileset["asset"]["version"] == "1.1" and tileset["geometricError"] > 0
    assert tileset["root"]["refine"] == "ADD" and len(tileset["root"]["transform"]) == 16
    assert EXTENSION in tileset["extensions"]["3DTILES_content_gltf"]["extensionsUsed"]
    groups = [g["properties"]["name"] for g in tileset["groups"]]
    assert groups == ["survey", "fill", "background"]
    assert tileset["schema"]["classes"]["layer"]["properties"]["source"]["componentType"] == "UINT8"

    seen: dict[str, list[np.ndarray]] = {name: [] for name in groups}
    for tile, _t, ancestors, prim, _doc in _contents(out):
        assert all("transform" not in a for a in ancestors[1:])  # one transform, on the root
        layer = groups[tile["content"]["group"]]
        assert tile["content"]["uri"].startswith(layer + "/") and tile["geometricError"] == 0
        assert 0 < len(prim) <= 700
        for box_tile in [tile, *ancestors]:  # every box (leaf, parents, root) holds the splats (axis-aligned)
            box = np.asarray(box_tile["boundingVolume"]["box"])
            assert np.count_nonzero(box[3:]) == 3 and box[[3, 7, 11]].min() > 0
            assert (np.abs(prim.positions - box[:3]) <= box[[3, 7, 11]]).all()
        for parent, child in zip(ancestors, [*ancestors[1:], tile], strict=True):
            assert parent["geometricError"] >= child["geometricError"]
        seen[layer].append(prim.sh[:, 0, 0].astype(np.int64))
    source = gs.fields["source"]
    for code, name in enumerate(groups, start=1):  # every splat in exactly one tile of its layer
        ids = np.concatenate(seen[name])
        assert np.array_equal(np.sort(ids), np.flatnonzero(source == code))
        layer = next(r for r in summary.layers if r.name == name)
        assert layer.splats == len(ids) and layer.tiles == len(seen[name])
        # the layer's own tileset: same tiles and transform, URIs relative to its folder
        alone = out.parent / name / "tileset.json"
        assert json.loads(alone.read_text())["root"]["transform"] == tileset["root"]["transform"]
        assert np.array_equal(np.sort(np.concatenate([p.sh[:, 0, 0] for *_, p, _ in _contents(alone)])), np.sort(ids))
    assert summary.splats == 5000 and sum(t.splats for t in summary.tiles) == 5000
    assert summary.bytes == sum((out.parent / t.uri).stat().st_size for t in summary.tiles)
    assert not list(out.parent.rglob(".*tmp*"))


def _nearest_ids(points: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the nearest truth point of each point, and the distance (SPZ tiles cannot carry splat ids)."""
    from scipy.spatial import cKDTree

    dist, ids = cKDTree(truth).query(points)
    return ids, dist


def test_spz_tileset_requires_both_extensions_and_places_every_decoded_splat(tmp_path):
    """The default (SPZ) tileset: 3DTILES_content_gltf requires both extensions (what CesiumJS checks before it draws
    splats); every box encloses the decoded positions; every splat appears once, in ECEF within 0.1 mm of pyproj
    (exact placement ≤ 0.02 mm, plus SPZ's ±30 µm per axis at the 14 fractional bits a ±500 m set allows)."""
    gs = _spz_ready(5000, extent=500.0, degree=1, layers=True)
    out = tmp_path / "tiles" / "tileset.json"
    summary = write_splat_tileset(gs, out, UTM, TilesetOptions(max_splats_per_tile=700))
    tileset = json.loads(out.read_text())
    content_gltf = tileset["extensions"]["3DTILES_content_gltf"]
    assert tileset["extensionsUsed"] == ["3DTILES_content_gltf"]
    assert {EXTENSION, SPZ_EXTENSION} <= set(content_gltf["extensionsUsed"])
    assert set(content_gltf["extensionsRequired"]) == {EXTENSION, SPZ_EXTENSION}
    assert "SPZ" in tileset["asset"]["extras"]["glTF"]
    points, layers = [], []
    for tile, t, ancestors, prim, doc in _contents(out):
        assert prim.compression == "spz" and prim.spz_fractional_bits >= 14
        assert set(doc["extensionsRequired"]) == {EXTENSION, SPZ_EXTENSION}
        for box_tile in [tile, *ancestors]:
            box = np.asarray(box_tile["boundingVolume"]["box"])
            assert (np.abs(prim.positions - box[:3]) <= box[[3, 7, 11]]).all()
        chain = t @ Y_UP_TO_Z_UP @ prim.node_matrix
        points.append((np.c_[prim.positions.astype(np.float64), np.ones(len(prim))] @ chain.T)[:, :3])
        layers.append(np.full(len(prim), tile["content"]["group"] + 1))
    ids, dist = _nearest_ids(np.concatenate(points), _truth(gs, np.arange(len(gs))))
    print(f"SPZ tiles: worst ECEF error {dist.max() * 1e3:.4f} mm over {len(dist)} splats")
    assert np.array_equal(np.sort(ids), np.arange(5000)) and dist.max() < 1e-4
    assert np.array_equal(gs.fields["source"][ids], np.concatenate(layers))  # each in its own layer's subtree
    raw = write_splat_tileset(
        gs, tmp_path / "raw" / "tileset.json", UTM, TilesetOptions(max_splats_per_tile=700, compression=RAW)
    )
    assert summary.bytes < raw.bytes / 3  # random values compress less than trained splats
    assert (
        "extensionsRequired"
        not in json.loads((tmp_path / "raw" / "tileset.json").read_text())["extensions"]["3DTILES_content_gltf"]
    )


def test_ecef_of_every_splat_matches_pyproj_within_a_millimetre(tmp_path):
    """Exact placement, UTM 33N at (500 000 E, 4 000 000 N, 100 m), a 1 km × 1 km × 100 m set."""
    gs = _splats(3000)
    gs.means[:4] = [[-500, -500, -50], [500, 500, 50], [500, -500, 0], [-500, 500, 50]]  # the far corners
    out = tmp_path / "tileset.json"
    summary = write_splat_tileset(gs, out, UTM, TilesetOptions(compression=RAW, max_splats_per_tile=1000))
    ids, ecef = _ecef(out)
    err = np.linalg.norm(ecef - _truth(gs, ids), axis=1)
    print(f"exact placement: worst ECEF error {err.max() * 1e3:.4f} mm over {len(err)} splats")
    assert err.max() < 1e-3
    assert summary.placement_error_m < 1e-3
    root = np.asarray(json.loads(out.read_text())["root"]["transform"]).reshape(4, 4).T
    assert np.allclose(root[:3, :3].T @ root[:3, :3], np.eye(3), atol=1e-12)  # rigid ENU frame
    origin_ecef = pyproj.Transformer.from_crs(UTM, "EPSG:4978", always_xy=True).transform(*ORIGIN)
    assert np.array_equal(root[:3, 3], origin_ecef)
    assert summary.convergence_deg == pytest.approx(0.0, abs=1e-9)
    assert summary.scale_factor == pytest.approx(0.9996, abs=1e-9)


def test_exact_placement_maps_shapes_and_view_dependent_colour(tmp_path):
    """East of the central meridian (convergence 0.66°): covariances follow the true local → ECEF map, and the
    rotated SH give the same colour along the same physical direction."""
    from scipy.spatial.transform import Rotation

    gs = _splats(60, extent=300, degree=2, seed=4, origin=ORIGIN_EAST, layers=False)
    before = [a.copy() for a in (gs.means, gs.quats, gs.log_scales, gs.sh_rest)]
    out = tmp_path / "tileset.json"
    summary = write_splat_tileset(gs, out, UTM, TilesetOptions(compression=RAW, max_splats_per_tile=1000))
    assert all(
        np.array_equal(a, b) for a, b in zip(before, (gs.means, gs.quats, gs.log_scales, gs.sh_rest), strict=True)
    )
    expected = pyproj.Proj(UTM).get_factors(
        *pyproj.Transformer.from_crs(UTM, "EPSG:4326", always_xy=True).transform(ORIGIN_EAST[0], ORIGIN_EAST[1])
    )
    assert summary.convergence_deg == pytest.approx(expected.meridian_convergence, abs=1e-9)
    assert summary.grid_north_azimuth_deg == pytest.approx(summary.convergence_deg, abs=1e-6)
    ((_tile, t, _a, prim, _doc),) = list(_contents(out))
    frame_rot = t[:3, :3]  # tile frame → ECEF (rotation, exact placement)
    to_ecef = pyproj.Transformer.from_crs(UTM, "EPSG:4978", always_xy=True)

    def tile_frame(local):  # pyproj's ECEF, expressed in the tile frame's axes
        return np.c_[to_ecef.transform(*(gs.origin + local).T)] @ frame_rot

    ids = prim.sh[:, 0, 0].astype(np.int64)
    rot = Rotation.from_quat(gs.quats[ids][:, [1, 2, 3, 0]]).as_matrix()
    axes = rot * gs.scales[ids].astype(np.float64)[:, None, :]  # columns: σ-scaled principal axes (local)
    for k, i in enumerate(ids):
        m = gs.means[i]
        spread = np.stack([tile_frame(np.stack([m + a, m - a])) for a in axes[k].T])  # (3 axes, 2, 3)
        mapped = (spread[:, 0] - spread[:, 1]) / 2.0
        sigma = mapped.T @ mapped  # Σ' = Σₐ Δₐ Δₐᵀ through the true map
        r = Rotation.from_quat(prim.rotations[k]).as_matrix()
        ours = r @ np.diag(prim.scales[k].astype(np.float64) ** 2) @ r.T
        # the Jacobian is taken at the origin: not applied, the vertical's tilt by r / R at distance r and the
        # horizontal scale's change by Δh / R at height difference Δh (plus float32 storage, ~1e-6)
        change = (np.linalg.norm(m[:2]) + abs(m[2])) / EARTH_RADIUS
        assert np.abs(ours - sigma).max() <= (2 * change + 1e-6) * np.abs(sigma).max()
        for v in np.eye(3):  # a local viewing direction and the same physical direction in the tile frame
            d = np.diff(tile_frame(np.stack([m, m + v])), axis=0)[0]
            colour_local = _sh_rgb(gs.sh_coeffs[i].astype(np.float64), v, 2)
            colour_tile = _sh_rgb(prim.sh[k].astype(np.float64), d / np.linalg.norm(d), 2)
            assert np.abs(colour_local - colour_tile).max() < 1e-3  # J is a rotation up to 3e-4 anisotropy


def test_grid_placement_keeps_local_positions_and_errs_by_the_earths_curvature(tmp_path):
    gs = _splats(2000, origin=ORIGIN_EAST)
    out = tmp_path / "tileset.json"
    summary = write_splat_tileset(
        gs, out, UTM, TilesetOptions(compression=RAW, max_splats_per_tile=800, placement=Placement.GRID)
    )
    for *_, prim, _doc in _contents(out):
        ids = prim.sh[:, 0, 0].astype(np.int64)
        assert np.array_equal(prim.positions, gs.means[ids].astype(np.float32))  # the set's local frame, exactly
    ids, ecef = _ecef(out)
    err = np.linalg.norm(ecef - _truth(gs, ids), axis=1)
    r = np.linalg.norm(gs.means[ids, :2], axis=1)
    dh = np.abs(gs.means[ids, 2])
    # the sagitta r²/2R and the height factor's change r·Δh/R, nothing else (5 % for the ellipsoid's radii)
    assert (err <= (r**2 / 2 + r * dh) / EARTH_RADIUS * 1.05 + 1e-5).all()
    assert err[(r < 100) & (dh < 10)].max() < 1e-3
    assert summary.placement_error_m == pytest.approx(err.max(), rel=0.2)
    k = summary.scale_factor
    assert summary.transform_scale[0] == pytest.approx(1 / k * (1 + ORIGIN_EAST[2] / EARTH_RADIUS), rel=1e-5)


def test_without_crs_the_origin_is_a_translation(tmp_path):
    gs = _splats(1500, layers=False)
    out = tmp_path / "tileset.json"
    summary = write_splat_tileset(gs, out, None, TilesetOptions(compression=RAW, max_splats_per_tile=1000))
    root = np.asarray(json.loads(out.read_text())["root"]["transform"]).reshape(4, 4).T
    assert np.array_equal(root[:3, :3], np.eye(3)) and np.array_equal(root[:3, 3], ORIGIN)
    ids, world = _ecef(out)
    expected = gs.origin + gs.means[ids].astype(np.float32).astype(np.float64)
    assert np.abs(world - expected).max() < 1e-9
    assert summary.placement == "none" and not summary.georeferenced and "not georeferenced" in summary.notes[0]
    assert [layer.name for layer in summary.layers] == ["survey"]


def test_geocentric_crs_offsets_are_placed_exactly(tmp_path):
    origin = np.array(pyproj.Transformer.from_crs(UTM, "EPSG:4978", always_xy=True).transform(*ORIGIN))
    gs = _splats(500, extent=400, origin=origin, layers=False)  # local offsets are ECEF metres here
    out = tmp_path / "tileset.json"
    summary = write_splat_tileset(gs, out, "EPSG:4978", RAW_OPTIONS)
    ids, ecef = _ecef(out)
    assert np.linalg.norm(ecef - (origin + gs.means[ids]), axis=1).max() < 1e-4  # float32 of ≤ 400 m
    assert summary.convergence_deg is None and summary.transform_scale == pytest.approx((1, 1, 1))


def test_us_survey_feet_are_converted_and_a_datum_fallback_is_reported(tmp_path):
    crs = "EPSG:2263"  # NAD83 / New York Long Island (ftUS): local offsets and σ are in US survey feet
    gs = _splats(300, extent=1000, origin=[987000.0, 200000.0, 30.0], layers=False)
    gs.log_scales[:] = 0.0  # σ = 1 ftUS on every axis
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        best = pyproj.transformer.TransformerGroup(crs, "EPSG:4978", always_xy=True).best_available
    out = tmp_path / "tileset.json"
    with pytest.warns(TilesetWarning) as caught:
        summary = write_splat_tileset(gs, out, crs, RAW_OPTIONS)
    messages = [str(w.message) for w in caught]
    # pyproj takes a 2D CRS's heights in metres: mixed units are reported
    assert any("0.3048" in m and "along z" in m for m in messages)
    if not best:  # NAD83 → WGS 84 needs a grid that is not installed: the fallback and its accuracy are reported
        assert any("not installed" in m and "accuracy" in m for m in messages)
    assert len(summary.notes) == len(messages) + 1
    ids, ecef = _ecef(out)
    assert np.linalg.norm(ecef - _truth(gs, ids, crs), axis=1).max() < 1e-3
    ((*_, prim, _doc),) = list(_contents(out))
    ft = 1200 / 3937  # 1 ftUS in metres; the scale factor is within 1e-4 of 1 here
    assert np.allclose(np.sort(prim.scales, axis=1), [ft, ft, 1.0], rtol=1e-4)


def test_rewrite_removes_our_stale_tiles_only(tmp_path):
    out = tmp_path / "tileset.json"
    write_splat_tileset(_splats(3000), out, None, TilesetOptions(compression=RAW, max_splats_per_tile=300))
    (tmp_path / "survey" / "notes.txt").write_text("mine")
    before = sorted(p.name for p in (tmp_path / "survey").glob("*.glb"))
    summary = write_splat_tileset(
        _splats(800, layers=False), out, None, TilesetOptions(compression=RAW, max_splats_per_tile=1000)
    )
    assert len(before) > 1 and sorted(p.name for p in (tmp_path / "survey").glob("*.glb")) == ["r.glb"]
    assert not list((tmp_path / "fill").glob("*")) and (tmp_path / "survey" / "notes.txt").exists()
    assert [t.uri for t in summary.tiles] == ["survey/r.glb"]


@pytest.mark.parametrize(
    ("crs", "error", "words"),
    [
        ("EPSG:999999", ConfigError, "unknown CRS"),
        ("not a crs", ConfigError, "unknown CRS"),
        ("EPSG:4326", ConfigError, "geographic"),
    ],
)
def test_unusable_crs_is_refused_naming_the_file(tmp_path, crs, error, words):
    out = tmp_path / "t" / "tileset.json"
    with pytest.raises(error, match=words) as err:
        write_splat_tileset(_splats(10), out, crs)
    assert err.value.path == out and not (tmp_path / "t").exists()


def test_westing_southing_axes_are_placed_and_left_handed_axes_refused(tmp_path):
    # South African Lo29 (EPSG:2053): westing / southing axes, east / north turned by 180°: a proper rotation
    lo29 = _splats(300, extent=200, origin=[10000.0, 2900000.0, 1500.0], layers=False)
    out = tmp_path / "lo29" / "tileset.json"
    write_splat_tileset(lo29, out, "EPSG:2053", RAW_OPTIONS)
    ids, ecef = _ecef(out)
    assert np.linalg.norm(ecef - _truth(lo29, ids, "EPSG:2053"), axis=1).max() < 1e-3
    # east / south / up is a mirror image of east / north / up: no rotation places it
    esu = "+proj=tmerc +lon_0=15 +k=0.9996 +x_0=500000 +datum=WGS84 +axis=esu +units=m +type=crs"
    out = tmp_path / "esu" / "tileset.json"
    with pytest.raises(ConfigError, match="right-handed") as err:
        write_splat_tileset(_splats(10, origin=[500000.0, -4000000.0, 100.0]), out, esu)
    assert err.value.path == out


def test_ballpark_datum_transformation_is_refused(tmp_path):
    crs = "EPSG:32633+5773"  # UTM 33N + EGM96 heights: needs the EGM96 geoid grid
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # pyproj: "best transformation is not available"
        group = pyproj.transformer.TransformerGroup(crs, "EPSG:4978", always_xy=True)
    if not group.transformers or "ballpark" not in group.transformers[0].description.lower():
        pytest.skip("the EGM96 grid is installed here: the transformation is not a ballpark one")
    with pytest.raises(ConfigError, match="ballpark"):
        write_splat_tileset(_splats(10), tmp_path / "tileset.json", crs)


def test_bad_input_is_refused_naming_the_file(tmp_path):
    out = tmp_path / "tileset.json"
    empty = _splats(5).subset(np.zeros(5, bool))
    with pytest.raises(DataError, match="empty") as err:
        write_splat_tileset(empty, out, UTM)
    assert err.value.path == out
    for attr in ("means", "sh_rest", "log_scales"):
        gs = _splats(20, degree=1)
        getattr(gs, attr).reshape(20, -1)[7, 0] = np.nan
        with pytest.raises(DataError, match=f"NaN or infinite {attr}") as err:
            write_splat_tileset(gs, out, UTM)
        assert err.value.path == out
    gs = _splats(20)
    gs.origin[0] = np.inf
    with pytest.raises(DataError, match="origin"):
        write_splat_tileset(gs, out, UTM)
    with pytest.raises(ConfigError, match="max_splats_per_tile"):
        TilesetOptions(max_splats_per_tile=0)
    with pytest.raises(ConfigError, match="placement"):
        TilesetOptions(placement="curved")
    with pytest.raises(ConfigError, match=".json"):
        write_splat_tileset(_splats(5), tmp_path / "tileset.glb", UTM)
    assert list(tmp_path.iterdir()) == []


def test_colour_space_is_recorded_and_linear_colours_are_not_decoded():
    gs = _splats(10, layers=False)
    doc, _ = _glb(encode_splat_glb(gs, ColorSpace.LINEAR))
    assert doc["meshes"][0]["primitives"][0]["extensions"][EXTENSION]["colorSpace"] == "lin_rec709_display"
    back = read_splat_glb(encode_splat_glb(gs, ColorSpace.LINEAR))
    base = np.clip(0.5 + SH_C0 * gs.sh_dc.astype(np.float64), 0, 1)
    assert np.abs(back.colors[:, :3] - base).max() <= 0.5 / 255 + 1e-6


# -- optional: independent readers (node packages installed by scripts/check_gltf_tiles.sh; never at test time) -----


def _tool_prefix() -> Path:
    return gltf_tools_prefix()


@pytest.mark.parametrize("compression", ["spz", "none"])
def test_gltf_validator_and_loaders_gl_accept_our_tiles_at_the_right_place(tmp_path, compression):
    """glTF-Validator finds no error (but the known ones, see the script) and loaders.gl's reading of our transforms
    puts each tile's first splat where pyproj does (SPZ tiles: the script decodes the splat from the GLB bytes and
    checks the stream's header, counts and required extensions; the splat is identified by its position)."""
    prefix = _tool_prefix()
    gs = (
        _splats(1200, degree=1, origin=ORIGIN_EAST)
        if compression == "none"
        else _spz_ready(1200, 500.0, 1, 0, ORIGIN_EAST)
    )
    out = tmp_path / "tileset.json"
    write_splat_tileset(gs, out, UTM, TilesetOptions(compression=compression, max_splats_per_tile=500))
    script = Path(__file__).resolve().parents[1] / "scripts" / "check_gltf_tiles.sh"
    env = {**os.environ, "GT_PREFIX": str(prefix), "GT_NO_INSTALL": "1", "ST": "/nonexistent"}
    proc = subprocess.run(["bash", str(script), str(out)], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0 and "errors: 0" in proc.stdout, proc.stdout + proc.stderr
    rows = [line.split()[2:] for line in proc.stdout.splitlines() if line.startswith("TILE ")]
    assert len(rows) == len(list(_contents(out)))
    ids = np.array([int(float(r[0])) for r in rows])
    ecef = np.array([[float(v) for v in r[1:4]] for r in rows])
    assert {r[4] for r in rows} == {"spz" if compression == "spz" else "float"}
    if compression == "spz":  # no id in an SPZ stream: the nearest true splat, which must be within SPZ's precision
        assert (ids == -1).all()
        ids, _ = _nearest_ids(ecef, _truth(gs, np.arange(len(gs))))
    assert np.linalg.norm(ecef - _truth(gs, ids), axis=1).max() < 1e-3  # printed to 1 µm


def test_summary_lines_report_the_placement(tmp_path):
    summary = write_splat_tileset(_spz_ready(100, 500.0, 0, origin=ORIGIN_EAST), tmp_path / "tileset.json", UTM)
    text = "\n".join(summary.lines())
    assert "EPSG:32633" in text and "convergence 0.65" in text and "scale factor 0.9997" in text
    assert "SPZ v2 (14 fractional bits or more): positions within 30.5 µm" in text  # ±500 m: 2^-15 m
    assert summary.position_quantisation_m == 2.0**-15
    assert math.isfinite(summary.placement_error_m)
