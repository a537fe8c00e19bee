#!/usr/bin/env bash
# Documented check: our 3DGS PLY, .splat and .sog exports load in PlayCanvas' splat-transform (an independent reader used
# by SuperSplat), which refuses PLY files with missing or unsupported properties ("Unsupported data", exit 1).
#
# Usage: scripts/check_splat_transform.sh [WORKDIR]
#   ST_PREFIX   where @playcanvas/splat-transform is (or gets) installed (default /tmp/hybridsplat-splat-transform)
#   ST_VERSION  npm version spec to install when missing (default: latest)
#
# Steps: (1) install splat-transform from the npm registry into ST_PREFIX if absent; (2) convert a synthetic
# georeferenced cloud with `hybridsplat convert` in both modes to .ply and .splat; (3) have splat-transform read
# each file and write CSV (PLY -> CSV, .splat -> PLY -> CSV); (4) check exit codes, row counts and that every 3DGS
# property is present, then compare the numbers with our own values (tests/test_fusion_splat_transform.py does the
# same comparison through pytest, plus a negative control). Exits non-zero on any failure.
# Versions: 2.7.1 (node >= 18) refuses a PLY with a missing property (exit 1, "Unsupported data"); 3.7.0 (engines:
# node >= 22, runs on 20) reads it as a plain table and drops the Gaussian columns, which step (4) catches.
# Checked with both on 2026-11-21.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${PY:-$ROOT/.venv/bin/python}"
ST_PREFIX="${ST_PREFIX:-/tmp/hybridsplat-splat-transform}"
ST_VERSION="${ST_VERSION:-latest}"
WORK="${1:-$(mktemp -d)}"
ST="$ST_PREFIX/node_modules/.bin/splat-transform"

command -v node >/dev/null || { echo "node is not installed: install Node.js >= 18 first" >&2; exit 3; }
if [ ! -x "$ST" ]; then
  echo "installing @playcanvas/splat-transform@$ST_VERSION into $ST_PREFIX" >&2
  npm install --silent --no-fund --no-audit --prefix "$ST_PREFIX" "@playcanvas/splat-transform@$ST_VERSION" >&2
fi
echo "splat-transform: $("$ST" --version 2>&1 | head -1)"
mkdir -p "$WORK"

cd "$ROOT"
"$PY" - "$WORK/cloud.ply" <<'EOF'
import sys
import numpy as np
from core.io.ply import write_ply
from core.pointcloud import PointCloud

rng = np.random.default_rng(7)
n = 5000
uv = rng.random((n, 2)) * 4.0
world = np.c_[uv, 0.05 * np.sin(3 * uv[:, 0])] + [512345.0, 5412345.0, 312.0]  # UTM-like
cloud = PointCloud.from_world(world, colors=rng.integers(0, 256, (n, 3)))
write_ply(sys.argv[1], cloud)
EOF

for mode in paper adaptive; do
  "$PY" -m hybridsplat convert "$WORK/cloud.ply" --mode "$mode" --out "$WORK/$mode.ply" --min-opacity 0
  "$PY" -m hybridsplat convert "$WORK/cloud.ply" --mode "$mode" --out "$WORK/$mode.splat" --min-opacity 0
  "$ST" -w "$WORK/$mode.ply" "$WORK/$mode.ply.csv" > "$WORK/$mode.ply.log" 2>&1 \
    || { cat "$WORK/$mode.ply.log"; echo "FAIL: splat-transform rejected $mode.ply" >&2; exit 1; }
  "$ST" -w "$WORK/$mode.splat" "$WORK/$mode.splat.csv" > "$WORK/$mode.splat.log" 2>&1 \
    || { cat "$WORK/$mode.splat.log"; echo "FAIL: splat-transform rejected $mode.splat" >&2; exit 1; }
  if grep -qiE "missing|unsupported|error" "$WORK/$mode.ply.log" "$WORK/$mode.splat.log"; then
    echo "FAIL: splat-transform reported a problem for $mode" >&2; exit 1
  fi
done

"$PY" - "$WORK" <<'EOF'
import sys
from pathlib import Path
import numpy as np
from core.io.gaussian_ply import gaussian_property_names, read_gaussian_ply

work = Path(sys.argv[1])
for mode in ("paper", "adaptive"):
    ours = read_gaussian_ply(work / f"{mode}.ply")
    csv = work / f"{mode}.ply.csv"
    header = csv.read_text().splitlines()[0].split(",")
    missing = [p for p in gaussian_property_names(0) if p not in header]
    if missing:
        sys.exit(f"FAIL: splat-transform CSV of {mode}.ply lacks {missing}")
    table = np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)
    col = {name: table[:, i] for i, name in enumerate(header)}
    if len(table) != len(ours):
        sys.exit(f"FAIL: {mode}.ply: splat-transform read {len(table)} rows, we wrote {len(ours)}")
    xyz = np.c_[col["x"], col["y"], col["z"]]
    err = np.abs(xyz - ours.means.astype(np.float32)).max()
    op = np.abs(col["opacity"] - ours.logit_opacities).max()
    sc = np.abs(np.c_[col["scale_0"], col["scale_1"], col["scale_2"]] - ours.log_scales).max()
    if max(err, op, sc) > 1e-6 * max(1.0, np.abs(xyz).max()):
        sys.exit(f"FAIL: {mode}.ply values differ: xyz {err}, opacity {op}, scale {sc}")
    print(f"OK {mode}.ply: {len(table)} Gaussians read by splat-transform, all {len(header)} properties, "
          f"max |Δ| xyz {err:.2e} m, opacity {op:.2e}, log-scale {sc:.2e}")
    rows = np.loadtxt(work / f"{mode}.splat.csv", delimiter=",", skiprows=1, ndmin=2)
    if len(rows) != len(ours):
        sys.exit(f"FAIL: {mode}.splat: splat-transform read {len(rows)} rows, we wrote {len(ours)}")
    print(f"OK {mode}.splat: {len(rows)} Gaussians read by splat-transform")
EOF
# SOG: our .sog bundle (fusion/sog_format.py) read back by splat-transform, compared with our own reader.
"$PY" -m hybridsplat export "$WORK/paper.ply" --out "$WORK/paper.sog" --min-opacity 0
"$ST" -w "$WORK/paper.sog" "$WORK/paper.sog.ply" > "$WORK/paper.sog.log" 2>&1 \
  || { cat "$WORK/paper.sog.log"; echo "FAIL: splat-transform rejected paper.sog" >&2; exit 1; }
"$PY" - "$WORK" <<'EOF'
import sys
from pathlib import Path
import numpy as np
import plyfile
from fusion.sog_format import read_sog

work = Path(sys.argv[1])
ours = read_sog(work / "paper.sog")
v = plyfile.PlyData.read(str(work / "paper.sog.ply"))["vertex"].data
if len(v) != len(ours):
    sys.exit(f"FAIL: paper.sog: splat-transform read {len(v)} splats, we wrote {len(ours)}")
xyz = np.c_[v["x"], v["y"], v["z"]].astype(np.float64)
dc = np.c_[v["f_dc_0"], v["f_dc_1"], v["f_dc_2"]].astype(np.float64)
err, dc_err = np.abs(xyz - ours.positions).max(), np.abs(dc - ours.sh_dc).max()
if err > 1e-5 * max(1.0, np.abs(xyz).max()) or dc_err > 1e-6:
    sys.exit(f"FAIL: paper.sog values differ: xyz {err}, f_dc {dc_err}")
print(f"OK paper.sog: {len(v)} Gaussians read by splat-transform, max |Δ| xyz {err:.2e} m, f_dc {dc_err:.2e}")
EOF
echo "splat-transform check passed (files in $WORK)"
