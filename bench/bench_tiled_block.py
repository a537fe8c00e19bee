"""A block where tiling matters, run tiled on a local Ray instance and as one untiled process, side by side.

Each run is a separate ``hybridsplat run`` process; its wall time and the peak resident memory of its whole process
tree (the driver, and for the tiled run the Ray instance and its workers) are sampled every 0.2 s. Printed per run:
wall time, peak memory, C2C mean and completeness of the MVS and merged products, held-out PSNR of merged (whole
image and inside the masks), fused points; for the tiled run the tiles, the points the overlaps gave up, positions
kept by two tiles (must be 0), the cost model's prediction against what happened, and the ratios tiled / untiled.

    python bench/bench_tiled_block.py --scene BLOCK/scene --work W --tiles 2x2 --workers 2 --train-iterations 600

``--name`` names the tiled project (default ``tiled``), ``--also`` shows tiled projects of earlier runs beside it
(e.g. one run with ``-- --no-tile-context``: the tiles trained alone, the control of the neighbour context).

The scene: ``hybridsplat synth --preset aerial --seed 2 --views 124 --test-views 6 --width 320 --height 240``
(126 training photos: a 11 × 10 nadir grid and 16 obliques over the 100 m × 80 m yard). Both runs get the same
options; extra ``run`` options after ``--``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import psutil

from hybridsplat.layout import ProjectLayout
from hybridsplat.project_io import stage_result
from hybridsplat.stages.convert import ConvertStage


def _tree_rss_mb(process: psutil.Process) -> float:
    total = 0
    for p in [process, *process.children(recursive=True)]:
        try:
            total += p.memory_info().rss
        except psutil.Error:
            pass
    return total / 2**20


def timed_run(args: list[str]) -> tuple[float, float]:
    """Run ``hybridsplat run ARGS`` in its own process: (wall seconds, peak MB of its process tree)."""
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "hybridsplat", "run", *args, "--quiet"])
    watched, peak, stop = psutil.Process(proc.pid), [0.0], threading.Event()

    def sample() -> None:
        while not stop.is_set():
            try:
                peak[0] = max(peak[0], _tree_rss_mb(watched))
            except psutil.Error:
                pass
            stop.wait(0.2)

    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    code = proc.wait()
    stop.set()
    thread.join()
    if code != 0:
        raise SystemExit(f"hybridsplat run {' '.join(args)} failed with exit code {code}")
    return time.perf_counter() - start, peak[0]


def products(project: Path) -> dict[str, float]:
    layout = ProjectLayout(project)
    metrics = json.loads(layout.metrics_json.read_text())["products"]
    out: dict[str, float] = {}
    for name in ("mvs", "merged"):
        c2c = metrics[name]["c2c"]
        out[f"{name} C2C mean (mm)"] = 1000 * c2c["mean"]
        out[f"{name} completeness"] = c2c["completeness"]
    images = metrics["merged"]["images"]
    out["merged PSNR whole (dB)"] = images["full"]["psnr"]
    out["merged PSNR masked (dB)"] = images["masked"]["psnr"]
    manifest = json.loads(layout.manifest.read_text())["stages"]
    out["fused points"] = stage_result(layout, ConvertStage).gaussians
    appearance = manifest.get("appearance") or {}
    out["appearance stage (s)"] = float(appearance.get("seconds") or 0.0)  # tiled: tile by tile
    return out


def border_statistics(plan, positions: np.ndarray) -> tuple[float, int]:
    """(seam ratio, near pairs across core borders) of a cloud under a tile plan: the seam check of
    :func:`recon.tiling.seam_check`, and the points whose nearest point owned by another tile is closer than a
    quarter of the median spacing (a surface kept by two tiles shows as such pairs; the untiled cloud under the same
    plan is the control)."""
    from scipy.spatial import cKDTree

    from recon.tiling import seam_check

    owner = plan.owner(positions)
    spacing = float(np.median(cKDTree(positions).query(positions, k=2)[0][:, 1]))
    near = 0
    for tile in np.unique(owner):
        mine, others = positions[owner == tile], positions[owner != tile]
        if len(others):
            near += int((cKDTree(others).query(mine, k=1)[0] < 0.25 * spacing).sum())
    return seam_check(plan, positions).ratio, near


def _fused(project: Path) -> np.ndarray:
    from core.io.ply import load_ply_data

    rows = load_ply_data(ProjectLayout(project).fused_ply)["vertex"].data
    return np.stack([rows["x"], rows["y"], rows["z"]], axis=1).astype(np.float64)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", type=Path, required=True)
    parser.add_argument("--work", type=Path, required=True, help="folder for the two projects")
    parser.add_argument("--tiles", default="2x2")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--train-iterations", type=int, default=600)
    parser.add_argument("--skip-untiled", action="store_true", help="reuse WORK/untiled from an earlier run")
    parser.add_argument("--name", default="tiled", help="folder of the tiled project in WORK")
    parser.add_argument("--untiled-name", default="untiled", help="folder of the untiled project in WORK")
    parser.add_argument("--also", nargs="*", default=[], help="tiled projects of earlier runs in WORK to show beside")
    parser.add_argument("extra", nargs="*", help="more run options (after --)")
    args = parser.parse_args()
    common = [str(args.scene), "--train-iterations", str(args.train_iterations), *args.extra]
    runs = {}
    if not args.skip_untiled:
        runs[args.untiled_name] = timed_run([*common, "--out", str(args.work / args.untiled_name)])
    runs[args.name] = timed_run(
        [*common, "--out", str(args.work / args.name), "--tiles", args.tiles, "--workers", str(args.workers)]
    )
    names = [args.untiled_name, args.name, *args.also]
    figures = {name: products(args.work / name) for name in names}
    print(
        f"{'':28s} "
        + " ".join(f"{n:>14s}" for n in names)
        + " "
        + " ".join(f"{n + '/untiled':>20s}" for n in names[1:])
    )
    for key in figures[args.untiled_name]:
        a = figures[args.untiled_name][key]
        row = " ".join(f"{figures[n][key]:14.4f}" for n in names)
        ratios = " ".join(f"{figures[n][key] / a if a else float('nan'):20.4f}" for n in names[1:])
        print(f"{key:28s} {row} {ratios}")
    for i, what in enumerate(("wall time (s)", "peak memory (MB)")):
        a = runs[args.untiled_name][i] if args.untiled_name in runs else float("nan")
        b = runs[args.name][i]
        print(f"{what:28s} {args.untiled_name} {a:.1f}, {args.name} {b:.1f} ({b / a:.3f}x; this run's projects only)")
    tiled = ProjectLayout(args.work / args.name)
    record = json.loads(tiled.record("tiles").read_text())
    pred = record["prediction"]
    from recon.tiling import read_tile_plan

    plan = read_tile_plan(tiled.tile_plan)
    print(f"tiles {record['grid']}, photos per tile {record['photos_per_tile']}, overlap {record['overlap_m']:.2f} m")
    tiled_xyz, untiled_xyz = _fused(args.work / args.name), _fused(args.work / args.untiled_name)
    exact = len(tiled_xyz) - len(np.unique(tiled_xyz, axis=0))
    print(
        f"fused points the tiles gave up to a neighbour's core {sum(record['stitched']['fused_dropped'])}, "
        f"stitched positions kept twice {exact}"
    )
    for name, xyz in (("untiled (control)", untiled_xyz), ("tiled", tiled_xyz)):
        ratio, near = border_statistics(plan, xyz)
        print(f"{name:18s} under the plan: seam ratio {ratio:.3f}, near pairs across borders {near}")
    print(f"cost model ({pred['rates']['source']} rates): tiles predicted {pred['wall_s']:.0f} s, "
          f"{pred['peak_mb']:.0f} MB; measured {pred['measured_wall_s']:.0f} s "
          f"({pred['measured_wall_s'] / pred['wall_s']:.2f}x), {pred['measured_peak_mb']:.0f} MB "
          f"({pred['measured_peak_mb'] / pred['peak_mb']:.2f}x)")  # fmt: skip


if __name__ == "__main__":
    main()
