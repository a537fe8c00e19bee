"""Where MVS holes are looked for: the masks' ``hole_area`` rules side by side on the classifier's scoring scenes.

For each scene (``D/<name>/scene`` + ``D/<name>/proj``, made as ``bench/bench_classify.py`` says) the shipped
default classifier (or ``--model``) predicts the needs-splats points once; the region masks are then drawn under
each rule (default: ``hull_below``, the 2D rule shipped until now, and ``region``, the 3D survey region of
:mod:`classify.survey_region`) and scored against the scene's exact truth (:func:`bench_classify.mask_scores`):

- coverage of the pixels that truly need splats, split by where their true surface lies: inside the survey box
  (the fused cloud's 1st-99th percentile box grown by τ, the region the fill serves) or outside it (the floor beyond
  the table, the backdrop: the background layer's pixels under the issue's rule);
- coverage of the rest of the scene (pixels that need no splats) and of the background (no true surface);
- mean mask coverage, empty masks, whether training is needed, seconds a view.

Run (2 cores, nothing else running, for the seconds)::

    python bench/bench_hole_area.py --data /work/data30 --scenes demo_s0 tabletop_s1 textured_s1 --json out.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
from pathlib import Path

from bench_classify import SCORING_SCENES, load, mask_scores

from classify.classes import load_classes
from classify.features import FeatureGroup, FeatureOptions
from classify.masks import HOLE_AREAS, MaskOptions
from classify.model import load_model, predict

KEYS = (
    "coverage_of_needs_in_box",
    "coverage_of_needs_outside_box",
    "needs_outside_box_share",
    "coverage_of_rest_scene",
    "coverage_of_background",
    "mean_mask_coverage",
    "empty_masks",
    "views",
    "training_needed",
    "seconds_per_view",
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="folder of <scene>/scene + <scene>/proj")
    ap.add_argument("--scenes", nargs="+", default=list(SCORING_SCENES))
    ap.add_argument("--rules", nargs="+", default=["hull_below", "region"], choices=HOLE_AREAS)
    ap.add_argument("--model", default=None, help="classifier (default: the shipped default model)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    from classify.run import DEFAULT_MODEL

    model = load_model(Path(args.model) if args.model else DEFAULT_MODEL)
    classes = load_classes()
    groups = FeatureOptions(groups=tuple(FeatureGroup))
    out: dict = {"uptime_before": subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()}
    print(f"{'scene':22s} {'rule':11s} " + " ".join(f"{k[:14]:>14s}" for k in KEYS))
    for name in args.scenes:
        data = load(Path(args.data), name, classes, groups)
        pred = predict(model, data.table.select(model.feature_names), threshold=float(model.info["threshold"]))
        out[name] = {"points_flagged": int(pred.needs_splats.sum()), "points": len(pred.needs_splats)}
        for rule in args.rules:
            m = mask_scores(data, pred.needs_splats, classes, MaskOptions(hole_area=rule))
            out[name][rule] = {k: m[k] for k in KEYS}
            print(f"{name:22s} {rule:11s} " + " ".join(_fmt(m[k]) for k in KEYS), flush=True)
    out["uptime_after"] = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1), encoding="utf-8")


def _fmt(v) -> str:
    if isinstance(v, bool):
        return f"{str(v):>14s}"
    if isinstance(v, int):
        return f"{v:14d}"
    return f"{v:14.3f}"


if __name__ == "__main__":
    main()
