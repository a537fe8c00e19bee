"""Classification with bounded memory (issue 34): classify.stream against the in-memory classify.run, side by side.

    python bench/bench_classify_stream.py --points 1_000_000 --memory-limit 1024

A dense workspace is generated in a temporary folder: 3 pinhole views (640 × 480, f = 320 px) 15 m above a wavy
30 m × 30 m terrain (photos of a chequer, constant depth maps) and a fused cloud of ``--points`` random points on
it at a UTM-sized origin (colours, normals, every view in the visibility). Each method runs in its own subprocess
with the shipped model: in-memory = :func:`classify.run.classify_dense` + ``write_classified``; streamed =
:func:`classify.stream.classify_stream` over :func:`recon.workspace.fused_source` under ``--memory-limit`` (MiB).
Printed per method: seconds, peak resident memory (ru_maxrss, MiB, the whole child process), cells and regrown
cells; then the ratios and whether both points.ply are the same bytes. A figure taken while something else runs on
the machine is not a figure: note the load (uptime).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

ORIGIN = np.array([500_000.0, 5_200_000.0, 300.0])


def _generate(dense: Path, n: int, seed: int = 1) -> None:
    """The dense workspace (see the module docstring) in ``dense``."""
    from core.cameras import Camera, Cameras, View
    from core.io.colmap import write_model
    from core.io.images import write_image
    from core.io.ply import write_ply
    from core.pointcloud import PointCloud
    from recon.workspace import DenseWorkspace, write_array, write_vis

    ws = DenseWorkspace(dense)
    ws.make_dirs()
    cam = Camera.pinhole(320.0, 320.0, 320.0, 240.0, 640, 480)
    down = np.diag([1.0, -1.0, -1.0])
    views = {i + 1: View.from_matrix(i + 1, f"v{i}.png", 1, np.c_[down, -down @ [15.0 + cx, 15.0, 15.0]])
             for i, cx in enumerate((-1.0, 0.0, 1.0))}  # fmt: skip
    write_model(ws.sparse, Cameras({1: cam}, views))
    rows, cols = np.mgrid[0:480, 0:640] + 0.5
    for v in views.values():
        x, y = v.center[0] + (cols - 320) / 320 * 15, v.center[1] - (rows - 240) / 320 * 15
        board = ((np.floor(x / 0.5) + np.floor(y / 0.5)) % 2).astype(np.uint8) * 180 + 40
        write_image(ws.images / v.name, np.repeat(board[..., None], 3, axis=2))
        write_array(ws.depth_map(v.name), np.full((480, 640), 15.0, np.float32))
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 30.0, (n, 2))
    z = 0.5 * np.sin(xy[:, 0] / 3.0) * np.cos(xy[:, 1] / 4.0) + rng.normal(0.0, 0.005, n)
    pos = np.column_stack([xy, z])
    colors = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    normals = np.tile(np.float32([0, 0, 1]), (n, 1))
    write_ply(ws.fused_ply, PointCloud(pos, ORIGIN, colors, normals))
    write_vis(ws.fused_vis, [np.arange(3)] * n)


def _child(mode: str, dense: Path, out: Path, limit: float) -> None:
    """Run one method and print a JSON line: seconds, peak MiB, cells, regrown."""
    t0 = time.perf_counter()
    info: dict[str, object] = {"mode": mode}
    if mode == "memory":
        from classify.run import classify_dense, write_classified

        write_classified(out, classify_dense(dense, "default"))
    else:
        from classify.features import views_from_workspace
        from classify.run import load_classifier
        from classify.stream import ClassifyStreamOptions, classify_stream, photo_cache_size
        from recon.workspace import fused_source

        model, classes, _, _ = load_classifier("default")
        stream = ClassifyStreamOptions(limit, work_dir=out.parent)
        views = views_from_workspace(dense, cache=photo_cache_size(views_from_workspace(dense), stream.plan()))
        source = fused_source(dense, stream.plan().chunk_size)
        result = classify_stream(source, model, views, classes, out, stream)
        info.update(cells=result.cells, regrown=result.regrown, max_loaded=result.max_loaded)
    info["seconds"] = time.perf_counter() - t0
    info["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps(info))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--memory-limit", type=float, default=1024.0, help="MiB, the streamed run's limit")
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(args.child[0], Path(args.child[1]), Path(args.child[2]), args.memory_limit)
        return
    print(f"load: {os.getloadavg()}")
    with tempfile.TemporaryDirectory(prefix="bench_classify_stream_") as tmp:
        dense = Path(tmp) / "dense"
        _generate(dense, args.points)
        runs = {}
        for mode in ("memory", "stream"):
            out = Path(tmp) / f"{mode}.ply"
            cmd = [sys.executable, __file__, "--memory-limit", str(args.memory_limit), "--child", mode, str(dense),
                   str(out)]  # fmt: skip
            line = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.strip().splitlines()[-1]
            runs[mode] = json.loads(line)
            print(f"{mode:7s} {runs[mode]}")
        same = (Path(tmp) / "memory.ply").read_bytes() == (Path(tmp) / "stream.ply").read_bytes()
    m, s = runs["memory"], runs["stream"]
    print(f"{args.points:,} points, limit {args.memory_limit:g} MiB: time streamed / in-memory "
          f"{s['seconds'] / m['seconds']:.2f}, peak memory streamed / in-memory {s['peak_mb'] / m['peak_mb']:.2f}; "
          f"same points.ply bytes: {same}")  # fmt: skip


if __name__ == "__main__":
    main()
