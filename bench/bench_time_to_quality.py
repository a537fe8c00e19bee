"""Time to quality (issue 32): when does the hybrid's merged product reach the plateaued whole-scene baseline's
held-out PSNR, against the baseline's own time?

    python bench/bench_time_to_quality.py PROJECT --budgets 0 250 500 1000 [--work DIR]

PROJECT is a finished ``hybridsplat run`` with the baseline trained to its plateau (e.g. 8 000 steps, with
checkpoints) and ``eval`` run, alone on the machine (its stage seconds are the figures). For each appearance budget
B in ``--budgets`` (0 = the appearance stage off: the survey layer keeps its converted look), a copy of PROJECT
under ``--work`` reruns ``appearance`` (at most B steps: the stage's early stop as configured, its cap in passes
over the photos off), ``merge`` and
``eval`` through the pipeline (eval's cache rescores only the products that changed). Printed per budget:

- the hybrid's seconds after SfM: the project's own seconds of mvs, classify, masks, convert, train, clean and
  background, plus the copy's appearance and merge (the SfM is the baseline's input too, so neither counts it);
- the merged product's held-out PSNR / SSIM / LPIPS on the whole photo, and PSNR inside the region masks;
- its seconds as a share of the baseline's (the baseline stage's seconds to its last step).

Beside them the baseline's checkpoints (seconds since the stage started, held-out PSNR), so both curves are read
on the same held-out views. The budgets are a list fixed before the run; no default is chosen from this output
(it scores held-out views). Run it alone: the appearance seconds of the copies are figures too.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hybridsplat.layout import ProjectLayout  # noqa: E402
from hybridsplat.project_io import stage_result  # noqa: E402
from hybridsplat.stages.appearance import AppearanceStage  # noqa: E402
from hybridsplat.stages.baseline import BaselineStage  # noqa: E402

#: the hybrid's stages after SfM whose seconds the copies do not change (appearance and merge are rerun)
UPSTREAM = ("mvs", "classify", "masks", "convert", "train", "clean", "background")


def _stage_seconds(project: Path) -> dict[str, float]:
    """Seconds of each stage that ran (not skipped, not cached) in the project's manifest."""
    stages = json.loads(ProjectLayout(project).manifest.read_text())["stages"]
    return {name: rec["seconds"] for name, rec in stages.items() if not rec.get("skipped") and not rec.get("cached")}


def _image_scores(project: Path) -> dict[str, dict[str, float]]:
    """Held-out image scores per product of eval/metrics.json: psnr, ssim, lpips (whole photo), masked_psnr."""
    products = json.loads(ProjectLayout(project).metrics_json.read_text())["products"]
    out = {}
    for name, rec in products.items():
        images = rec.get("images") or {}
        if "full" in images:
            masked = images.get("masked") or {}
            out[name] = {**{k: images["full"][k] for k in ("psnr", "ssim", "lpips")}, "masked_psnr": masked.get("psnr")}
    return out


def _rerun_with_budget(project: Path, copy: Path, budget: int) -> None:
    """``copy`` = PROJECT less its report, appearance at most ``budget`` steps (0: off), then appearance, merge and
    eval rerun."""
    from hybridsplat.pipeline import load_config, run_pipeline
    from hybridsplat.stages import registered_stages
    from hybridsplat.terminal import Terminal

    if copy.exists():
        shutil.rmtree(copy)
    shutil.copytree(project, copy, ignore=shutil.ignore_patterns("report"), symlinks=True)
    config = load_config(copy)
    appearance = config.stages["appearance"]
    training = appearance.training
    if budget > 0:
        training = replace(training, iterations=budget, min_iterations=min(training.min_iterations, budget))
    options = replace(appearance, enabled=budget > 0, max_passes=0, training=training)  # B steps, no pass cap
    names = ["appearance", "merge", "eval"]
    stages = [s for s in registered_stages() if s.name in names]
    run_pipeline(copy, config.with_stage_options("appearance", options), stages=stages, terminal=Terminal(quiet=True),
                 force=names)  # fmt: skip


def _fmt(value: float | None, digits: int) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("project", type=Path)
    parser.add_argument("--budgets", type=int, nargs="*", default=[0, 250, 500, 1000])
    parser.add_argument("--work", type=Path, default=None, help="folder of the copies (default: PROJECT.ttq)")
    args = parser.parse_args()
    project = args.project.resolve()
    work = (args.work or project.with_name(project.name + ".ttq")).resolve()
    seconds, scores = _stage_seconds(project), _image_scores(project)
    if "baseline" not in seconds or "baseline" not in scores:
        sys.exit(f"{project}: no baseline trained and scored in this project (run it with the baseline on)")
    baseline_s, target = seconds["baseline"], scores["baseline"]["psnr"]
    upstream = sum(seconds.get(name, 0.0) for name in UPSTREAM)
    baseline = stage_result(ProjectLayout(project), BaselineStage)
    print(f"{project.name}: baseline {baseline.iterations} steps, {baseline_s:.1f} s, held-out "
          f"{target:.2f} dB / SSIM {scores['baseline']['ssim']:.3f} / LPIPS {scores['baseline']['lpips']:.3f}, "
          f"masked {_fmt(scores['baseline']['masked_psnr'], 2)} dB")  # fmt: skip
    for step, t in sorted((int(k), v) for k, v in baseline.checkpoints.items()):
        row = scores.get(f"baseline_{step}")
        if row:
            share = t / baseline_s
            print(f"  baseline @ {step:5d} steps  {t:7.1f} s  {row['psnr']:6.2f} dB  ({share:.2f} of its time)")
    print(f"hybrid after SfM: mvs..background {upstream:.1f} s (the project's), appearance + merge per budget:")
    print(" budget  steps  appear s  merge s  hybrid s  share   PSNR   SSIM  LPIPS  masked  reaches baseline")
    rows = [(None, seconds.get("appearance", 0.0), seconds.get("merge", 0.0), scores.get("merged"), project)]
    for budget in args.budgets:
        copy = work / f"budget_{budget}"
        _rerun_with_budget(project, copy, budget)
        s = _stage_seconds(copy)
        rows.append((budget, s.get("appearance", 0.0), s.get("merge", 0.0), _image_scores(copy).get("merged"), copy))
    for budget, appear, merge, row, where in rows:
        appearance = stage_result(ProjectLayout(where), AppearanceStage)
        steps = appearance.iterations if appearance is not None and budget != 0 else 0
        total = upstream + appear + merge
        label = "default" if budget is None else str(budget)
        psnr = row["psnr"] if row else None
        reaches = "yes" if psnr is not None and psnr >= target else "no"
        print(f" {label:>7} {steps:6d} {appear:9.1f} {merge:8.1f} {total:9.1f} {total / baseline_s:6.2f} "
              f"{_fmt(psnr, 2):>6} {_fmt(row and row['ssim'], 3):>6} {_fmt(row and row['lpips'], 3):>6} "
              f"{_fmt(row and row['masked_psnr'], 2):>7}  {reaches}")  # fmt: skip


if __name__ == "__main__":
    main()
