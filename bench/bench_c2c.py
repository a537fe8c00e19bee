"""C2C benchmark: hybridsplat's eval.c2c against open3d's compute_point_cloud_distance, side by side.

    python bench/bench_c2c.py            # 10 M compared points against 10 M reference points
    python bench/bench_c2c.py --quick    # 1 M against 1 M

Both clouds sample the same synthetic terrain (200 m × 200 m, undulating, with box "buildings") in local
float64 coordinates (what eval.c2c works on after moving clouds to one origin): the reference like a
LiDAR scan, the compared cloud like MVS (2 cm noise, 1 % outliers).
Each method runs in its own subprocess (fresh interpreter) that loads the same clouds from .npy files, so
peak resident memory (ru_maxrss) is measured per method; the time covers the distance computation only
(open3d's includes building its PointCloud objects from numpy, as a user would have to). Distances are
checked against each other on every point. Timings on a shared machine are noisy: re-run before quoting.
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


def terrain(n: int, seed: int, noise: float, outliers: float) -> np.ndarray:
    """(n, 3) float64 local points on a 200 m terrain with blocks; generated in chunks to bound memory."""
    rng = np.random.default_rng(seed)
    out = np.empty((n, 3))
    for start in range(0, n, 2_000_000):
        m = min(2_000_000, n - start)
        xy = rng.uniform(0, 200, size=(m, 2))
        z = 3 * np.sin(xy[:, 0] / 17) * np.cos(xy[:, 1] / 23) + 0.02 * xy[:, 0]
        blocks = (np.floor(xy[:, 0] / 25) + np.floor(xy[:, 1] / 25)) % 3 == 0
        inner = ((xy % 25) > 5).all(axis=1)
        z = z + np.where(blocks & inner, 8.0, 0.0)
        pts = np.c_[xy, z] + rng.normal(0, noise, size=(m, 3))
        bad = rng.random(m) < outliers
        pts[bad, 2] += rng.uniform(0.5, 3.0, size=int(bad.sum()))
        out[start : start + m] = pts
    return out


def worker(method: str, folder: Path) -> None:
    """Run one method on the clouds in ``folder``; print one JSON line with seconds and peak RSS."""
    import psutil

    compared = np.load(folder / "compared.npy")
    reference = np.load(folder / "reference.npy")
    rss_before = psutil.Process().memory_info().rss
    t0 = time.perf_counter()
    if method == "hybridsplat":
        sys.path.insert(0, str(ROOT))
        from eval.c2c import nearest_distances

        d = nearest_distances(compared, reference)
    elif method == "ckdtree_plain":
        from scipy.spatial import cKDTree

        d, _ = cKDTree(reference).query(compared, k=1, workers=-1)
    elif method == "open3d":
        import open3d as o3d

        a = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(compared))
        b = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(reference))
        d = np.asarray(a.compute_point_cloud_distance(b))
    else:
        raise SystemExit(f"unknown method {method}")
    seconds = time.perf_counter() - t0
    np.save(folder / f"d_{method}.npy", d)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"method": method, "seconds": seconds, "peak_mb": peak_mb, "before_mb": rss_before / 2**20}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="1 M against 1 M points instead of 10 M")
    parser.add_argument("--n", type=int, default=None, help="points per cloud (overrides --quick)")
    parser.add_argument("--methods", default="hybridsplat,open3d,ckdtree_plain")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--folder", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.worker, Path(args.folder))
        return
    n = args.n or (1_000_000 if args.quick else 10_000_000)
    print(f"C2C benchmark: {n:,} compared vs {n:,} reference points, {os.cpu_count()} cores (shared: timings noisy)")
    with tempfile.TemporaryDirectory(prefix="bench_c2c_") as tmp:
        folder = Path(tmp)
        t0 = time.perf_counter()
        np.save(folder / "reference.npy", terrain(n, seed=1, noise=0.005, outliers=0.0))
        np.save(folder / "compared.npy", terrain(n, seed=2, noise=0.02, outliers=0.01))
        print(f"data: {time.perf_counter() - t0:.1f} s to generate")
        results = {}
        for method in args.methods.split(","):
            out = subprocess.run(
                [sys.executable, __file__, "--worker", method, "--folder", str(folder)],
                capture_output=True,
                text=True,
            )
            if out.returncode != 0:
                print(f"{method}: failed\n{out.stderr[-2000:]}")
                continue
            results[method] = json.loads(out.stdout.strip().splitlines()[-1])
        ours = np.load(folder / "d_hybridsplat.npy") if "hybridsplat" in results else None
        print(
            f"{'method':<16}{'seconds':>10}{'peak RSS MB':>14}{'RSS before MB':>15}{'time ratio':>12}{'max |Δd| m':>14}"
        )
        base = results.get("open3d", {}).get("seconds")
        for method, r in results.items():
            ratio = f"{r['seconds'] / base:.2f}" if base else "–"
            diff = "–"
            if ours is not None:
                diff = f"{np.abs(np.load(folder / f'd_{method}.npy') - ours).max():.1e}"
            print(f"{method:<16}{r['seconds']:>10.2f}{r['peak_mb']:>14.0f}{r['before_mb']:>15.0f}{ratio:>12}{diff:>14}")
        if "hybridsplat" in results and base:
            h = results["hybridsplat"]
            verdict = "faster" if h["seconds"] <= base else "SLOWER"
            print(
                f"hybridsplat / open3d time = {h['seconds'] / base:.2f} ({verdict}); "
                f"peak {h['peak_mb'] / 1024:.2f} GB (target <= 3 GB)"
            )
        if ours is not None:
            print(f"C2C mean {ours.mean():.4f} m, std {ours.std():.4f} m, P95 {np.percentile(ours, 95):.4f} m")


if __name__ == "__main__":
    main()
