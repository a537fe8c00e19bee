"""The eval stage's store of measurements (``eval.cache``): re-evaluations with and without it, side by side.

``python bench/bench_eval_cache.py PROJECT [--iterations 300] [--work DIR]``

PROJECT is a finished project with the baseline (e.g. a ``bench/bench_pipeline.py`` base project:
``OUT/runs/aerial/base``); it is copied to ``WORK`` (its ``cache/`` left out) and never changed. On the copy:

1. eval forced, cache off: what every re-evaluation cost before the store (all products measured);
2. eval forced, cache on and empty: the same work plus hashing and storing (the overhead);
3. eval forced again: every product restored;
4. a retraining (``train.training.iterations`` = ``--iterations``): train, clean, merge and eval rerun; eval
   measures only the products that changed (splats, merged) — the benchmark's knob sweeps do exactly this on copies
   of a base;
5. the same state, eval forced with the cache off: the figure step 4 replaces. The two metrics files must agree.

Prints each step's eval time, products measured / restored, the ratio to the no-cache figure and the machine load.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hybridsplat.layout import ProjectLayout  # noqa: E402
from hybridsplat.options import with_option  # noqa: E402
from hybridsplat.pipeline import load_config, run_pipeline  # noqa: E402
from hybridsplat.project_io import stage_result  # noqa: E402
from hybridsplat.stages import stage_options_types  # noqa: E402
from hybridsplat.stages.evaluate import EvalStage  # noqa: E402


def _load() -> str:
    return "load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def _eval(project: Path, cache: bool, force: bool = True, train: dict[str, object] | None = None) -> dict:
    """Run the pipeline on ``project`` with the eval stage's cache on or off (eval forced unless ``force`` is
    False) and the train stage's options changed by ``train`` ({option path: value}, e.g. training.iterations)."""
    config = load_config(project)
    eval_options = config.options("eval", stage_options_types()["eval"])
    config = config.with_stage_options("eval", replace(eval_options, cache=cache))
    if train:
        options = config.options("train", stage_options_types()["train"])
        for key, value in train.items():
            options = with_option(options, key, value)
        config = config.with_stage_options("train", options)
    stages = run_pipeline(project, config, force=["eval"] if force else ()).stages
    record = stages["eval"]
    metrics = json.loads(ProjectLayout(project).metrics_json.read_text())["products"]
    measured = sum(not p["skipped"] for p in metrics.values())
    reused = stage_result(ProjectLayout(project), EvalStage).reused or 0
    return {"seconds": record.seconds, "measured": measured - reused, "reused": reused, "metrics": metrics}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("project", type=Path)
    parser.add_argument("--iterations", type=int, default=300, help="training steps of the simulated retraining")
    parser.add_argument("--work", type=Path, default=None, help="scratch folder (default: a temporary one)")
    args = parser.parse_args()
    if not ProjectLayout(args.project).metrics_json.is_file():
        raise SystemExit(f"{args.project}: not an evaluated project (no eval/metrics.json)")
    work = args.work or Path(tempfile.mkdtemp(prefix="bench_eval_cache_"))
    copy = work / "project"
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(args.project, copy, ignore=shutil.ignore_patterns("cache"))
    print(f"{args.project} -> {copy}; {_load()}")

    rows = []
    t0 = time.perf_counter()
    rows.append(("1. every product, cache off", _eval(copy, cache=False)))
    rows.append(("2. every product, empty cache (stores)", _eval(copy, cache=True)))
    rows.append(("3. nothing changed (restores)", _eval(copy, cache=True)))
    retrain = {"training.iterations": args.iterations}
    rows.append(("4. after a retraining, cache on", _eval(copy, cache=True, force=False, train=retrain)))
    rows.append(("5. same state, cache off", _eval(copy, cache=False)))
    same = rows[3][1]["metrics"] == rows[4][1]["metrics"]
    reference = rows[0][1]["seconds"]
    print("\n| eval run | seconds | measured | restored | × step 1 |\n|---|---|---|---|---|")
    for name, r in rows:
        print(f"| {name} | {r['seconds']:.1f} | {r['measured']} | {r['reused']} | {r['seconds'] / reference:.2f} |")
    print(f"\nafter the retraining: {rows[3][1]['seconds']:.1f} s with the store against {rows[4][1]['seconds']:.1f} s "
          f"without ({rows[3][1]['seconds'] / rows[4][1]['seconds']:.2f}); metrics identical: {same}")  # fmt: skip
    print(f"total {time.perf_counter() - t0:.0f} s; {_load()}")
    if not same:
        raise SystemExit("the restored measurements differ from the measured ones")


if __name__ == "__main__":
    main()
