"""The hole-filled trusted depth (``fusion.clean.hole_filled_depth``, the merge's survey-point rule) alone and beside
a second process doing the same, with OpenBLAS's threads as they come and limited to one, side by side.

    python bench/bench_hole_fill_contention.py [--width 1000 --height 666 --holes 60]

scipy's ``LinearNDInterpolator`` solves a 2 × 2 system per Delaunay triangle through LAPACK; OpenBLAS hands each such
call to its threads, which spin while they wait. Alone that costs nothing; beside another process on the same
cores the spinning threads starve each other (a fountain project's merge sat minutes in ``exec_blas_async_wait``).
The function now runs that step with one BLAS thread (threadpoolctl); "threads as they come" below is the same
interpolation without the limit. Run it on an otherwise idle machine: the second process is part of the figure.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _depth(width: int, height: int, holes: int) -> np.ndarray:
    """A tilted plane 2 m away with ``holes`` round holes of 5–60 px radius (inf), seeded."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:height, 0:width]
    depth = (2.0 + 0.001 * x + 0.0005 * y).astype(np.float32)
    for _ in range(holes):
        cy, cx, r = rng.integers(0, height), rng.integers(0, width), rng.integers(5, 60)
        depth[(y - cy) ** 2 + (x - cx) ** 2 < r * r] = np.inf
    return depth


def _unlimited(depth: np.ndarray) -> np.ndarray:
    """The interpolation step of ``hole_filled_depth`` without the thread limit (the code before it)."""
    import cv2
    from scipy.interpolate import LinearNDInterpolator

    holes = ~np.isfinite(depth)
    border = ~holes & cv2.dilate(holes.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    sites, targets = np.argwhere(border).astype(np.float64), np.argwhere(holes).astype(np.float64)
    return LinearNDInterpolator(sites, depth[border].astype(np.float64))(targets)


def _timed(mode: str, depth: np.ndarray) -> float:
    from fusion.clean import hole_filled_depth

    t0 = time.perf_counter()
    _unlimited(depth) if mode == "unlimited" else hole_filled_depth(depth)
    return time.perf_counter() - t0


def _two_at_once(mode: str, args: argparse.Namespace) -> float:
    """Seconds of the slower of two fresh processes running ``mode`` at the same time (each builds its depth)."""
    cmd = [sys.executable, __file__, "--child", mode, "--width", str(args.width), "--height", str(args.height),
           "--holes", str(args.holes)]  # fmt: skip
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True) for _ in range(2)]
    return max(float(p.communicate()[0].split()[-1]) for p in procs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=1000)
    parser.add_argument("--height", type=int, default=666)
    parser.add_argument("--holes", type=int, default=60)
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    depth = _depth(args.width, args.height, args.holes)
    if args.child:
        print(_timed(args.child, depth))
        return
    print(f"depth {args.width} x {args.height}, {int((~np.isfinite(depth)).sum())} hole pixels")
    rows = {mode: (_timed(mode, depth), _two_at_once(mode, args)) for mode in ("unlimited", "one BLAS thread")}
    print(f"{'BLAS threads':<18}{'alone s':>10}{'beside a 2nd process s':>26}{'ratio':>8}")
    for mode, (alone, beside) in rows.items():
        print(f"{mode:<18}{alone:10.2f}{beside:26.2f}{beside / alone:8.1f}")
    print(f"beside a 2nd process, unlimited / one thread: {rows['unlimited'][1] / rows['one BLAS thread'][1]:.0f}x")


if __name__ == "__main__":
    main()
