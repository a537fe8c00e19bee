"""Benchmark: MVS points → Gaussians throughput and peak memory (fusion.convert), paper and adaptive modes, with the
column-grid neighbour search against scipy's cKDTree side by side.

Each measurement runs in a fresh subprocess (clean peak RSS from ``resource.getrusage``): the parent writes a
synthetic MVS-like cloud once (a wavy 2.5-D terrain at ~3 cm spacing with 0.1 % outliers, colours, normals and a
``confidence`` field) to a temporary .npz; the worker loads it, warms the numba kernels up on a small cloud (JIT load
time is reported apart), measures its RSS, converts, and reports seconds and peak RSS.

    python bench/bench_convert.py            # 1 M and 10 M points (target: >= 2 M points/s on 2 cores)
    python bench/bench_convert.py --quick    # 200 k and 1 M points

Timings on a shared machine are noisy: the load average is printed with the results.
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


def make_cloud(n: int, path: Path, seed: int = 0) -> None:
    """A synthetic MVS-like cloud: terrain z = 2 sin(x/7) + 0.5 cos(y/5) over an area with ~3 cm spacing."""
    rng = np.random.default_rng(seed)
    side = np.sqrt(n) * 0.03
    uv = rng.random((n, 2)) * side
    z = 2 * np.sin(uv[:, 0] / 7) + 0.5 * np.cos(uv[:, 1] / 5) + rng.normal(scale=0.002, size=n)
    pos = np.c_[uv, z]
    m = max(1, n // 1000)  # 0.1 % outliers in the bounding box
    pos[:m] = rng.random((m, 3)) * [side, side, 6.0] - [0, 0, 3.0]
    normals = np.c_[-2 / 7 * np.cos(uv[:, 0] / 7), 0.1 * np.sin(uv[:, 1] / 5), np.ones(n)]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    np.savez(
        path,
        positions=pos,
        colors=rng.integers(0, 256, (n, 3), dtype=np.uint8),
        normals=normals.astype(np.float32),
        confidence=rng.random(n).astype(np.float32),
    )


def worker(npz: str, mode: str, backend: str) -> None:
    import warnings

    import psutil

    from core.pointcloud import PointCloud
    from fusion.convert import ConvertOptions, convert_points

    warnings.simplefilter("ignore")
    opts = ConvertOptions(neighbor_backend=backend)
    t = time.perf_counter()
    rng = np.random.default_rng(1)
    small = rng.random((2000, 3))  # warm-up cloud with the same kinds of attributes: every kernel compiled/loaded
    convert_points(PointCloud(small, colors=np.zeros((2000, 3), np.uint8)), mode, opts)  # PCA normals path
    warm = PointCloud(small, colors=np.zeros((2000, 3), np.uint8), normals=small.astype(np.float32))
    warm.fields["confidence"] = np.ones(2000, np.float32)
    convert_points(warm, mode, opts)
    warmup = time.perf_counter() - t
    data = np.load(npz)
    cloud = PointCloud(
        data["positions"], colors=data["colors"], normals=data["normals"], fields={"confidence": data["confidence"]}
    )
    del data
    rss_before = psutil.Process().memory_info().rss
    t, cpu = time.perf_counter(), time.process_time()
    result = convert_points(cloud, mode, opts)
    seconds, cpu = time.perf_counter() - t, time.process_time() - cpu
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(
        json.dumps(
            {
                "n": len(cloud),
                "seconds": seconds,
                "cpu": cpu,
                "seconds_neighbors": result.stats.seconds_neighbors,
                "warmup": warmup,
                "rss_before": rss_before,
                "peak": peak,
                "median_spacing": result.stats.median_spacing,
            }
        )
    )


def run(npz: Path, mode: str, backend: str) -> dict:
    cmd = [sys.executable, __file__, "--worker", str(npz), mode, backend]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="200 k and 1 M points instead of 1 M and 10 M")
    ap.add_argument("--worker", nargs=3, metavar=("NPZ", "MODE", "BACKEND"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(*args.worker)
        return
    sizes = [200_000, 1_000_000] if args.quick else [1_000_000, 10_000_000]
    print(f"bench_convert: {os.cpu_count()} cores, load average at start {os.getloadavg()[0]:.1f} (shared machine)")
    header = (
        f"{'points':>10} {'mode':>9} {'backend':>7} {'s':>7} {'Mpts/s':>7} {'knn s':>6} {'cpu s':>6} "
        f"{'peak MB':>8} {'+MB':>7} {'B/pt':>6}"
    )
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            npz = Path(tmp) / f"cloud_{n}.npz"
            make_cloud(n, npz)
            for mode in ("paper", "adaptive"):
                res = {b: run(npz, mode, b) for b in ("grid", "kdtree")}
                for b, r in res.items():
                    extra = (r["peak"] - r["rss_before"]) / 2**20
                    rows.append((n, mode, b, r))
                    print(header if len(rows) == 1 else "", end="\n" if len(rows) == 1 else "")
                    print(
                        f"{n:>10} {mode:>9} {b:>7} {r['seconds']:7.2f} {n / r['seconds'] / 1e6:7.2f} "
                        f"{r['seconds_neighbors']:6.2f} {r['cpu']:6.2f} {r['peak'] / 2**20:8.0f} {extra:7.0f} "
                        f"{(r['peak'] - r['rss_before']) / n:6.0f}",
                        flush=True,
                    )
                ratio = res["kdtree"]["seconds"] / res["grid"]["seconds"]
                warm = res["grid"]["warmup"]
                print(f"{'':>10} {mode:>9} grid is {ratio:.2f}x faster than kdtree (JIT warm-up {warm:.2f} s)")
            npz.unlink()
    print(f"load average at end {os.getloadavg()[0]:.1f}; target >= 2 M points/s on 2 cores")
    print("'+MB' = peak RSS minus RSS with the input cloud loaded (the conversion's own memory incl. its output)")
    print("'cpu s' = CPU seconds of the process (all threads): wall time on 2 idle cores is at least cpu s / 2")


if __name__ == "__main__":
    main()
