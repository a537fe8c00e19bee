"""Masked training with and without the geometric losses (issue 31) at equal steps: time per step side by side.

    OMP_WAIT_POLICY=PASSIVE python bench/bench_train_geometry.py                  # 12k fill + 40k context, 320×240
    OMP_WAIT_POLICY=PASSIVE python bench/bench_train_geometry.py --steps 40 --repeats 3 --fill 5000

Scene (built here, seeded): a textured plane of ``--context`` flat frozen Gaussians (1.2 m square) with a disc of
``--fill`` trainable ones in its middle (radius ``--disc``; the truth flat on the plane, the initial fill moved by
~2 cm, round and randomly rotated), ``--views`` cameras on a ring at 30° elevation, the masks = where the true
fill's alpha > 0.5. Every run is :func:`fusion.train.train_splats` with the same options (``flat``, SH degree 1,
no densification so that every run keeps the same count, no early stop), only the geometric options differ:

- ``off``: today's training (``geometry=None``, ``priors=None``);
- ``every k``: depth–normal consistency (weight 0.05, plane depth) on every k-th step from the first;
- ``every k + prior``: the default cadence plus the MVS depth prior on the rendered depth
  (``PriorOptions(normal_weight=0)``).

Time per step = the loop's wall (and process CPU) seconds from the end of step ``--skip`` to the last step, over the
steps between (the first steps load numba caches; preparing the scene and the priors is not counted). Runs are
interleaved round by round (``--repeats`` rounds, the order rotated each round) so that load from other processes
hits every configuration alike; the table gives the median per configuration and its ratio to ``off``. ``uptime`` is
printed before and after: on a shared 2-core machine compare ratios, not times. The target (issue 31): ≤ 1.3× the
time of ``off`` at equal steps.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import subprocess
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402


def _uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    except OSError:  # pragma: no cover - no uptime binary
        return "uptime unavailable"


def ring_cameras(n: int, width: int, height: int, radius: float = 2.0):
    """n pinhole cameras on a ring at 30° elevation looking at the origin (COLMAP world-to-camera poses)."""
    from core.cameras import Camera, Cameras, View

    cam = Camera.pinhole(0.9 * width, 0.9 * width, width / 2, height / 2, width, height)
    views = {}
    for i in range(n):
        az = 2 * math.pi * i / n
        c = radius * np.array([math.cos(az) * math.cos(0.5), math.sin(az) * math.cos(0.5), math.sin(0.5)])
        z = -c / np.linalg.norm(c)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        views[i + 1] = View.from_matrix(i + 1, f"v{i:02d}.png", 1, np.concatenate([R, (-R @ c)[:, None]], axis=1))
    return Cameras({1: cam}, views)


def flat_layer(n: int, half: float, rng: np.random.Generator, disc: float | None = None, hole: float = 0.0):
    """n flat opaque Gaussians scattered on the plane z = 0 within |x|, |y| <= half (a disc of radius ``disc``, or
    outside radius ``hole``), σ matched to the spacing, random colours."""
    from core.gaussians import SH_C0, GaussianSet

    xy = rng.uniform(-half, half, (4 * n, 2))
    r = np.linalg.norm(xy, axis=1)
    keep = (r >= hole) & (r <= disc if disc is not None else True)
    xy = xy[keep][:n]
    area = (math.pi * disc**2) if disc is not None else (4 * half * half - math.pi * hole * hole)
    sigma = 0.7 * math.sqrt(area / len(xy))
    m = len(xy)
    colours = rng.uniform(0.1, 0.9, (m, 3))
    return GaussianSet(np.column_stack([xy, np.zeros(m)]), np.tile(np.log([sigma, sigma, 1e-3]), (m, 1)),
                       np.tile([1.0, 0, 0, 0], (m, 1)), np.full(m, 3.0), (colours - 0.5) / SH_C0)  # fmt: skip


def build_scene(args: argparse.Namespace):
    """(cameras, photos, masks, initial fill, frozen context)."""
    from core.gaussians import GaussianSet
    from fusion.render import render_gaussian_set

    rng = np.random.default_rng(0)
    width, height = (int(v) for v in args.size.split("x"))
    cams = ring_cameras(args.views, width, height)
    fill = flat_layer(args.fill, args.disc, rng, disc=args.disc)
    context = flat_layer(args.context, 0.6, rng, hole=args.disc)
    names = ("means", "log_scales", "quats", "logit_opacities", "sh_dc")
    truth = GaussianSet(*(np.concatenate([getattr(fill, k), getattr(context, k)]) for k in names))
    photos, masks = {}, {}
    for v in cams:
        photos[v.name] = render_gaussian_set(truth, cams.camera_of(v), v, backend="cpu").to_numpy().colour
        masks[v.name] = render_gaussian_set(fill, cams.camera_of(v), v, backend="cpu").to_numpy().alpha > 0.5
    init = fill.subset(slice(None))
    init.means = init.means + rng.normal(0, 0.02, init.means.shape)
    init.log_scales = init.log_scales.mean(axis=1, keepdims=True).repeat(3, axis=1)
    q = rng.normal(size=(len(init), 4))
    init.quats = q / np.linalg.norm(q, axis=1, keepdims=True)
    return cams, photos, masks, init, context


def configurations(cadences: list[int]):
    """{name: GeometryOptions | None} in table order."""
    from fusion.train import GeometryOptions

    out = {"off": None}
    for k in cadences:
        out[f"every {k}"] = GeometryOptions(every=k)
    return out


def timed_run(args, scene, geometry) -> tuple[float, float, float]:
    """(wall s per step, CPU s per step, final depth–normal inconsistency or NaN) of one training run."""
    from fusion.train import DefaultStrategy, TrainOptions, train_splats

    cams, photos, masks, init, context = scene
    marks: dict[int, tuple[float, float]] = {}

    def progress(info) -> None:
        if info.step in (args.skip, args.steps):
            marks[info.step] = (time.perf_counter(), time.process_time())

    opts = TrainOptions(iterations=args.steps, sh_degree=1, sh_degree_interval=10, flat=True, min_iterations=10**6,
                        eval_every=args.steps, strategy=DefaultStrategy(refine_start=10_000),
                        geometry=geometry)  # fmt: skip
    result = train_splats(cams, photos, masks, init, context=context, options=opts, progress=progress)
    n = args.steps - args.skip
    wall = (marks[args.steps][0] - marks[args.skip][0]) / n
    cpu = (marks[args.steps][1] - marks[args.skip][1]) / n
    return wall, cpu, result.history[-1].normal_consistency


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fill", type=int, default=12_000, help="trainable Gaussians (default 12000)")
    parser.add_argument("--context", type=int, default=40_000, help="frozen context Gaussians (default 40000)")
    parser.add_argument("--disc", type=float, default=0.2, help="radius of the trained disc, m (default 0.2)")
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--size", default="320x240", help="WxH of the photos (default 320x240)")
    parser.add_argument("--steps", type=int, default=60, help="steps per run (default 60)")
    parser.add_argument("--skip", type=int, default=8, help="first steps not timed (default 8)")
    parser.add_argument("--repeats", type=int, default=3, help="rounds (default 3)")
    parser.add_argument("--cadences", default="1,2,4", help="comma-separated k of 'every k' (default 1,2,4)")
    args = parser.parse_args()
    import torch

    print(f"load before: {_uptime()}")
    scene = build_scene(args)
    confs = configurations([int(k) for k in args.cadences.split(",")])
    names = list(confs)
    times: dict[str, list[tuple[float, float, float]]] = {k: [] for k in names}
    timed_run(args, scene, confs[names[-1]])  # warm-up: numba caches of every kernel
    for rep in range(args.repeats):
        for name in names[rep % len(names) :] + names[: rep % len(names)]:
            times[name].append(timed_run(args, scene, confs[name]))
    print(f"load after:  {_uptime()}")
    mask_px = sum(int(m.sum()) for m in scene[2].values())
    print(f"\n{len(scene[3])} trainable + {len(scene[4])} frozen Gaussians, {args.views} views {args.size} "
          f"({mask_px / len(scene[2]):.0f} mask px per view), {args.steps} steps (timed after {args.skip}), "
          f"{torch.get_num_threads()} torch threads, medians of {args.repeats} interleaved rounds")  # fmt: skip
    base = tuple(statistics.median(t[i] for t in times["off"]) for i in (0, 1))
    print(f"{'configuration':<20}{'ms/step':>9}{'CPU ms/step':>13}{'ratio':>8}{'ratio CPU':>11}{'1 - cos':>9}")
    for name in names:
        wall, cpu, nc = (statistics.median(t[i] for t in times[name]) for i in (0, 1, 2))
        print(f"{name:<20}{1e3 * wall:>9.1f}{1e3 * cpu:>13.1f}{wall / base[0]:>8.2f}{cpu / base[1]:>11.2f}"
              f"{nc:>9.3f}")  # fmt: skip
    print("(1 - cos: the last window's mean depth-normal inconsistency on the geometric steps; target ratio <= 1.3)")


if __name__ == "__main__":
    main()
