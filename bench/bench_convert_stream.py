"""Out-of-core MVS → Gaussian conversion and LAZ export (issue 34): fusion.convert_stream against fusion.convert.

    python bench/bench_convert_stream.py --points 10_000_000                 # streamed and in-memory, side by side
    python bench/bench_convert_stream.py --points 100_000_000 --no-memory    # the issue's figure: streamed only

The cloud samples bench_c2c's 200 m terrain like an MVS cloud (5 mm noise, 0.1 % outliers) at a UTM-sized origin,
with colours from height and position, and is generated and written to LAZ chunk by chunk
(:class:`core.io.las.LasChunkWriter`), so no step holds the whole cloud. Each method runs in its own
subprocess, reading the LAZ and writing the Gaussians' centres as LAZ (colour, opacity, scale, source, class):
streamed = :func:`fusion.convert_stream.convert_stream` under ``--memory-limit`` (MiB); in-memory = ``read_las`` +
``convert_points`` + ``export_points``. Printed per method: seconds, peak resident memory (ru_maxrss, MiB, the whole
child process), cells and fallback points; then the ratios and the largest differences of the exported opacities
and scales (both files list the points in the input order). A figure taken while something else runs on the
machine is not a figure: note the load (uptime).
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
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

ORIGIN = np.array([500_000.0, 5_200_000.0, 300.0])  # UTM-sized
CHUNK = 2_000_000


def _generate(path: Path, n: int, seed: int = 1) -> float:
    """Write n terrain points with colours to ``path`` (LAZ), CHUNK points at a time; returns seconds."""
    from bench_c2c import terrain

    from core.io.atomic import atomic_path
    from core.io.las import LasChunkWriter
    from core.pointcloud import PointCloud

    t0 = time.perf_counter()
    with atomic_path(path) as tmp:
        writer = LasChunkWriter(tmp, target=path)
        for start in range(0, n, CHUNK):
            local = terrain(min(CHUNK, n - start), seed * 100_003 + start // CHUNK, 0.005, 0.001) - [100, 100, 0]
            shade = np.clip(128 + 12 * local[:, 2], 0, 255)
            colors = np.stack([shade, 0.6 * shade + 0.4 * (local[:, 0] + 100) % 255, 255 - shade], axis=1)
            writer.write(PointCloud(local, ORIGIN, colors=colors.astype(np.uint8)))
        writer.close()
    return time.perf_counter() - t0


def _child(method: str, source: str, out: str, work: str, memory_limit_mb: float) -> None:
    """Run one conversion + LAZ export and print its figures as JSON (a fresh interpreter: its own ru_maxrss)."""
    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    extra: dict = {}
    if method == "streamed":
        from core.io.point_stream import las_source
        from fusion.convert_stream import StreamOptions, convert_stream

        stream = StreamOptions(memory_limit_mb=memory_limit_mb, work_dir=Path(work))
        r = convert_stream(las_source(source, ORIGIN), stream=stream, las_path=out)
        extra = {"cells": r.cells, "halo_m": r.halo, "fallback_points": r.fallback_points, "las_points": r.las_points,
                 "points_per_cell": r.plan.points_per_cell, "chunk_size": r.plan.chunk_size,
                 "max_cell_points": r.max_cell_points, **{f"s_{k}": v for k, v in r.seconds.items()}}  # fmt: skip
        stats = r.stats
    else:
        from core.io.las import read_las
        from fusion.convert import convert_points
        from fusion.export import export_points

        cloud = read_las(source).with_origin(ORIGIN)
        result = convert_points(cloud)
        export_points(out, result.gaussians)
        stats = result.stats
    seconds = time.perf_counter() - t0
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    figures = {"seconds": seconds, "peak_mb": peak_mb, "median_spacing_mm": stats.median_spacing * 1e3}
    print(json.dumps({**figures, "estimated_normals": stats.estimated_normals, **extra}))


def _compare(a: Path, b: Path) -> dict[str, float]:
    """Largest absolute differences of the positions, opacities and scales of two exports of the same points."""
    from core.io.las import read_las

    x, y = read_las(a), read_las(b)
    if len(x) != len(y):
        return {"count_a": len(x), "count_b": len(y)}
    return {
        "positions_m": float(np.abs(x.world_positions - y.world_positions).max()),
        "opacity": float(np.abs(x.fields["opacity"] - y.fields["opacity"]).max()),
        "scale_m": float(np.abs(x.fields["scale"] - y.fields["scale"]).max()),
        "colors": int(np.abs(x.colors.astype(int) - y.colors.astype(int)).max()),
    }


def _run(method: str, source: Path, out: Path, work: Path, limit: float) -> dict:
    cmd = [sys.executable, __file__, "--child", method, str(source), str(out), str(work), str(limit)]
    done = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "OMP_WAIT_POLICY": "PASSIVE"})
    if done.returncode:
        raise SystemExit(f"{method} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--points", type=lambda s: int(s.replace("_", "")), default=10_000_000)
    parser.add_argument("--memory-limit", type=float, default=4096.0, help="MiB for the streamed conversion")
    parser.add_argument("--no-memory", action="store_true", help="skip the in-memory conversion")
    parser.add_argument("--work", default=None, help="folder for the LAZ files and cell files (default: a temp)")
    parser.add_argument("--keep", action="store_true", help="keep the exported LAZ files")
    parser.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(*args.child[:4], float(args.child[4]))
        return
    work = Path(args.work or tempfile.mkdtemp(prefix="bench_convert_stream_"))
    work.mkdir(parents=True, exist_ok=True)
    n = args.points
    source = work / f"mvs_{n}.laz"
    print(f"{n:,} points; load: {os.getloadavg()[0]:.2f}", flush=True)
    if not source.is_file():
        seconds = _generate(source, n)
        print(f"wrote {source.name}: {source.stat().st_size / 1e6:.0f} MB in {seconds:.0f} s (chunks of {CHUNK:,})")
    rows, outs = {}, {}
    methods = ("streamed",) + (() if args.no_memory or n > 10_000_000 else ("in-memory",))
    for method in methods:
        outs[method] = work / f"gaussians_{method}.laz"
        rows[method] = _run(method, source, outs[method], work, args.memory_limit)
        shown = {k: round(v, 4) if isinstance(v, float) else v for k, v in rows[method].items()}
        print(method, json.dumps(shown), flush=True)
    if len(rows) == 2:
        a, b = rows["streamed"], rows["in-memory"]
        print(
            f"streamed / in-memory: time {a['seconds'] / b['seconds']:.2f}, peak memory "
            f"{a['peak_mb'] / b['peak_mb']:.2f}; largest differences {_compare(outs['streamed'], outs['in-memory'])}"
        )
    if not args.keep:
        for path in outs.values():
            path.unlink(missing_ok=True)
    print(f"load after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
