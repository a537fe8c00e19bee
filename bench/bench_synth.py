"""Benchmark of synthetic scene generation: wall time per preset and per stage, rays per second, statistics.

    python bench/bench_synth.py            # tiny, tabletop and aerial at their default sizes
    python bench/bench_synth.py --quick    # tiny, and tabletop/aerial at 16 views of 320x240

Prints one row per preset (views, image size, seconds per stage, seconds per view, LiDAR points) and the
cross-view colour std / image gradient per material kind, side by side (non-collaborative vs textured).
Timings are wall-clock on whatever the machine is doing at the time: on shared cores they are noisy; the CPU
time of the process (all its threads) is printed beside the wall time as a steadier figure.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data_synth import generate_scene  # noqa: E402


def run(preset: str, out: Path, **overrides: object) -> dict[str, object]:
    stamps: dict[str, float] = {}
    start = time.perf_counter()
    cpu_start = time.process_time()

    def progress(stage: str, done: int, total: int) -> None:
        stamps.setdefault(stage, time.perf_counter())
        stamps[f"{stage}_end"] = time.perf_counter()

    generate_scene(preset, out, seed=0, progress=progress, **overrides)
    total = time.perf_counter() - start
    cpu = time.process_time() - cpu_start
    meta = json.loads((out / "scene.json").read_text())
    stages = {}
    order = ["render", "lidar", "stats", "write"]
    prev = start
    for stage in order:
        end = stamps.get(f"{stage}_end", prev)
        stages[stage] = end - prev
        prev = end
    return {"preset": preset, "total_s": total, "cpu_s": cpu, "stages": stages, "meta": meta}


def kind_summary(meta: dict) -> dict[str, tuple[float, ...]]:
    """Per material kind: exact cross-view std, image-sampled std, mean and median image gradient (averaged)."""
    out: dict[str, list[tuple[float, ...]]] = {}
    for m in meta["materials"]:
        name = m["name"]
        if name not in meta["cross_view_color_std"]:
            continue
        row = (
            meta["cross_view_color_std"][name],
            meta["cross_view_color_std_image"][name],
            meta["image_gradient"].get(name, float("nan")),
            meta["image_gradient_median"].get(name, float("nan")),
        )
        out.setdefault(m["kind"], []).append(row)
    return {k: tuple(sum(v[i] for v in rows) / len(rows) for i in range(4)) for k, rows in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="smaller tabletop/aerial (16 views, 320x240)")
    parser.add_argument("--keep", type=Path, default=None, help="keep the scenes in this folder")
    args = parser.parse_args()
    small = {"views": 16, "width": 320, "height": 240} if args.quick else {}
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench_synth_"))
    root.mkdir(parents=True, exist_ok=True)
    results = []
    try:
        for preset, overrides in (("tiny", {}), ("tabletop", small), ("aerial", small)):
            out = root / preset
            if out.exists():
                shutil.rmtree(out)
            r = run(preset, out, **overrides)
            results.append(r)
            m = r["meta"]
            n_views = len(m["views"]["train"]) + len(m["views"]["test"])
            size = m["image_size"]
            st = r["stages"]
            print(
                f"{preset:9s} views {len(m['views']['train']):3d}+{len(m['views']['test']):<2d} "
                f"{size['width']}x{size['height']}  wall {r['total_s']:7.1f} s  cpu {r['cpu_s']:7.1f} s  "
                f"render {st['render']:6.1f} s "
                f"({st['render'] / n_views:5.2f} s/view)  lidar {st['lidar']:5.1f} s ({m['lidar_points']} pts)  "
                f"stats {st['stats']:5.1f} s  write {st['write']:5.1f} s  gsd {m['gsd_m'] * 1000:.2f} mm",
                flush=True,
            )
        print("\ncross-view colour std (8-bit; exact rays | image-sampled) and image gradient per material kind:")
        for r in results:
            summary = kind_summary(r["meta"])
            tex = summary.get("textured", (float("nan"),) * 4)
            for kind, (exact, image, grad, grad_med) in sorted(summary.items()):
                ratio = image / tex[1] if tex[1] > 0 else float("nan")
                print(
                    f"  {r['preset']:9s} {kind:12s} exact {exact:6.2f} | image {image:6.2f} "
                    f"(x{ratio:4.1f} of textured)  gradient mean {grad:6.2f} (x{grad / tex[2]:4.2f}) "
                    f"median {grad_med:6.2f} (x{grad_med / tex[3]:4.2f} of textured)"
                )
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
