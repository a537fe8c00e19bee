"""Tiles on a simulated Ray cluster when things go wrong: a worker node killed mid-run, and an interrupted run resumed.

1. A head and two worker nodes as separate processes on 127.0.0.1 (``ray.cluster_utils.Cluster``; the head takes
   no tasks, each worker one CPU). An undisturbed tiled run, then the same run where a worker node is removed (its
   raylet and workers killed) as soon as the first tile finished its mvs stage: the task that ran there is retried
   on the other node, resuming after the last stage its tile recorded. Printed: what each tile had finished when
   the node went, and whether every stitched product (fused cloud, classified cloud, trained and cleaned splats,
   merged product) is byte for byte the undisturbed run's.
2. ``hybridsplat run --tiles`` in its own process, interrupted (SIGINT, as Ctrl-C) once the first tile finished all
   its stages, then run again: printed, per tile, the stages the second run redid and those it found up to date.

    python bench/bench_tiles_faults.py --scene SCENE --work W [--tiles 2x2]

SCENE: e.g. ``hybridsplat synth --preset aerial --seed 0 --views 24 --width 256 --height 192 --test-views 2``.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from hybridsplat.layout import ProjectLayout

PRODUCTS = ("dense/fused.ply", "classify/points.ply", "splats/trained.ply", "splats/cleaned.ply", "export/merged.ply")
TILE_OPTIONS = ["--train-iterations", "200", "--max-image-size", "192"]


def _config(scene: Path, tiles: str, address: str):
    from fusion.train.masked import MaskedTrainingOptions
    from hybridsplat.config import InputOptions, ProjectConfig
    from hybridsplat.options import options_with
    from hybridsplat.stages.tiles import TilesOptions
    from recon.mvs import MvsOptions

    stages = {
        "mvs": options_with(MvsOptions, {"max_image_size": 192}),
        "train": options_with(MaskedTrainingOptions, {"training.iterations": 200}),
        "tiles": TilesOptions(grid=tiles, ray_address=address),
    }
    return ProjectConfig(input=InputOptions(path=str(scene)), stages=stages)


def _tile_manifests(project: Path) -> dict[str, dict]:
    out = {}
    for path in sorted(ProjectLayout(project).tiles_dir.glob("r*c*/manifest.json")):
        try:
            out[path.parent.name] = json.loads(path.read_text())["stages"]
        except (OSError, ValueError):
            pass  # being written
    return out


def killed_worker(scene: Path, work: Path, tiles: str) -> None:
    from ray.cluster_utils import Cluster

    from hybridsplat.pipeline import run_pipeline

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 0})
    workers = [cluster.add_node(num_cpus=1) for _ in range(2)]
    cluster.wait_for_nodes()
    try:
        start = time.perf_counter()
        run_pipeline(work / "undisturbed", _config(scene, tiles, cluster.address))
        print(f"undisturbed run on the 3-node cluster: {time.perf_counter() - start:.1f} s")
        cut: dict[str, str] = {}

        def kill_when_a_tile_passed_mvs() -> None:
            while not cut:
                state = _tile_manifests(work / "disturbed")
                if any("mvs" in stages for stages in state.values()):
                    cluster.remove_node(workers[1])
                    cut.update({t: ",".join(s) or "-" for t, s in state.items()})
                    break
                time.sleep(0.2)

        killer = threading.Thread(target=kill_when_a_tile_passed_mvs, daemon=True)
        killer.start()
        start = time.perf_counter()
        run_pipeline(work / "disturbed", _config(scene, tiles, cluster.address))
        print(f"disturbed run: a worker node removed when the tiles had finished {cut} (the others had not started);"
              f" the run ended in {time.perf_counter() - start:.1f} s")  # fmt: skip
        for product in PRODUCTS:
            a, b = (work / run / product for run in ("undisturbed", "disturbed"))
            same = a.is_file() and b.is_file() and a.read_bytes() == b.read_bytes()
            size = b.stat().st_size if b.is_file() else 0
            print(f"  {product:22s} {'identical' if same else 'DIFFERENT'} ({size} B)")
    finally:
        cluster.shutdown()


def interrupted_and_resumed(scene: Path, work: Path, tiles: str) -> None:
    project = work / "interrupted"
    args = [sys.executable, "-m", "hybridsplat", "run", str(scene), "--out", str(project), "--tiles", tiles, "--quiet",
            *TILE_OPTIONS]  # fmt: skip
    proc = subprocess.Popen(args)
    while proc.poll() is None:
        done = [t for t, s in _tile_manifests(project).items() if "clean" in s]
        if done:
            proc.send_signal(signal.SIGINT)
            print(f"interrupted (SIGINT) after tile {done[0]} finished; exit code {proc.wait()}")
            break
        time.sleep(0.5)
    before = {t: set(s) for t, s in _tile_manifests(project).items()}
    start = time.perf_counter()
    subprocess.run(args, check=True)
    record = json.loads(ProjectLayout(project).record("tiles").read_text())
    print(f"resumed in {time.perf_counter() - start:.1f} s; per tile (recorded before the resume -> redone):")
    for tile in record["per_tile"]:
        redone = [n for n, s in tile["stages"].items() if not (s["cached"] or s["skipped"])]
        print(f"  {tile['tile']}: finished before {sorted(before.get(tile['tile'], set()))}, redone {redone}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", type=Path, required=True)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--tiles", default="2x2")
    parser.add_argument("--only", choices=("killed", "interrupted"), default=None)
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    if args.only in (None, "killed"):
        killed_worker(args.scene.resolve(), args.work.resolve(), args.tiles)
    if args.only in (None, "interrupted"):
        interrupted_and_resumed(args.scene.resolve(), args.work.resolve(), args.tiles)


if __name__ == "__main__":
    main()
