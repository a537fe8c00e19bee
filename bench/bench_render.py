"""Renderer benchmark: reference (PyTorch autograd) vs cpu (numba, hand-written backward), side by side.

    python bench/bench_render.py            # 10k / 50k / 200k Gaussians at 256×192 and 512×384
    python bench/bench_render.py --quick    # 10k and 50k at 256×192 only

Scene (as in shared/notes/cpu-splat-renderer.md): N Gaussians at depth 2–6 m in front of a pinhole camera, image
σ 0.5–2.5 px, opacity 0.5–0.9, SH degree 0. Every (configuration, backend) runs in a fresh subprocess so that peak
memory is its own: ``peak`` is the process's maximum RSS, ``+peak`` the growth over the RSS after imports, scene
set-up and a small warm-up render (numba JIT/cache load is kept out of the timings). Times are medians of
``--repeats`` runs: wall clock with all threads torch and numba have (2 cores here), and ``f+b CPU-ms``, the CPU
time of all threads together (less sensitive to other processes on a shared machine; ideal wall time on k idle
cores is about CPU-ms / k for the parallel parts).
Reference configurations whose estimated memory exceeds ``--ref-limit-gb`` are skipped.

On a machine shared with other jobs, OpenMP threads that spin-wait (torch's default) lose their time slices and
multi-threaded runs get several times slower; ``OMP_WAIT_POLICY=PASSIVE python bench/bench_render.py`` avoids it
(the cpu backend's own kernels use blocking Python threads, not OpenMP).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

CONFIGS_FULL = [(n, w, h) for (w, h) in [(256, 192), (512, 384)] for n in (10_000, 50_000, 200_000)]
CONFIGS_QUICK = [(10_000, 256, 192), (50_000, 256, 192)]
# Reference memory model: saved autograd tensors per (list entry × pixel) of every tile, float32, upper bound
# (tiles stop early when all their pixels saturate). Measured 57-75 bytes here (7.0 GB at 200k / 256×192).
REF_BYTES_PER_ENTRY_PIXEL = 80.0


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def worker(n: int, width: int, height: int, backend: str, repeats: int, ref_limit_gb: float, threads: int) -> dict:
    import numba
    import numpy as np
    import torch

    if threads > 0:
        torch.set_num_threads(threads)
        numba.set_num_threads(threads)

    from fusion.render import render
    from fusion.render.cpu import bin_gaussians
    from fusion.render.projection import project_gaussians
    from fusion.render.synthetic import random_scene

    scene = random_scene(n, width, height, seed=0, sh_degree=0)
    with torch.no_grad():
        proj = project_gaussians(scene.means, scene.quats, scene.log_scales, scene.viewmat, scene.K, width, height)
        bins = bin_gaussians(
            proj.means2d.numpy(), proj.extents.numpy(), proj.depths.numpy(), proj.visible.numpy(), width, height
        )
    n_isect = len(bins.ids)
    est_gb = n_isect * 256 * REF_BYTES_PER_ENTRY_PIXEL / 1e9
    result = {"n": n, "width": width, "height": height, "backend": backend, "intersections": n_isect}
    if backend == "reference" and est_gb > ref_limit_gb:
        result["skipped"] = f"estimated {est_gb:.1f} GB > {ref_limit_gb:g} GB"
        return result
    small = random_scene(200, 32, 24, seed=1)
    warm = [p.clone().requires_grad_(True) for p in small.params]
    render(*warm, *small.camera, backend=backend).colour.sum().backward()
    base = _peak_mb()

    fwd, both, cpu_both = [], [], []
    for _ in range(repeats):
        params = [p.clone().requires_grad_(True) for p in scene.params]
        c0 = time.process_time()
        t0 = time.perf_counter()
        res = render(*params, *scene.camera, backend=backend)
        t1 = time.perf_counter()
        (res.colour.sum() + 0.1 * res.depth.sum()).backward()
        t2 = time.perf_counter()
        cpu_both.append(time.process_time() - c0)
        fwd.append(t1 - t0)
        both.append(t2 - t0)
        colour = res.colour.detach().numpy()
    peak = _peak_mb()
    result.update(
        fwd_ms=1e3 * statistics.median(fwd),
        fwdbwd_ms=1e3 * statistics.median(both),
        fwdbwd_cpu_ms=1e3 * statistics.median(cpu_both),
        peak_mb=peak,
        peak_growth_mb=peak - base,
        coverage=float(res.alpha.detach().mean()),
        checksum=float(np.asarray(colour, np.float64).sum()),
    )
    return result


def run_one(n: int, width: int, height: int, backend: str, repeats: int, ref_limit_gb: float, threads: int) -> dict:
    cmd = [sys.executable, __file__, "--worker", str(n), str(width), str(height), backend, "--repeats", str(repeats)]
    cmd += ["--ref-limit-gb", str(ref_limit_gb), "--threads", str(threads)]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])
    if proc.returncode != 0:
        return {"n": n, "width": width, "height": height, "backend": backend, "skipped": proc.stderr.strip()[-200:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _fmt(r: dict | None, key: str, spec: str) -> str:
    if r is None or "skipped" in r:
        return "skipped"
    return format(r[key], spec)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="only 10k and 50k Gaussians at 256×192")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per configuration (median reported)")
    parser.add_argument("--ref-limit-gb", type=float, default=8.0, help="skip reference runs estimated above this")
    parser.add_argument("--backends", default="reference,cpu", help="comma-separated backends to run")
    parser.add_argument("--threads", type=int, default=0, help="torch and numba threads (0: all cores)")
    parser.add_argument("--worker", nargs=4, metavar=("N", "W", "H", "BACKEND"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        n, w, h, backend = args.worker
        print(json.dumps(worker(int(n), int(w), int(h), backend, args.repeats, args.ref_limit_gb, args.threads)))
        return

    import numba
    import torch

    backends = args.backends.split(",")
    configs = CONFIGS_QUICK if args.quick else CONFIGS_FULL
    threads = args.threads or f"{torch.get_num_threads()} (torch) / {numba.get_num_threads()} (numba)"
    print(f"threads {threads}, repeats {args.repeats}")
    print("note: wall-clock times; on a shared machine they vary run to run")
    head = f"{'N':>7} {'image':>8} {'isect':>8} | {'backend':>9} {'fwd ms':>8} {'fwd+bwd ms':>10} "
    head += f"{'f+b CPU-ms':>10} {'peak MB':>8} {'+peak MB':>8}"
    print(head + f" | {'fwd ratio':>9} {'f+b ratio':>9}")
    rows = []
    for n, w, h in configs:
        results = {
            b: run_one(n, w, h, b, args.repeats if b == "cpu" else max(1, args.repeats // 3), args.ref_limit_gb,
                       args.threads)
            for b in backends
        }  # fmt: skip
        rows.append(results)
        ref, cpu = results.get("reference"), results.get("cpu")
        for b, r in results.items():
            ratio_f = ratio_b = "-"
            if b == "cpu" and ref and cpu and "skipped" not in ref and "skipped" not in cpu:
                ratio_f = f"{ref['fwd_ms'] / cpu['fwd_ms']:.1f}x"
                ratio_b = f"{ref['fwdbwd_ms'] / cpu['fwdbwd_ms']:.1f}x"
            line = f"{n:>7} {f'{w}x{h}':>8} {r.get('intersections', 0):>8} | {b:>9} {_fmt(r, 'fwd_ms', '8.1f'):>8} "
            line += f"{_fmt(r, 'fwdbwd_ms', '10.1f'):>10} {_fmt(r, 'fwdbwd_cpu_ms', '10.1f'):>10} "
            line += f"{_fmt(r, 'peak_mb', '8.0f'):>8} "
            line += f"{_fmt(r, 'peak_growth_mb', '8.0f'):>8} | {ratio_f:>9} {ratio_b:>9}"
            print(line + (f"   ({r['skipped']})" if "skipped" in r else ""), flush=True)
    target = next((r for r in rows if r.get("cpu", {}).get("n") == 50_000 and r["cpu"].get("width") == 256), None)
    if target and "skipped" not in target.get("cpu", {"skipped": 1}):
        cpu = target["cpu"]
        ok = cpu["fwdbwd_ms"] <= 120 and cpu["peak_mb"] <= 600
        print(f"target 50k/256x192: cpu fwd+bwd {cpu['fwdbwd_ms']:.0f} ms (<=120), peak {cpu['peak_mb']:.0f} MB (<=600)"
              f" -> {'met' if ok else 'NOT met'}")  # fmt: skip


if __name__ == "__main__":
    main()
