"""Per-group cost of the classifier's features on a reconstructed project, side by side.

Reads ``P/dense`` (``fused.ply`` + ``.vis``, the photos and depth maps of the dense reconstruction: held-out
photos never take part) and times each feature group on the whole fused cloud: geometric (``compute_features``
with that group alone: the space-filling-curve order, the finest k-NN every other group reuses, three scales),
then the multi-view group's own function on the same points, and ``compute_features`` with the three groups.
Photos and depth maps are decoded once beforehand (their decode time is printed apart), so the figures compare the
groups' work, not the file reads; each figure is the best of ``--repeat`` runs. A figure taken while something else
runs on the machine is not a figure: the load (``uptime``) is printed before and after::

    python bench/bench_classify_features.py --project P [--repeat 3] [--max-points 500000]
"""

from __future__ import annotations

import argparse
import subprocess
import time
from collections.abc import Callable

import numpy as np

from classify.features import (
    ALL_GROUPS,
    FeatureGroup,
    FeatureOptions,
    ViewData,
    compute_features,
    views_from_workspace,
)
from classify.features.multiview import multiview_features
from core.pointcloud import PointCloud
from hybridsplat.layout import ProjectLayout
from recon.workspace import read_fused


def _uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    except OSError:
        import os

        return "load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def _best(fn: Callable[[], object], repeat: int) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def _subset(cloud: PointCloud, n: int, seed: int = 0) -> PointCloud:
    if n <= 0 or len(cloud) <= n:
        return cloud
    keep = np.sort(np.random.default_rng(seed).choice(len(cloud), n, replace=False))
    vis = None if cloud.visibility is None else [cloud.visibility[i] for i in keep]
    normals = None if cloud.normals is None else cloud.normals[keep]
    colors = None if cloud.colors is None else cloud.colors[keep]
    return PointCloud(cloud.positions[keep], cloud.origin, colors, normals, visibility=vis)


def _warm(views: ViewData, cloud: PointCloud) -> float:
    """Decode every photo and depth map once (the loaders cache them) and compile the numba kernels; seconds."""
    t0 = time.perf_counter()
    for v in views.cameras:
        views.image(v.name)
        views.depth(v.name)
    seconds = time.perf_counter() - t0
    small = _subset(cloud, 200)
    compute_features(small, FeatureOptions(groups=ALL_GROUPS), views)
    return seconds


def _group_runs(cloud: PointCloud, views: ViewData) -> dict[str, Callable[[], object]]:
    pos, vis, mv = cloud.positions, cloud.visibility, FeatureOptions().multiview
    return {"multiview": lambda: multiview_features(pos, vis, views, mv)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--project", required=True, help="project folder (its dense/ workspace is read)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per figure; the best is kept")
    ap.add_argument("--max-points", type=int, default=0, help="random subset of the fused cloud (0: all)")
    args = ap.parse_args()

    import numba

    dense = ProjectLayout(args.project).dense
    cloud = _subset(read_fused(dense), args.max_points)
    views = views_from_workspace(dense, cache=max(64, len(views_from_workspace(dense).cameras)))
    n = len(cloud)
    entries = sum(len(v) for v in cloud.visibility) if cloud.visibility is not None else 0
    print(f"load before: {_uptime()}")
    per_point = entries / max(n, 1)
    print(f"{dense}: {n:,} points, {len(views.cameras)} views, {per_point:.1f} fusing views a point")
    print(f"numba threads {numba.get_num_threads()}")
    print(f"decoding photos + depth maps once: {_warm(views, cloud):.2f} s (excluded below)")
    rows: list[tuple[str, int, float]] = []
    t, geo = _best(lambda: compute_features(cloud, FeatureOptions(groups=(FeatureGroup.GEOMETRIC,))), args.repeat)
    rows.append(("geometric (+ k-NN)", len(geo.names), t))  # type: ignore[union-attr]
    for name, fn in _group_runs(cloud, views).items():
        t, cols = _best(fn, args.repeat)
        rows.append((name, len(cols), t))  # type: ignore[arg-type]
    t, table = _best(lambda: compute_features(cloud, FeatureOptions(groups=ALL_GROUPS), views), args.repeat)
    rows.append(("compute_features default 3", len(table.names), t))  # type: ignore[union-attr]
    t_mv = dict((r[0], r[2]) for r in rows)["multiview"]
    print(f"{'group':28} {'features':>8} {'seconds':>9} {'points/s':>12} {'point-views/s':>14} {'x multiview':>12}")
    for name, count, t in rows:
        pv = f"{entries / t:14,.0f}" if entries else f"{'-':>14}"
        print(f"{name:28} {count:8d} {t:9.2f} {n / t:12,.0f} {pv} {t / t_mv:12.2f}")
    print(f"load after: {_uptime()}")


if __name__ == "__main__":
    main()
