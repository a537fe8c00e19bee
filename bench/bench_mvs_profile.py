"""Profile of the CPU MVS per part, before and after, on the views of an existing dense workspace.

Prints seconds per view of each part of :mod:`recon.mvs_cpu` — pyramid set-up, matching cost (warp + NCC +
aggregation; the torch version split into warp, box filters and the rest), hypothesis generation (propagation
shifts, medians), the sweep and refinement bookkeeping, the geometric-consistency filter, normals — for the
module of a git revision ("before", default: the last commit of the torch-only MVS) and for today's module, on the
same views in one run, with their ratios. Parts are the exclusive wall time of the module's functions (a stack of
wrappers: a part nested in another counts once, in the inner one); "rest" is the remainder of the view.

    python bench/bench_mvs_profile.py --workspace /tmp/demo29/project/dense [--views 4] [--before REV|none]

The geometric filter and the normals run on the workspace's own photometric maps (as in ``recon.mvs``); fusion
(pycolmap) runs once on a copy of the workspace with ``--fusion``. Timings on a shared machine are noisy: compare
the ratios of one run, and read the load printed at the start and the end.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from recon.mvs_cpu_options import CpuMvsOptions

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

BEFORE_REV = "4a92792"
"""The last commit whose ``recon/mvs_cpu.py`` is the torch-only MVS (2.2–2.7 s a view at 320×240)."""

BEFORE_EFFORT = {"num_planes": 64, "refine_rounds": 3}
"""The effort options the 'before' module reads (its defaults; today's are None = from the quality preset)."""

# function name -> part label; the functions missing from a module are skipped
PARTS = {
    "_resize": "pyramid set-up",
    "_make_level": "pyramid set-up",
    "_sample": "warp (grid_sample)",
    "_box": "box filters (NCC, plane hyps)",
    "_cost": "matching cost (warp+NCC+best-k)",
    "_median": "hypotheses: median",
    "_shift": "hypotheses: propagation shifts",
    "_evaluate": "sweep/parabola bookkeeping",
    "_take_best": "refinement bookkeeping",
    "_parabola": "sweep/parabola bookkeeping",
    "geometric_filter": "geometric consistency",
    "normals_from_depth": "normals",
}


def load_before(rev: str) -> ModuleType:
    """``recon/mvs_cpu.py`` of git revision ``rev`` imported as module ``mvs_cpu_before`` (from a temporary file)."""
    source = subprocess.run(
        ["git", "-C", str(REPO), "show", f"{rev}:recon/mvs_cpu.py"], check=True, capture_output=True, text=True
    ).stdout
    path = Path(tempfile.mkdtemp(prefix="mvs_before_")) / "mvs_cpu_before.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("mvs_cpu_before", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["mvs_cpu_before"] = module
    spec.loader.exec_module(module)
    return module


def warm_up(module: ModuleType) -> float:
    """Seconds of a first small depth estimate, normals and filter with ``module``: numba compiles its kernels or
    loads them from its cache (recon/__pycache__) on the first call, which then stays out of the figures."""
    from recon.mvs_cpu_options import CpuMvsOptions

    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    img = rng.random((40, 48)).astype(np.float32)
    K = np.array([[50.0, 0, 24], [0, 50.0, 20], [0, 0, 1]])
    move = np.eye(4)
    move[0, 3] = -0.2
    opts = CpuMvsOptions(coarse_size=24, **BEFORE_EFFORT)
    est = module.estimate_depth(img, [np.roll(img, 2, axis=1)], K, [K], [move], (2.0, 6.0), opts)
    module.geometric_filter(est.depth, K, [est.depth], [K], [move])
    module.normals_from_depth(est.depth, K)
    return time.perf_counter() - t0


class _Profiler:
    """Exclusive wall seconds per part of a module's wrapped functions (a stack: nested calls count once)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self._stack: list[list[float]] = []  # per active call: [start, seconds spent in nested wrapped calls]

    def wrap(self, fn: Callable, label: str) -> Callable:
        def timed(*args, **kwargs):
            self._stack.append([time.perf_counter(), 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                start, nested = self._stack.pop()
                spent = time.perf_counter() - start
                self.seconds[label] += spent - nested
                if self._stack:
                    self._stack[-1][1] += spent

        return timed


@contextmanager
def profiled(module: ModuleType) -> Iterator[_Profiler]:
    """Wraps the module's functions named in ``PARTS`` for the duration of the block."""
    prof = _Profiler()
    saved = {name: getattr(module, name) for name in PARTS if hasattr(module, name)}
    for name, fn in saved.items():
        setattr(module, name, prof.wrap(fn, PARTS[name]))
    try:
        yield prof
    finally:
        for name, fn in saved.items():
            setattr(module, name, fn)


@dataclass
class Views:
    """The inputs of ``estimate_depth`` per reference view of a workspace, and its photometric maps."""

    workspace: Path
    refs: list[int]
    names: dict[int, str]
    sources: dict[int, list[int]]
    depth_range: dict[int, tuple[float, float]]
    Ks: dict[int, np.ndarray]
    poses: dict[int, np.ndarray]  # 4×4 cam_from_world

    def rel(self, src: int, ref: int) -> np.ndarray:
        return self.poses[src] @ np.linalg.inv(self.poses[ref])

    def gray(self, i: int) -> np.ndarray:
        from recon.mvs import _load_gray

        return _load_gray(self.workspace / "images" / self.names[i])


def read_views(workspace: Path, num_views: int, num_sources: int) -> Views:
    """``num_views`` evenly spaced registered views of a dense workspace, with their sources and depth ranges."""
    import pycolmap

    from recon.view_selection import select_views

    rec = pycolmap.Reconstruction(str(workspace / "sparse"))
    ids = sorted(int(i) for i in rec.reg_image_ids())
    sel = select_views(rec, num_sources=num_sources)
    refs = [ids[k] for k in np.linspace(0, len(ids) - 1, min(num_views, len(ids))).round().astype(int)]
    poses = {}
    for i in ids:
        m = np.eye(4)
        m[:3] = np.asarray(rec.image(i).cam_from_world().matrix())
        poses[i] = m
    return Views(
        workspace,
        refs,
        {i: rec.image(i).name for i in ids},
        sel.sources,
        sel.depth_range,
        {i: np.asarray(rec.image(i).camera.calibration_matrix(), np.float64) for i in ids},
        poses,
    )


def profile_module(module: ModuleType, views: Views, options: CpuMvsOptions) -> tuple[dict[str, float], float]:
    """Seconds per view of each part, and in all, of one MVS module: depth, photometric normals, geometric filter
    and geometric normals per view (the filter on the workspace's photometric maps when it has them)."""
    from recon.workspace import read_array

    total = 0.0
    with profiled(module) as prof:
        for ref in views.refs:
            srcs = views.sources.get(ref, [])
            args = (
                views.gray(ref),
                [views.gray(s) for s in srcs],
                views.Ks[ref],
                [views.Ks[s] for s in srcs],
                [views.rel(s, ref) for s in srcs],
                views.depth_range[ref],
            )
            maps = {i: _photometric(views, i, read_array) for i in [ref, *srcs]}
            t0 = time.perf_counter()
            est = module.estimate_depth(*args, options)
            module.normals_from_depth(est.depth, views.Ks[ref], options.normal_radius)
            ref_map = maps[ref] if maps[ref] is not None else est.depth
            src_maps = [maps[s] if maps[s] is not None else est.depth for s in srcs]
            depth, _ = module.geometric_filter(
                ref_map,
                views.Ks[ref],
                src_maps,
                [views.Ks[s] for s in srcs],
                [views.rel(s, ref) for s in srcs],
                options.geom_max_reproj_px,
                options.geom_max_rel_depth,
                min(options.geom_min_consistent, max(len(srcs), 1)),
            )
            module.normals_from_depth(depth, views.Ks[ref], options.normal_radius)
            total += time.perf_counter() - t0
    n = len(views.refs)
    parts = {k: v / n for k, v in prof.seconds.items()}
    parts["rest"] = total / n - sum(parts.values())
    return parts, total / n


def _only(views: Views, ref: int) -> Views:
    return Views(**{**views.__dict__, "refs": [ref]})


def _photometric(views: Views, i: int, read_array) -> np.ndarray | None:
    path = views.workspace / "stereo" / "depth_maps" / f"{views.names[i]}.photometric.bin"
    return read_array(path) if path.is_file() else None


def time_fusion(workspace: Path) -> tuple[float, int]:
    """Seconds and points of pycolmap fusion of a copy of the workspace (its maps as they are)."""
    from recon.mvs import FusionOptions, fuse

    with tempfile.TemporaryDirectory(prefix="mvs_fusion_") as tmp:
        copy = Path(tmp) / "dense"
        shutil.copytree(workspace, copy, ignore=shutil.ignore_patterns("fused.ply*"))
        t0 = time.perf_counter()
        n = fuse(copy, FusionOptions(), log_path=Path(tmp) / "fusion.log")
        return time.perf_counter() - t0, n


def print_table(columns: dict[str, tuple[dict[str, float], float]]) -> None:
    """One row per part, one column (s/view) per module, and the share of the last column's total."""
    labels = list(dict.fromkeys(label for parts, _ in columns.values() for label in parts))
    names = list(columns)
    head = "".join(f"{n:>14}" for n in names)
    print(f"\n{'part (s/view)':<36}{head}{'share':>8}")
    last_parts, last_total = columns[names[-1]]
    for label in labels:
        cells = "".join(f"{columns[n][0].get(label, 0.0):>14.3f}" for n in names)
        print(f"{label:<36}{cells}{last_parts.get(label, 0.0) / last_total:>8.0%}")
    print(f"{'total':<36}{''.join(f'{columns[n][1]:>14.3f}' for n in names)}")
    if len(names) > 1:
        first = columns[names[0]][1]
        print(f"{'ratio to ' + names[0]:<36}{''.join(f'{first / columns[n][1]:>13.2f}x' for n in names)}")


def _parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workspace", required=True, help="COLMAP dense workspace (images/, sparse/, stereo/)")
    ap.add_argument("--views", type=int, default=4, help="reference views, evenly spaced over the registered ones")
    ap.add_argument("--before", default=BEFORE_REV, help="git revision of the 'before' module, or 'none'")
    ap.add_argument("--threads", type=int, default=2, help="torch threads (and kernel threads)")
    ap.add_argument("--fusion", action="store_true", help="also time pycolmap fusion on a copy of the workspace")
    ap.add_argument("--quality", default="balanced", help="quality preset of today's module (fast|balanced|high)")
    return ap.parse_args()


def main() -> None:
    args = _parse_args()
    import torch

    import recon.mvs_cpu as after
    from recon.mvs_cpu_options import CpuMvsOptions

    torch.set_num_threads(args.threads)
    options = CpuMvsOptions(quality=args.quality)
    views = read_views(Path(args.workspace), args.views, options.num_sources)
    h, w = views.gray(views.refs[0]).shape
    print(f"load {os.getloadavg()}; torch threads {torch.get_num_threads()}; {len(views.refs)} views of {w}×{h}")
    modules = {} if args.before == "none" else {f"before {args.before}": load_before(args.before)}
    modules["after"] = after
    opts = {name: replace(options, **BEFORE_EFFORT) for name in modules}
    opts["after"] = options
    for name, module in modules.items():  # JIT compilation and first-call set-up stay out of the figures
        profile_module(module, _only(views, views.refs[0]), opts[name])
    sums: dict[str, dict[str, float]] = {name: defaultdict(float) for name in modules}
    for ref in views.refs:  # modules alternate view by view: a change of load hits both
        for name, module in modules.items():
            parts, total = profile_module(module, _only(views, ref), opts[name])
            for label, seconds in {**parts, "total": total}.items():
                sums[name][label] += seconds / len(views.refs)
    print_table({name: ({k: v for k, v in s.items() if k != "total"}, s["total"]) for name, s in sums.items()})
    if args.fusion:
        seconds, n = time_fusion(Path(args.workspace))
        count = len(list((Path(args.workspace) / "images").iterdir()))
        print(f"\nfusion (pycolmap, single-threaded): {seconds / count:.3f} s/view, {n} points")
    print(f"load {os.getloadavg()}")


if __name__ == "__main__":
    main()
