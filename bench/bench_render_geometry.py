"""What the renderer's geometry outputs cost on the cpu backend, side by side with colour only.

    OMP_WAIT_POLICY=PASSIVE python bench/bench_render_geometry.py            # 50k Gaussians, 320×240
    OMP_WAIT_POLICY=PASSIVE python bench/bench_render_geometry.py --n 20000 --repeats 5

Scene: :func:`fusion.render.synthetic.random_scene` (depth 2–6 m, image σ 0.5–2.5 px, opacity 0.5–0.9), SH degree
3, float32, every pixel rendered. Parts, each the median of ``--repeats`` runs, colour-only and geometry runs
interleaved so that load from other processes hits both alike (wall ms, and CPU ms of all threads together):

- ``colour fwd`` / ``colour bwd``: ``render(..., backend="cpu")`` and the backward of a colour + depth loss;
- ``geometry fwd`` / ``geometry bwd``: the same with ``render_geometry=True`` (8-feature kernels, per-Gaussian
  normals, plane and median depth, as :mod:`fusion.splat_surface` renders them), the backward of the same loss plus
  a weighted sum of the normal, plane-depth and median-depth maps (every geometry output's backward).

Ratios are geometry over colour; ``step ratio`` = (geometry fwd + bwd) / (colour fwd + bwd).
``uptime`` load averages are printed before and after: on a shared 2-core machine, compare ratios, not times.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import time


def _uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    except OSError:  # pragma: no cover - no uptime binary
        return "uptime unavailable"


def _timed(fn) -> tuple[float, float]:
    """(wall ms, process CPU ms) of one call."""
    w0, c0 = time.perf_counter(), time.process_time()
    fn()
    return 1e3 * (time.perf_counter() - w0), 1e3 * (time.process_time() - c0)


def run(n: int, width: int, height: int, repeats: int) -> dict[str, list[tuple[float, float]]]:
    """Timings per part: {part: [(wall ms, CPU ms), ...]}."""
    import torch

    from fusion.render import render
    from fusion.render.synthetic import random_scene

    scene = random_scene(n, width, height, seed=0, sh_degree=3)
    gen = torch.Generator().manual_seed(0)
    weights = torch.rand(height, width, 3, generator=gen)
    times: dict[str, list[tuple[float, float]]] = {}

    def add(part: str, t: tuple[float, float]) -> None:
        times.setdefault(part, []).append(t)

    for rep in range(repeats + 1):  # the first round warms up (JIT cache load) and is dropped
        for geometry in (False, True):
            params = [p.clone().requires_grad_(True) for p in scene.params]
            out = {}
            name = "geometry" if geometry else "colour"

            def forward(params=params, out=out, geometry=geometry) -> None:
                out["res"] = render(*params, *scene.camera, backend="cpu", render_geometry=geometry)

            t_fwd = _timed(forward)
            res = out["res"]
            loss = (res.colour * weights).sum() + 0.1 * res.depth.sum()
            if geometry:
                geo = res.geometry
                loss = loss + (geo.normal * weights).sum() + 0.1 * (geo.plane_depth.sum() + geo.median_depth.sum())
            t_bwd = _timed(loss.backward)
            if rep:
                add(f"{name} fwd", t_fwd)
                add(f"{name} bwd", t_bwd)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=50_000, help="Gaussians (default 50000)")
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds after one warm-up round")
    args = parser.parse_args()
    print(f"load before: {_uptime()}")
    times = run(args.n, args.width, args.height, args.repeats)
    print(f"load after:  {_uptime()}")
    med = {part: tuple(statistics.median(t[i] for t in ts) for i in (0, 1)) for part, ts in times.items()}
    print(f"\n{args.n} Gaussians, {args.width}×{args.height}, cpu backend, medians of {args.repeats} runs")
    print(f"{'part':<14}{'wall ms':>10}{'CPU ms':>10}{'ratio (wall)':>14}{'ratio (CPU)':>13}")
    for part in ("colour fwd", "geometry fwd", "colour bwd", "geometry bwd"):
        wall, cpu = med[part]
        base = med.get(part.replace("geometry", "colour")) if part.startswith("geometry") else None
        ratio = f"{wall / base[0]:>14.2f}{cpu / base[1]:>13.2f}" if base else ""
        print(f"{part:<14}{wall:>10.1f}{cpu:>10.1f}{ratio}")
    colour = med["colour fwd"][0] + med["colour bwd"][0], med["colour fwd"][1] + med["colour bwd"][1]
    geo = med["geometry fwd"][0] + med["geometry bwd"][0], med["geometry fwd"][1] + med["geometry bwd"][1]
    print(f"{'step ratio':<14}{geo[0]:>10.1f}{geo[1]:>10.1f}{geo[0] / colour[0]:>14.2f}{geo[1] / colour[1]:>13.2f}")


if __name__ == "__main__":
    main()
