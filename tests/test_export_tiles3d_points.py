"""The survey points (a 3D Tiles point-cloud layer) and the mesh beside the splats of a tileset (fusion.tiles3d_points).

Truth is independent of the writer: pyproj's ECEF (EPSG:4978) of origin + local and back, composed here from the
tileset's root transform (column-major), the 3D Tiles y-up → z-up rotation as printed in the spec and each GLB's node
matrix as stored; GLBs are decoded with pygltflib and numpy; points are matched to the input by brute-force nearest
neighbours (a point carries no id). Tolerance 1 mm: float32 tile-frame positions round by ≤ 0.5 ulp (3e-5 m at 500 m)
and the exact placement is below 0.02 mm over a 1 km set (tests/test_export_tiles3d.py).
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pyproj
import pytest
from npm_readers import gltf_tools_prefix

from core.errors import ConfigError, DataError
from core.gaussians import GaussianSet
from core.io import write_point_cloud
from core.io.origin import write_origin
from core.pointcloud import PointCloud
from fusion.mesh.export import write_mesh
from fusion.mesh.types import TriangleMesh
from fusion.tiles3d import TilesetOptions, write_splat_tileset

UTM32 = "EPSG:32632"
ORIGIN = np.array([500000.0, 5000000.0, 120.0])  # zone 32's central meridian at 45° N
Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])  # 3D Tiles 1.1, row-major
MM = 1e-3


def _splats(n: int = 200, seed: int = 0, origin=ORIGIN) -> GaussianSet:
    rng = np.random.default_rng(seed)
    return GaussianSet(
        np.c_[rng.uniform(-300, 300, (n, 2)), rng.uniform(-20, 20, n)],
        rng.normal(-3.0, 1.0, (n, 3)),
        rng.normal(size=(n, 4)),
        rng.normal(0.0, 3.0, n),
        rng.normal(size=(n, 3)).astype(np.float32),
        np.zeros((n, 0, 3), np.float32),
        origin=np.array(origin, np.float64),
        fields={"source": rng.choice(np.array([1, 2], np.uint8), n)},
    )


def _cloud(n: int, seed: int = 1, origin=ORIGIN + [3.25, -7.5, 0.75]) -> PointCloud:
    """Random points in ±400 m horizontally and ±30 m vertically about their own origin (not the splats')."""
    rng = np.random.default_rng(seed)
    positions = np.c_[rng.uniform(-400, 400, (n, 2)), rng.uniform(-30, 30, n)]
    return PointCloud(positions, np.array(origin, np.float64), colors=rng.integers(0, 256, (n, 3), dtype=np.uint8))


def _ecef(world: np.ndarray, crs: str = UTM32) -> np.ndarray:
    x, y, z = pyproj.Transformer.from_crs(crs, "EPSG:4978", always_xy=True).transform(*world.T)
    return np.c_[x, y, z]


def _from_ecef(ecef: np.ndarray, crs: str = UTM32) -> np.ndarray:
    x, y, z = pyproj.Transformer.from_crs("EPSG:4978", crs, always_xy=True).transform(*ecef.T)
    return np.c_[x, y, z]


def _read_glb(path: Path) -> dict[str, np.ndarray]:
    """POSITION, COLOR_0 (as stored), indices and the node matrix (row-major) of a one-primitive GLB (pygltflib)."""
    import pygltflib

    doc = pygltflib.GLTF2.load_from_bytes(path.read_bytes())
    blob = doc.binary_blob()
    dtypes = {5126: "<f4", 5121: "<u1", 5125: "<u4", 5123: "<u2"}
    comps = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}

    def accessor(index: int) -> np.ndarray:
        acc = doc.accessors[index]
        view = doc.bufferViews[acc.bufferView]
        assert view.byteStride in (None, 0)
        start = (view.byteOffset or 0) + (acc.byteOffset or 0)
        n = comps[acc.type]
        return np.frombuffer(blob, dtypes[acc.componentType], acc.count * n, start).reshape(acc.count, n)

    prim = doc.meshes[0].primitives[0]
    out = {"POSITION": accessor(prim.attributes.POSITION), "mode": np.array(prim.mode)}
    if prim.attributes.COLOR_0 is not None:
        assert doc.accessors[prim.attributes.COLOR_0].normalized
        out["COLOR_0"] = accessor(prim.attributes.COLOR_0)
    if prim.indices is not None:
        out["indices"] = accessor(prim.indices).reshape(-1, 3)
    out["node"] = np.asarray(doc.nodes[0].matrix, np.float64).reshape(4, 4).T
    assert len(doc.nodes) == 1 and doc.nodes[0].mesh == 0
    return out


def _tile_frame(glb: dict[str, np.ndarray]) -> np.ndarray:
    """(N, 3) float64 tile-frame positions: y-up → z-up (3D Tiles) · node matrix · POSITION."""
    p = np.c_[glb["POSITION"].astype(np.float64), np.ones(len(glb["POSITION"]))]
    return (p @ (Y_UP_TO_Z_UP @ glb["node"]).T)[:, :3]


def _walk(tile: dict, parent: np.ndarray, ancestors: list):
    t = parent @ np.asarray(tile.get("transform", np.eye(4).reshape(-1)), float).reshape(4, 4).T
    yield tile, t, ancestors
    for child in tile.get("children", []):
        yield from _walk(child, t, [*ancestors, tile])


def _contents(out: Path, layer: str):
    """(tile, tile → ECEF transform, ancestors, decoded GLB) of every content of metadata group ``layer``."""
    tileset = json.loads(out.read_text())
    names = [g["properties"]["name"] for g in tileset["groups"]]
    for tile, t, ancestors in _walk(tileset["root"], np.eye(4), []):
        if "content" in tile and names[tile["content"]["group"]] == layer:
            yield tile, t, ancestors, _read_glb(out.parent / tile["content"]["uri"])


def _world_points(out: Path, crs: str | None, layer: str = "survey points"):
    """Every point of ``layer``: world coordinates (pyproj back from ECEF, or the transform without a CRS), colours."""
    world, colors = [], []
    for _tile, t, _anc, glb in _contents(out, layer):
        chain = t @ Y_UP_TO_Z_UP @ glb["node"]
        p = np.c_[glb["POSITION"].astype(np.float64), np.ones(len(glb["POSITION"]))] @ chain.T
        world.append(_from_ecef(p[:, :3], crs) if crs else p[:, :3])
        colors.append(glb.get("COLOR_0", np.zeros((len(p), 4), np.uint8)))
    return np.concatenate(world), np.concatenate(colors)


def _match(found: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from scipy.spatial import cKDTree

    dist, ids = cKDTree(truth).query(found)
    return ids, dist


# -- (a) the points are placed exactly ------------------------------------------------------------------------------


def test_survey_points_land_on_their_world_positions_through_pyproj(tmp_path):
    """UTM 32N, points about their own origin (3.25 m, −7.5 m, 0.75 m from the splats'): ECEF through the written
    transforms, back to UTM with pyproj, within 1 mm of origin + local; every point once, its colour unchanged."""
    gs, cloud = _splats(), _cloud(4000)
    out = tmp_path / "tiles" / "tileset.json"
    summary = write_splat_tileset(gs, out, UTM32, TilesetOptions(max_splats_per_tile=1500), points=cloud)
    tileset = json.loads(out.read_text())
    groups = [g["properties"] for g in tileset["groups"]]
    assert [g["name"] for g in groups] == ["survey", "fill", "survey points"]
    assert groups[2] == {"name": "survey points", "kind": "points"} and groups[0]["kind"] == "splats"
    # median splits: 4000 → 2 × 2000 → 4 × 1000 (≤ 1500)
    assert [c["content"]["uri"].split("/")[0] for c, *_ in _contents(out, "survey points")] == ["survey_points"] * 4

    world, colors = _world_points(out, UTM32)
    ids, dist = _match(world, cloud.world_positions)
    print(f"survey points: worst error {dist.max() * 1e3:.4f} mm over {len(dist)} points (UTM back from ECEF)")
    assert len(world) == len(cloud) and np.array_equal(np.sort(ids), np.arange(len(cloud)))
    assert dist.max() < MM
    assert np.array_equal(colors[:, :3], cloud.colors[ids]) and (colors[:, 3] == 255).all()
    # the same in ECEF, pyproj forward
    ecef = _ecef(world)
    assert np.linalg.norm(ecef - _ecef(cloud.world_positions[ids]), axis=1).max() < MM

    layer = next(r for r in summary.layers if r.name == "survey points")
    assert (layer.kind, layer.source, layer.splats, layer.tiles) == ("points", None, 4000, 4)
    assert summary.splats == len(gs) and summary.bytes == sum(
        (out.parent / t.uri).stat().st_size for t in summary.tiles
    )
    alone = json.loads((out.parent / "survey_points" / "tileset.json").read_text())  # for CesiumJS: no splat ext.
    assert alone["root"]["transform"] == tileset["root"]["transform"]
    assert "extensionsRequired" not in alone["extensions"]["3DTILES_content_gltf"]
    assert "KHR_gaussian_splatting" in tileset["extensions"]["3DTILES_content_gltf"]["extensionsRequired"]


# -- (b) k-d tiling and bounding volumes ----------------------------------------------------------------------------


def test_points_are_kd_tiled_and_every_box_encloses_its_points(tmp_path):
    """Without a CRS the tile frame is the splats' world frame: the root transform is the splats' origin and the
    points' float32 positions are their offsets about it. 2 500 points at most 300 a tile: ≥ 9 leaves, each point in
    exactly one, every box (leaf, parents, root) holds them; a rewrite without points removes the layer's files."""
    gs, cloud = _splats(), _cloud(2500, origin=ORIGIN + [100.0, 50.0, -2.0])
    out = tmp_path / "tileset.json"
    write_splat_tileset(gs, out, None, TilesetOptions(max_splats_per_tile=300), points=cloud)
    counts = []
    for tile, _t, ancestors, glb in _contents(out, "survey points"):
        frame = _tile_frame(glb)
        assert int(glb["mode"]) == 0 and tile["geometricError"] == 0  # POINTS
        counts.append(len(frame))
        for box_tile in [tile, *ancestors]:
            box = np.asarray(box_tile["boundingVolume"]["box"])
            assert np.count_nonzero(box[3:]) == 3 and box[[3, 7, 11]].min() > 0
            assert (np.abs(frame - box[:3]) <= box[[3, 7, 11]]).all()
        for parent, child in zip(ancestors[1:], [*ancestors[2:], tile], strict=True):
            assert parent["geometricError"] >= child["geometricError"] and "content" not in parent
    assert len(counts) >= int(np.ceil(2500 / 300)) and max(counts) <= 300 and sum(counts) == 2500
    world, _ = _world_points(out, None)
    ids, dist = _match(world, cloud.world_positions)
    assert np.array_equal(np.sort(ids), np.arange(2500)) and dist.max() < MM

    write_splat_tileset(gs, out, None, TilesetOptions(max_splats_per_tile=300))
    assert not [p for p in (out.parent / "survey_points").rglob("*") if p.is_file()]
    assert [g["properties"]["name"] for g in json.loads(out.read_text())["groups"]] == ["survey", "fill"]


# -- (c) the mesh ---------------------------------------------------------------------------------------------------


def _mesh(origin=ORIGIN + [-12.5, 20.0, 1.5], seed: int = 2) -> TriangleMesh:
    """A 15 × 15 height field over ±250 m (vertices about their own origin), coloured."""
    rng = np.random.default_rng(seed)
    g = np.linspace(-250.0, 250.0, 15)
    x, y = np.meshgrid(g, g)
    vertices = np.c_[x.ravel(), y.ravel(), rng.uniform(-10, 10, x.size)]
    quads = [(r * 15 + c, r * 15 + c + 1, (r + 1) * 15 + c + 1, (r + 1) * 15 + c) for r in range(14) for c in range(14)]
    triangles = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    return TriangleMesh(vertices, triangles, np.array(origin, np.float64), rng.uniform(0, 1, (x.size, 3)))


def _write_mesh(path: Path, mesh: TriangleMesh, crs: str | None = UTM32) -> Path:
    write_mesh(path, mesh)
    write_origin(path, mesh.origin, crs)  # as the mesh stage does: the sidecar carries the CRS
    return path


def test_mesh_vertices_land_on_their_world_positions(tmp_path):
    mesh = _mesh()
    glb_in = _write_mesh(tmp_path / "in" / "mesh.glb", mesh)
    out = tmp_path / "tiles" / "tileset.json"
    summary = write_splat_tileset(_splats(), out, UTM32, points=_cloud(300), mesh=glb_in)
    groups = [g["properties"] for g in json.loads(out.read_text())["groups"]]
    assert groups[-1] == {"name": "mesh", "kind": "mesh"}
    (tile, t, _anc, glb), *rest = list(_contents(out, "mesh"))
    assert not rest and tile["content"]["uri"] == "mesh/mesh.glb" and int(glb["mode"]) == 4  # TRIANGLES
    chain = t @ Y_UP_TO_Z_UP @ glb["node"]
    ecef = (np.c_[glb["POSITION"].astype(np.float64), np.ones(len(glb["POSITION"]))] @ chain.T)[:, :3]
    truth = mesh.vertices + mesh.origin
    ids, dist = _match(_from_ecef(ecef), truth)
    print(f"mesh: worst error {dist.max() * 1e3:.4f} mm over {len(dist)} vertices")
    assert np.array_equal(np.sort(ids), np.arange(len(truth))) and dist.max() < MM
    assert np.linalg.norm(ecef - _ecef(truth[ids]), axis=1).max() < MM
    faces = {tuple(sorted(f)) for f in ids[glb["indices"]]}
    assert faces == {tuple(sorted(f)) for f in mesh.triangles}
    expected = np.rint(mesh.vertex_colors[ids] * 255).astype(np.uint8)
    assert np.abs(glb["COLOR_0"][:, :3].astype(int) - expected).max() <= 1  # trimesh's own 8-bit rounding
    box = np.asarray(tile["boundingVolume"]["box"])
    frame = _tile_frame(glb)
    assert (np.abs(frame - box[:3]) <= box[[3, 7, 11]]).all()
    record = next(r for r in summary.layers if r.name == "mesh")
    assert (record.kind, record.splats, record.tiles, record.tileset) == ("mesh", len(truth), 1, "mesh/tileset.json")


# -- bad input ------------------------------------------------------------------------------------------------------


def test_bad_points_and_meshes_are_refused_naming_the_file_and_nothing_is_written(tmp_path):
    out = tmp_path / "tiles" / "tileset.json"
    gs = _splats()
    nan = _cloud(10)
    nan.positions[3, 1] = np.nan
    for bad, words in ((_cloud(0), "empty"), (nan, "NaN")):
        with pytest.raises(DataError, match=words) as err:
            write_splat_tileset(gs, out, UTM32, points=bad)
        assert str(out) in str(err.value)
    other_crs = tmp_path / "p33.ply"
    write_point_cloud(other_crs, _cloud(10))
    write_origin(other_crs, _cloud(10).origin, "EPSG:32633")
    with pytest.raises(ConfigError, match="EPSG:32633") as err:
        write_splat_tileset(gs, out, UTM32, points=other_crs)
    assert str(other_crs) in str(err.value)

    not_glb = tmp_path / "m.glb"
    not_glb.write_bytes(b"solid nothing\n")
    with pytest.raises(DataError, match="not a GLB") as err:
        write_splat_tileset(gs, out, UTM32, mesh=not_glb)
    assert str(not_glb) in str(err.value)
    ply = tmp_path / "m.ply"
    write_mesh(ply, _mesh())
    with pytest.raises(ConfigError, match=r"\.glb"):
        write_splat_tileset(gs, out, UTM32, mesh=ply)
    mesh33 = _write_mesh(tmp_path / "m33" / "mesh.glb", _mesh(), "EPSG:32633")
    with pytest.raises(ConfigError, match="EPSG:32633") as err:
        write_splat_tileset(gs, out, UTM32, mesh=mesh33)
    assert str(mesh33) in str(err.value)
    no_sidecar = tmp_path / "bare" / "mesh.glb"  # vertices about (0, 0, 0): 5 000 km from the splats
    write_mesh(no_sidecar, _mesh(origin=np.zeros(3)))
    with pytest.raises(DataError, match="origin sidecar") as err:
        write_splat_tileset(gs, out, UTM32, points=_cloud(10), mesh=no_sidecar)
    assert str(no_sidecar) in str(err.value)
    assert not out.parent.exists()


# -- (d, e) independent readers: glTF-Validator and loaders.gl -----------------------------------------------------

_NODE_SCRIPT = r"""
const fs = require('node:fs');
const http = require('node:http');
const path = require('node:path');
const {load} = require('@loaders.gl/core');
const {Tiles3DLoader} = require('@loaders.gl/3d-tiles');
const validator = require('gltf-validator');
const file = path.resolve(process.argv[2]);
const root = path.dirname(file);
const Y_UP_TO_Z_UP = [1, 0, 0, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 1]; // column-major
function mul(a, b) {
  const r = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) {
    for (let rr = 0; rr < 4; rr++) for (let k = 0; k < 4; k++) r[c * 4 + rr] += a[k * 4 + rr] * b[c * 4 + k];
  }
  return r;
}
const server = http.createServer((req, res) => {
  const p = path.join(root, decodeURIComponent(new URL(req.url, 'http://x').pathname));
  if (!p.startsWith(root) || !fs.existsSync(p)) { res.writeHead(404); res.end(); return; }
  res.writeHead(200); res.end(fs.readFileSync(p));
});
server.listen(0, '127.0.0.1', async () => {
  const result = {contents: {}, issues: [], tiles: 0};
  try {
    const base = `http://127.0.0.1:${server.address().port}/`;
    const tileset = await load(base + path.basename(file), Tiles3DLoader);
    const rootTransform = tileset.root.transform;
    const stack = [tileset.root];
    while (stack.length) {
      const tile = stack.pop();
      result.tiles++;
      for (const child of tile.children || []) stack.push(child);
      if (!tile.contentUrl) continue;
      const uri = tile.contentUrl.slice(base.length);
      if (!uri.startsWith('survey_points/') && !uri.startsWith('mesh/')) continue;
      const content = await load(tile.contentUrl, Tiles3DLoader, {'3d-tiles': {loadGLTF: true}});
      const prim = content.gltf.meshes[0].primitives[0];
      const turn = content.rotateYtoZ ? Y_UP_TO_Z_UP : [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
      const m = mul(mul(rootTransform, turn), content.gltf.nodes[0].matrix);
      const p = prim.attributes.POSITION.value;
      const ecef = [];
      for (let i = 0; i < p.length; i += 3) {
        for (let r = 0; r < 3; r++) ecef.push(m[r] * p[i] + m[4 + r] * p[i + 1] + m[8 + r] * p[i + 2] + m[12 + r]);
      }
      result.contents[uri] = {ecef, type: content.type, mode: prim.mode};
      const bytes = new Uint8Array(fs.readFileSync(path.join(root, uri)));
      const report = await validator.validateBytes(bytes, {maxIssues: 1000});
      for (const msg of report.issues.messages) {
        result.issues.push({uri, severity: msg.severity, code: msg.code, message: msg.message});
      }
    }
  } catch (e) {
    result.error = String(e.stack || e);
  }
  fs.writeFileSync(process.argv[3], JSON.stringify(result));
  server.close();
});
"""


def test_gltf_validator_and_loaders_gl_read_the_points_and_the_mesh_where_pyproj_puts_them(tmp_path):
    """glTF-Validator: no error and no warning in a point tile or the mesh tile; loaders.gl's Tiles3DLoader loads the
    tileset (SPZ splats beside) and its positions, through loaders.gl's root transform, lie within 1 mm of pyproj's
    ECEF of every point and vertex."""
    prefix = gltf_tools_prefix()
    cloud, mesh = _cloud(1500), _mesh()
    glb_in = _write_mesh(tmp_path / "in" / "mesh.glb", mesh)
    out = tmp_path / "tiles" / "tileset.json"
    write_splat_tileset(_splats(), out, UTM32, TilesetOptions(max_splats_per_tile=600), points=cloud, mesh=glb_in)
    script, report = tmp_path / "check.cjs", tmp_path / "report.json"
    script.write_text(_NODE_SCRIPT)
    env = {**os.environ, "NODE_PATH": str(prefix / "node_modules")}
    proc = subprocess.run(
        ["node", str(script), str(out), str(report)], capture_output=True, text=True, timeout=300, env=env
    )
    assert proc.returncode == 0 and report.is_file(), proc.stdout + proc.stderr
    result = json.loads(report.read_text())
    assert "error" not in result, result.get("error")
    bad = [i for i in result["issues"] if i["severity"] <= 1]  # 0 error, 1 warning
    assert not bad, bad
    uris = sorted(result["contents"])
    assert uris == ["mesh/mesh.glb"] + sorted(u for u in uris if u.startswith("survey_points/"))
    assert len(uris) == 1 + 4  # 1500 points at most 600 a tile: median splits into 4 × 375
    points = np.concatenate([np.reshape(result["contents"][u]["ecef"], (-1, 3)) for u in uris[1:]])
    ids, dist = _match(points, _ecef(cloud.world_positions))
    assert np.array_equal(np.sort(ids), np.arange(len(cloud))) and dist.max() < MM
    vertices = np.reshape(result["contents"]["mesh/mesh.glb"]["ecef"], (-1, 3))
    ids, dist = _match(vertices, _ecef(mesh.vertices + mesh.origin))
    assert np.array_equal(np.sort(ids), np.arange(len(mesh.vertices))) and dist.max() < MM
    assert [result["contents"][u]["mode"] for u in uris] == [4, 0, 0, 0, 0]


# -- (f) the command line -------------------------------------------------------------------------------------------


def test_export_command_adds_points_and_mesh_to_a_tileset_and_refuses_them_elsewhere(tmp_path, capsys):
    from fusion.export import ExportOptions, export_gaussian_ply
    from hybridsplat.cli import run_cli

    merged = tmp_path / "export" / "merged.ply"
    export_gaussian_ply(merged, _splats(), ExportOptions(crs=UTM32, extra_fields=True, min_opacity=0))
    points = tmp_path / "export" / "merged_points.ply"
    cloud = _cloud(500)
    write_point_cloud(points, cloud)
    write_origin(points, cloud.origin, UTM32)
    mesh = _write_mesh(tmp_path / "export" / "mesh.glb", _mesh())
    out = tmp_path / "tiles" / "tileset.json"
    args = ["export", str(merged), "--out", str(out), "--survey-points", str(points), "--mesh", str(mesh)]
    assert run_cli(args) == 0
    text = capsys.readouterr().out
    assert "layer survey points: 500 points, 1 tiles" in text and "layer mesh: 225 vertices" in text
    groups = [g["properties"]["name"] for g in json.loads(out.read_text())["groups"]]
    assert groups[-2:] == ["survey points", "mesh"]
    world, _ = _world_points(out, UTM32)
    ids, dist = _match(world, cloud.world_positions)
    assert np.array_equal(np.sort(ids), np.arange(500)) and dist.max() < MM  # PLY float32 locals: < 0.05 mm

    spz = tmp_path / "other" / "merged.spz"
    assert run_cli(["export", str(merged), "--out", str(spz), "--out", str(out), "--mesh", str(mesh)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--mesh applies to a tileset.json output only" in err[0] and str(spz) in err[0]
    assert not spz.exists()
    sog = tmp_path / "sog" / "meta.json"  # a .json, but PlayCanvas SOG (unbundled), not 3D Tiles
    assert run_cli(["export", str(merged), "--out", str(sog), "--survey-points", str(points)]) == 2
    assert "--survey-points applies to a tileset.json output only" in capsys.readouterr().err
    assert not sog.exists()


# -- the merge stage ------------------------------------------------------------------------------------------------


def test_merge_stage_tileset_holds_the_survey_points_it_writes(tmp_path):
    """``--viewer-format 3dtiles``: the tileset's point layer is the cloud of export/merged_points.ply (the survey
    points after the exporters' opacity filter: the invisible ones are in neither), placed through pyproj."""
    from types import SimpleNamespace

    from core.io import read_point_cloud
    from fusion.export import export_points
    from hybridsplat.layout import ProjectLayout
    from hybridsplat.stages.merge import _viewer_exports

    layout = ProjectLayout(tmp_path / "p")
    gaussians, survey = _splats(seed=3), _splats(n=800, seed=4)
    survey.logit_opacities[:50] = -20.0  # α ≈ 2e-9: dropped by the exporters
    export_points(layout.merged_points_ply, survey)
    ctx = SimpleNamespace(layout=layout, options=lambda stage: SimpleNamespace(viewer_formats=("3dtiles",)))
    _viewer_exports(ctx, gaussians, survey, UTM32)
    written = read_point_cloud(layout.merged_points_ply)
    world, colors = _world_points(layout.merged_viewer("3dtiles"), UTM32)
    ids, dist = _match(world, written.world_positions)
    n = len(written)  # the 50 and the random ones below α = 1/255
    assert n <= 750 and len(world) == n and np.array_equal(np.sort(ids), np.arange(n)) and dist.max() < MM
    assert np.array_equal(colors[:, :3], written.colors[ids])
