#!/usr/bin/env bash
# Documented check: our KHR_gaussian_splatting GLB tiles pass Khronos' glTF-Validator and our 3D Tiles tileset loads in
# loaders.gl (@loaders.gl/3d-tiles, an independent 3D Tiles reader), and our attribute layout equals the one PlayCanvas'
# splat-transform writes for the same splats (a second, independent writer of the extension).
#
# Usage: scripts/check_gltf_tiles.sh [TILESET_JSON ...]
#   GT_PREFIX      where gltf-validator and @loaders.gl/{core,3d-tiles} are (or get) installed
#                  (default /tmp/hybridsplat-gltf-tools)
#   GT_NO_INSTALL  1: never install; exit 3 when the packages are missing (what the pytest wrapper uses)
#   ST             splat-transform binary for the layout comparison (default: the one scripts/check_splat_transform.sh
#                  installs); the comparison is skipped when it is absent
#
# Steps: (1) install the npm packages into GT_PREFIX if absent; (2) without TILESET_JSON, write a synthetic
# georeferenced set (UTM 33N, three layers, SH degree 1) with fusion.tiles3d.write_splat_tileset twice: SPZ-compressed
# tiles (KHR_gaussian_splatting_compression_spz_2, the default) and float32 tiles; (3) node, per tileset: serve its
# folder on 127.0.0.1, load it with loaders.gl's Tiles3DLoader, load every tile content (glTF, y-up → z-up), run
# glTF-Validator on every GLB, and print one line per content: 'TILE <uri> <id of its first splat> <ECEF x y z> <spz|float>'
# (root transform · y-up→z-up · node matrix · position), then 'errors: N'. Float32 tiles: the position and id (SH DC
# red) are loaders.gl's parsed values. SPZ tiles (loaders.gl does not decode SPZ): the script decodes the first splat
# from the GLB bytes itself (chunks, the extension's bufferView, gunzip, SPZ v2 header, 24-bit fixed point) and checks
# that the stream is SPZ v2 in bufferView 0 (where CesiumJS reads it), that every accessor has the stream's count and no
# bufferView, and that both extensions are required by the GLB and by the tileset's 3DTILES_content_gltf; the id is -1
# (SPZ cannot carry it: the caller matches the position);
# (4) with splat-transform, convert a 3DGS PLY of the same splats to .glb and compare every KHR_gaussian_splatting
# attribute with ours (after the 180° turn about z that splat-transform applies to PLY input). Exits non-zero on any
# failure.
#
# Known, ignored: glTF-Validator 2.0.0-dev.3.10 reports MESH_PRIMITIVE_INVALID_ATTRIBUTE for every extension-prefixed
# semantic ('KHR_gaussian_splatting:SCALE', …): it predates them (KhronosGroup/glTF-Validator issue #252, open; the glTF
# change allowing them is KhronosGroup/glTF#2514), UNSUPPORTED_EXTENSION (an info) for KHR_gaussian_splatting and
# KHR_gaussian_splatting_compression_spz_2, and, in SPZ tiles, UNUSED_OBJECT (an info) for the bufferView holding the
# SPZ stream (only the extension the validator does not know refers to it). Every other issue counts (SPZ tiles were
# checked on 2026-11-27: no other issue). Checked on 2026-07-20 with gltf-validator 2.0.0-dev.3.10, @loaders.gl/3d-tiles 4.5.4,
# splat-transform 3.7.0, node 20.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${PY:-$ROOT/.venv/bin/python}"
GT_PREFIX="${GT_PREFIX:-/tmp/hybridsplat-gltf-tools}"
ST="${ST:-/tmp/hybridsplat-splat-transform/node_modules/.bin/splat-transform}"
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT

command -v node >/dev/null || { echo "node is not installed: install Node.js >= 18 first" >&2; exit 3; }
if [ ! -d "$GT_PREFIX/node_modules/gltf-validator" ] || [ ! -d "$GT_PREFIX/node_modules/@loaders.gl/3d-tiles" ]; then
  if [ "${GT_NO_INSTALL:-0}" = "1" ]; then
    echo "gltf-validator / @loaders.gl/3d-tiles are not installed in $GT_PREFIX (GT_NO_INSTALL=1)" >&2; exit 3
  fi
  echo "installing gltf-validator and @loaders.gl/3d-tiles into $GT_PREFIX" >&2
  npm install --silent --no-fund --no-audit --prefix "$GT_PREFIX" gltf-validator @loaders.gl/core @loaders.gl/3d-tiles >&2
fi

cd "$ROOT"
TILESETS=("$@")
if [ ${#TILESETS[@]} -eq 0 ]; then
  TILESETS=("$WORK/tiles/tileset.json" "$WORK/tiles_raw/tileset.json")
  "$PY" - "${TILESETS[@]}" <<'EOF'
import sys
import numpy as np
from core.gaussians import GaussianSet
from fusion.tiles3d import TilesetOptions, write_splat_tileset

rng = np.random.default_rng(7)
n = 3000
sh_dc = rng.normal(size=(n, 3)).astype(np.float32)
sh_dc[:, 0] = np.arange(n)  # the splat's id, read back below
gs = GaussianSet(
    np.c_[rng.uniform(-300, 300, (n, 2)), rng.uniform(-20, 20, n)], rng.normal(-3, 1, (n, 3)), rng.normal(size=(n, 4)),
    rng.normal(0, 3, n), sh_dc, rng.normal(0, 0.2, (n, 3, 3)), origin=[512345.0, 4012345.0, 250.0],
    fields={"source": rng.integers(1, 4, n).astype(np.uint8)},
)
for out, compression in zip(sys.argv[1:], ["spz", "none"]):  # SPZ (CesiumJS's form, the default) and float32
    summary = write_splat_tileset(gs, out, "EPSG:32633", TilesetOptions(max_splats_per_tile=500, compression=compression))
    print("\n".join(summary.lines()))
EOF
fi

cat > "$WORK/check.cjs" <<'EOF'
// Load a tileset with loaders.gl over HTTP from 127.0.0.1, validate every GLB with glTF-Validator.
const fs = require('node:fs');
const http = require('node:http');
const path = require('node:path');
const {load} = require('@loaders.gl/core');
const {Tiles3DLoader} = require('@loaders.gl/3d-tiles');
const validator = require('gltf-validator');
const zlib = require('node:zlib');
const SPZ = 'KHR_gaussian_splatting_compression_spz_2';

const file = path.resolve(process.argv[2]);
const root = path.dirname(file);
const KNOWN = (m, spz) => (m.code === 'MESH_PRIMITIVE_INVALID_ATTRIBUTE' && m.pointer.includes('/attributes/KHR_gaussian_splatting:'))
  || (m.code === 'UNSUPPORTED_EXTENSION' && m.message.includes('KHR_gaussian_splatting'))
  || (spz && m.code === 'UNUSED_OBJECT' && m.pointer === `/bufferViews/${spz.bufferView}`); // used by the SPZ extension

// The first splat of a KHR_gaussian_splatting_compression_spz_2 primitive, decoded here from the GLB bytes alone (GLB
// chunks, the extension's bufferView, gunzip, SPZ v2 header and 24-bit fixed-point position): an independent reader.
function spzFirstSplat(glb, prim, spz) {
  const dv = new DataView(glb.buffer, glb.byteOffset, glb.byteLength);
  const jsonLen = dv.getUint32(12, true);
  const json = JSON.parse(new TextDecoder().decode(glb.subarray(20, 20 + jsonLen)));
  const bin = glb.subarray(28 + jsonLen, 28 + jsonLen + dv.getUint32(20 + jsonLen, true));
  const view = json.bufferViews[spz.bufferView];
  const raw = zlib.gunzipSync(bin.subarray(view.byteOffset || 0, (view.byteOffset || 0) + view.byteLength));
  const h = new DataView(raw.buffer, raw.byteOffset, raw.byteLength);
  const [magic, version, count, bits] = [h.getUint32(0, true), h.getUint32(4, true), h.getUint32(8, true), raw[13]];
  const problems = [];
  if (magic !== 0x5053474e || version !== 2) problems.push(`SPZ magic/version ${magic.toString(16)}/${version}, expected NGSP/2`);
  if (spz.bufferView !== 0) problems.push(`SPZ bufferView ${spz.bufferView}: CesiumJS reads bufferView 0`);
  for (const [name, index] of Object.entries(json.meshes[0].primitives[0].attributes)) {
    if (json.accessors[index].count !== count) problems.push(`${name}: count ${json.accessors[index].count}, SPZ holds ${count}`);
    if (json.accessors[index].bufferView !== undefined) problems.push(`${name}: has a bufferView beside the SPZ stream`);
  }
  for (const ext of [EXT, SPZ]) if (!(json.extensionsRequired || []).includes(ext)) problems.push(`${ext} not in extensionsRequired`);
  const p = [0, 1, 2].map((k) => { let v = raw[16 + 3 * k] | (raw[17 + 3 * k] << 8) | (raw[18 + 3 * k] << 16); if (v & 0x800000) v -= 1 << 24; return v / 2 ** bits; });
  return {p, problems};
}
const EXT = 'KHR_gaussian_splatting';

function mul(a, b) { // 4x4 column-major
  const r = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) for (let rr = 0; rr < 4; rr++) for (let k = 0; k < 4; k++) r[c * 4 + rr] += a[k * 4 + rr] * b[c * 4 + k];
  return r;
}
const Y_UP_TO_Z_UP = [1, 0, 0, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 1]; // column-major of the 3D Tiles matrix

const server = http.createServer((req, res) => {
  const p = path.join(root, decodeURIComponent(new URL(req.url, 'http://x').pathname));
  if (!p.startsWith(root) || !fs.existsSync(p)) { res.writeHead(404); res.end(); return; }
  res.writeHead(200); res.end(fs.readFileSync(p));
});
server.listen(0, '127.0.0.1', async () => {
  let errors = 0;
  try {
    const base = `http://127.0.0.1:${server.address().port}/`;
    const tileset = await load(base + path.basename(file), Tiles3DLoader);
    const contentGltf = (JSON.parse(fs.readFileSync(file, 'utf8')).extensions || {})['3DTILES_content_gltf'] || {};
    const rootTransform = tileset.root.transform || [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
    const stack = [tileset.root];
    let tiles = 0;
    while (stack.length) {
      const tile = stack.pop();
      tiles++;
      for (const child of tile.children || []) stack.push(child);
      if (!tile.contentUrl) continue;
      const uri = tile.contentUrl.slice(base.length);
      const content = await load(tile.contentUrl, Tiles3DLoader, {'3d-tiles': {loadGLTF: true}});
      if (content.type !== 'glTF' || !content.rotateYtoZ) { console.log(`ERROR ${uri}: not read as y-up glTF`); errors++; }
      const prim = content.gltf.meshes[0].primitives[0];
      if (!prim.extensions || !prim.extensions.KHR_gaussian_splatting) { console.log(`ERROR ${uri}: no extension`); errors++; }
      const node = content.gltf.nodes[0].matrix || [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
      const m = mul(mul(rootTransform, Y_UP_TO_Z_UP), node);
      const glb = new Uint8Array(fs.readFileSync(path.join(root, uri)));
      const spz = ((prim.extensions || {}).KHR_gaussian_splatting || {}).extensions?.[SPZ];
      let p, id = -1; // an SPZ stream cannot carry the id: the caller matches the position
      if (spz) {
        const first = spzFirstSplat(glb, prim, spz);
        for (const what of first.problems) { console.log(`ERROR ${uri}: ${what}`); errors++; }
        if (!(contentGltf.extensionsRequired || []).includes(SPZ)) { console.log(`ERROR tileset: ${SPZ} not required in 3DTILES_content_gltf`); errors++; }
        p = first.p;
      } else {
        p = prim.attributes.POSITION.value;
        id = prim.attributes['KHR_gaussian_splatting:SH_DEGREE_0_COEF_0'].value[0];
      }
      const ecef = [0, 1, 2].map((r) => m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r]);
      console.log(`TILE ${uri} ${id} ${ecef.map((v) => v.toFixed(6)).join(' ')} ${spz ? 'spz' : 'float'}`);
      const report = await validator.validateBytes(glb, {maxIssues: 1000});
      for (const msg of report.issues.messages) {
        if (KNOWN(msg, spz)) continue;
        console.log(`ISSUE ${uri} severity ${msg.severity} ${msg.code} ${msg.pointer || ''}: ${msg.message}`);
        if (msg.severity <= 1) errors++; // 0 error, 1 warning
      }
    }
    console.log(`loaders.gl read ${tiles} tiles; glTF-Validator ${validator.version()}`);
  } catch (e) {
    console.log(`ERROR ${e.stack || e}`);
    errors++;
  }
  console.log(`errors: ${errors}`);
  server.close();
  process.exitCode = errors ? 1 : 0;
});
EOF
for TILESET in "${TILESETS[@]}"; do
  echo "checking $TILESET"
  NODE_PATH="$GT_PREFIX/node_modules" node "$WORK/check.cjs" "$TILESET"
done

if [ -x "$ST" ]; then
  "$PY" - "$WORK" "$ST" <<'EOF'
import subprocess
import sys
from pathlib import Path

import numpy as np
from core.gaussians import GaussianSet
from fusion.export import ExportOptions, export_gaussian_ply
from fusion.gltf_splats import encode_splat_glb, read_splat_glb

work, st = Path(sys.argv[1]), sys.argv[2]
rng = np.random.default_rng(3)
n = 500
gs = GaussianSet(rng.normal(size=(n, 3)) * 10, rng.normal(-3, 1, (n, 3)), rng.normal(size=(n, 4)), rng.normal(0, 3, n),
                 rng.normal(size=(n, 3)), rng.normal(0, 0.2, (n, 15, 3)))
gs.quats /= np.linalg.norm(gs.quats, axis=1, keepdims=True)  # splat-transform writes the PLY's quaternion as is
export_gaussian_ply(work / "st.ply", gs, ExportOptions(min_opacity=0))
proc = subprocess.run([st, "-w", str(work / "st.ply"), str(work / "st.glb")], capture_output=True, text=True)
if proc.returncode != 0:
    sys.exit(f"FAIL: splat-transform could not write a GLB:\n{proc.stdout}{proc.stderr}")
theirs, ours = read_splat_glb(work / "st.glb"), read_splat_glb(encode_splat_glb(gs))
# splat-transform reads a 3DGS PLY as y-down (PlayCanvas' convention) and writes the GLB turned 180° about z; ours keeps
# the frame (z-up survey data; the node matrix turns it y-up). Apply that turn to ours: it also tests our quaternion
# order and our SH rotation (fusion.gltf_splats.rotate_sh_rest) against an independent implementation.
from scipy.spatial.transform import Rotation
from fusion.gltf_splats import rotate_sh_rest

turn = Rotation.from_euler("z", 180, degrees=True)
ours_pos = turn.apply(ours.positions.astype(np.float64)).astype(np.float32)
ours_rot = (turn * Rotation.from_quat(ours.rotations.astype(np.float64))).as_quat()
ours_sh = np.concatenate([ours.sh[:, :1], rotate_sh_rest(ours.sh[:, 1:], turn.as_matrix())], axis=1)
order, mine = np.lexsort(np.round(theirs.positions, 3).T), np.lexsort(np.round(ours_pos, 3).T)
their_rot, ours_rot = theirs.rotations[order].astype(np.float64), ours_rot[mine]
ours_rot *= np.sign((their_rot * ours_rot).sum(axis=1))[:, None]  # q and -q are the same rotation
checks = {
    "POSITION": (theirs.positions[order], ours_pos[mine]),
    "ROTATION (x, y, z, w)": (their_rot, ours_rot),
    "SCALE (linear)": (theirs.scales[order], ours.scales[mine]),
    "OPACITY (alpha)": (theirs.opacities[order], ours.opacities[mine]),
    "SH_DEGREE_l_COEF_n (all 16)": (theirs.sh[order], ours_sh[mine]),
}
for name, (a, b) in checks.items():
    if a.shape != b.shape or not np.allclose(a, b, rtol=1e-5, atol=1e-6):
        sys.exit(f"FAIL: {name} differs from splat-transform's GLB (max |Δ| {np.abs(a - b).max()})")
print(f"splat-transform layout: OK ({n} splats, SH degree 3: positions, rotations, scales, opacities, SH equal)")
EOF
else
  echo "splat-transform not found at $ST: layout comparison skipped (scripts/check_splat_transform.sh installs it)"
fi
echo "glTF / 3D Tiles check passed"
