"""Train the default classifier shipped as classify/models/default.skops, reproducibly.

Training data: procedural data_synth layouts (``random-object`` and ``random-aerial``, seeds 0–47:
``classify.training.DEFAULT_TRAINING_SCENES``), the even seeds at 24 views of 320×240, the odd ones at 16
requested views of 288×216 (two sampling densities), 2 held-out views each, reconstructed with ``hybridsplat sfm``
(the scene's known cameras) and ``hybridsplat mvs --threads 1`` (CPU MVS). Labels: the scenes' truth (τ = 3 GSD),
the ignore band (points within τ of both kinds of surface) kept in training. Features: geometric, radiometric and
multi-view. Forest: ``classify.training.DEFAULT_FOREST`` (32 trees, depth ≤ 14, leaves ≥ 5 points, unweighted
classes, seed 0, probabilities smoothed once over the finest neighbourhood); the needs-splats threshold is chosen
on leave-one-scene-out predictions (each scene predicted by a forest that never saw it, the scenes dealt to 6
folds; ``classify.training.train_on_scenes``). The recipe was chosen on these training scenes alone
(``bench/bench_classify.py --part choose``: each candidate's mean out-of-fold F1); scoring (``bench/bench_classify.py
--part score``) uses the hand-built layouts and procedural seeds 106–111, never a training layout.

    python scripts/train_default_classifier.py --data D        # reuses D/<preset>_s<seed>/{scene,proj}
    python scripts/train_default_classifier.py --data D --out classify/models/default.skops

Steps that exist are reused (scenes, reconstructions, cached features), so a rerun only retrains (minutes). Scenes
that are missing are generated and reconstructed (about a minute each on 2 cores; the script prints the time).
``--check-reproducible`` trains twice and fails unless the two forests have identical trees and thresholds.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

from classify.classes import load_classes
from classify.features import FeatureGroup, FeatureOptions
from classify.features.registry import feature_group
from classify.model import same_forest, save_model
from classify.synthetic import load_scene_data
from classify.training import DEFAULT_FOREST, DEFAULT_TRAINING_SCENES, SCENE_FOLDS, SynthTrainingScene, train_on_scenes
from data_synth.layout import SceneLayout
from hybridsplat.layout import ProjectLayout


def ensure_scene(data: Path, scene: SynthTrainingScene) -> tuple[Path, float]:
    """data/<preset>_s<seed>/{scene,proj}: generated and reconstructed when missing; the seconds spent doing so."""
    root = data / scene.name
    scene_dir, project = root / "scene", ProjectLayout(root / "proj")
    hs = [sys.executable, "-m", "hybridsplat"]
    t0 = time.perf_counter()
    if not SceneLayout(scene_dir).scene_json.is_file():
        synth = ["synth", "--preset", scene.preset, "--seed", str(scene.seed), *scene.synth_args]
        subprocess.run([*hs, *synth, "--out", str(scene_dir), "--overwrite"], check=True)
    if not project.fused_ply.is_file():
        subprocess.run([*hs, "sfm", str(scene_dir), "--out", str(project.root)], check=True)
        subprocess.run([*hs, "mvs", str(project.root), "--threads", "1"], check=True)
    return root, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=Path("/work/data_classify"))
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "classify/models/default.skops")
    ap.add_argument("--seed", type=int, default=0, help="forest seed")
    ap.add_argument("--groups", default=",".join(g.value for g in FeatureOptions().groups),
                    help="feature groups (comma-separated FeatureGroup values)")  # fmt: skip
    ap.add_argument("--ignore-band", action=argparse.BooleanOptionalAction, default=False,
                    help="leave the truth's ignore band out of training")  # fmt: skip
    ap.add_argument("--scene-folds", type=int, default=SCENE_FOLDS, help="folds the scenes are dealt to")
    ap.add_argument(
        "--check-reproducible", action="store_true", help="train twice; fail unless the trees are identical"
    )
    args = ap.parse_args()
    classes = load_classes()
    options = FeatureOptions(groups=tuple(feature_group(g) for g in args.groups.split(",")))
    cached = FeatureOptions(groups=tuple(FeatureGroup))  # every group cached once; the model selects its own
    datas, build_s = [], 0.0
    t0 = time.perf_counter()
    for scene in DEFAULT_TRAINING_SCENES:
        root, seconds = ensure_scene(args.data, scene)
        build_s += seconds
        dense = ProjectLayout(root / "proj").dense
        datas.append(load_scene_data(root / "scene", dense, classes, cached, cache=root / "features.npz"))
    features_s = time.perf_counter() - t0 - build_s
    info = {
        "trained_by": "scripts/train_default_classifier.py",
        "scenes": [scene.to_dict() for scene in DEFAULT_TRAINING_SCENES],
        "tau_gsd": 3.0,
        "ignore_band": bool(args.ignore_band),
        "scene_folds": args.scene_folds,
    }
    forest = replace(DEFAULT_FOREST, seed=args.seed)
    t1 = time.perf_counter()
    model, report = train_on_scenes(
        datas, classes, options, forest, info=info, ignore_ambiguous=args.ignore_band, scene_folds=args.scene_folds
    )
    fit_s = time.perf_counter() - t1
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_model(model, args.out)
    if args.check_reproducible:
        again, _ = train_on_scenes(
            datas, classes, options, forest, info=info, ignore_ambiguous=args.ignore_band, scene_folds=args.scene_folds
        )
        if not same_forest(model, again) or again.info["threshold"] != model.info["threshold"]:
            raise SystemExit("two trainings on the same data gave different trees or thresholds")
        print("reproducible: a second training gave identical trees and threshold")
    rep = report.to_dict()
    summary = {"leave_one_scene_out": rep["needs_splats"], "per_class": rep["per_class"]}
    summary |= {"threshold": model.info["threshold"], "smooth_passes": model.info["smooth_passes"]}
    summary |= {"build_s": round(build_s, 1), "features_s": round(features_s, 1), "fit_s": round(fit_s, 1)}
    print(json.dumps(summary, indent=1))
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
