"""Out-of-core C2C on LAZ clouds (issue 34): eval.c2c_stream against the in-memory eval.c2c, side by side.

    python bench/bench_c2c_stream.py --points 10_000_000          # both ways, compared
    python bench/bench_c2c_stream.py --points 100_000_000 --no-memory   # streamed only (the in-memory one needs ~10 GB)
    python bench/bench_c2c_stream.py --points 10_000_000 --eval --memory-limit 1024   # + the eval stage's paths

``--eval`` adds the eval stage's two paths: ``eval-streamed`` (eval.geometry_stream.compare_clouds_streamed, as
``run --memory-limit`` runs it: the compared cloud — a product — in memory, the reference read in chunks, exact
distances both ways, cells from the limit) and ``eval-in-memory`` (eval.c2c.compare_clouds without max_dist, what the
stage runs without a limit); their figures are the same (reverse mean within rel 1e-12).

Both clouds sample bench_c2c's 200 m terrain (the reference like a LiDAR scan, the compared cloud like MVS: 2 cm
noise, 1 % outliers) at a UTM-sized origin, generated and written to LAZ chunk by chunk
(:func:`core.io.las.write_las_chunks`), so no step holds a whole cloud. Each C2C runs in its own subprocess: peak
resident memory (ru_maxrss) and seconds per method, the figures (mean, median, completeness at τ) of both and
their ratios. A figure taken while something else runs on the machine is not a figure: note the load (uptime).
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
sys.path.insert(0, str(ROOT / "bench"))

ORIGIN = np.array([500_000.0, 5_200_000.0, 300.0])  # UTM-sized
CHUNK = 2_000_000
HALO, TAU = 0.5, 0.05  # metres: search radius both ways, completeness threshold


def _generate(path: Path, n: int, seed: int, noise: float, outliers: float) -> float:
    from bench_c2c import terrain

    from core.io.las import write_las_chunks

    t0 = time.perf_counter()
    chunks = (terrain(min(CHUNK, n - s), seed * 100_003 + s // CHUNK, noise, outliers) for s in range(0, n, CHUNK))
    write_las_chunks(path, chunks, ORIGIN)
    return time.perf_counter() - t0


def _child(method: str, compared: str, reference: str, work: str) -> None:
    """Run one C2C and print its figures as JSON (in a fresh interpreter, for its own ru_maxrss)."""
    t0 = time.perf_counter()
    if method.startswith("eval-"):
        stats, scores, extra = _eval_child(method, compared, reference, work)
    elif method == "streamed":
        from eval.c2c_stream import las_chunks, streamed_c2c

        r = streamed_c2c(las_chunks(compared, ORIGIN), las_chunks(reference, ORIGIN), HALO, TAU, work_dir=work)
        stats, scores, extra = r.stats, r.scores, {"cells": r.grid.nx * r.grid.ny}
    else:
        from core.io.las import read_las
        from eval.c2c import compare_clouds

        r = compare_clouds(read_las(compared), read_las(reference), max_dist=HALO, tau=TAU)
        stats, scores, extra = r.stats, r.scores, {}
    seconds = time.perf_counter() - t0
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({
        "seconds": seconds, "peak_mb": peak_mb, "mean_mm": stats.mean * 1e3, "median_mm": stats.median * 1e3,
        "outliers": stats.outlier_count, "completeness": scores.recall, "precision": scores.precision, **extra,
    }))  # fmt: skip


def _eval_child(method: str, compared: str, reference: str, work: str) -> tuple:
    """The eval stage's C2C (``eval-streamed`` within the limit in ``work``'s name, or ``eval-in-memory``):
    (statistics, scores, extra figures)."""
    from core.io.las import read_las

    cloud = read_las(compared)  # the product: in memory in the eval stage either way
    read_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # the peak of reading the product alone
    if method == "eval-streamed":
        from eval.c2c_stream import plan_c2c_memory
        from eval.geometry_stream import compare_clouds_streamed, reference_source

        folder, limit = work.rsplit("@", 1)
        plan = plan_c2c_memory(float(limit))
        r = compare_clouds_streamed(cloud, reference_source(reference, plan.chunk), plan, tau=TAU, work_dir=folder)
        extra = {"points_per_cell": plan.points_per_cell, "product_read_peak_mb": read_mb}
        return r.stats, r.scores, {**extra, "reverse_mean_mm": r.reverse.mean * 1e3}
    from eval.c2c import compare_clouds

    r = compare_clouds(cloud, read_las(reference), tau=TAU)
    return r.stats, r.scores, {"product_read_peak_mb": read_mb, "reverse_mean_mm": r.reverse.mean * 1e3}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--points", type=lambda s: int(s.replace("_", "")), default=10_000_000)
    parser.add_argument("--no-memory", action="store_true", help="skip the in-memory C2C")
    parser.add_argument("--work", default=None, help="folder for the LAZ files and cell files (default: a temp)")
    parser.add_argument("--eval", action="store_true", help="also the eval stage's streamed and in-memory C2C")
    parser.add_argument("--memory-limit", type=float, default=1024.0, help="MiB of the eval-streamed run")
    parser.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(*args.child)
        return
    work = Path(args.work or tempfile.mkdtemp(prefix="bench_c2c_stream_"))
    work.mkdir(parents=True, exist_ok=True)
    n = args.points
    compared, reference = work / "compared.laz", work / "reference.laz"
    print(f"{n:,} points a cloud; load: {os.getloadavg()[0]:.2f}")
    for path, seed, noise, outliers in ((reference, 1, 0.0, 0.0), (compared, 2, 0.02, 0.01)):
        if not path.is_file():
            seconds = _generate(path, n, seed, noise, outliers)
            print(f"wrote {path.name}: {path.stat().st_size / 1e6:.0f} MB in {seconds:.0f} s (chunks of {CHUNK:,})")
    rows = {}
    methods = ("streamed",) + (() if args.no_memory else ("in-memory",))
    methods += (("eval-streamed",) + (() if args.no_memory else ("eval-in-memory",))) if args.eval else ()
    for method in methods:
        child_work = f"{work}@{args.memory_limit:g}" if method == "eval-streamed" else str(work)
        cmd = [sys.executable, __file__, "--child", method, str(compared), str(reference), child_work]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.strip().splitlines()[-1]
        rows[method] = json.loads(out)
        print(method, json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in rows[method].items()}))
    for streamed, memory in (("streamed", "in-memory"), ("eval-streamed", "eval-in-memory")):
        if streamed in rows and memory in rows:
            a, b = rows[streamed], rows[memory]
            print(
                f"{streamed} / {memory}: time {a['seconds'] / b['seconds']:.2f}, "
                f"peak memory {a['peak_mb'] / b['peak_mb']:.2f}"
                f"; mean differs by {abs(a['mean_mm'] - b['mean_mm']):.2e} mm, completeness by "
                f"{abs(a['completeness'] - b['completeness']):.2e}"
            )
    print(f"load after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
