"""Train the default classifier shipped as classify/models/default.skops, reproducibly.

Training data: data_synth scenes of both presets (``tabletop``, ``aerial``) and several seeds
(``classify.training.DEFAULT_TRAINING_SCENES``), each generated with its own size overrides (seed 7, and aerial
seed 11: 24 views at 320×240; seeds 8–10: 16 requested views (the rigs make 18–20) at 288×216, so the model sees
two sampling densities), 2 held-out views, reconstructed with ``hybridsplat sfm`` (the scene's known cameras) and
``hybridsplat mvs --threads 1`` (CPU MVS). Labels: the scenes' truth (τ = 3 GSD). Forest: 32 trees, depth ≤ 14,
leaves ≥ 5 points, balanced class weights, seed 0, probabilities smoothed once over the finest neighbourhood; the
needs-splats threshold is chosen on leave-one-scene-out predictions (each scene predicted by a forest that never
saw it; ``classify.training.train_on_scenes``). Scoring (``bench/bench_classify.py``) uses seed 1, never a
training seed.

    python scripts/train_default_classifier.py --data D        # reuses D/<preset>_s<seed>/{scene,proj}
    python scripts/train_default_classifier.py --data D --out classify/models/default.skops

Steps that exist are reused (scenes, reconstructions, cached features), so a rerun only retrains. Scenes that
are missing are generated and reconstructed (tens of minutes each on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from classify.classes import load_classes
from classify.features import FeatureOptions
from classify.model import ForestOptions, save_model
from classify.synthetic import load_scene_data
from classify.training import DEFAULT_TRAINING_SCENES, SynthTrainingScene, train_on_scenes
from data_synth.layout import SceneLayout
from hybridsplat.layout import ProjectLayout


def ensure_scene(data: Path, scene: SynthTrainingScene) -> Path:
    """data/<preset>_s<seed>/{scene,proj}: generated and reconstructed when missing."""
    root = data / scene.name
    scene_dir, project = root / "scene", ProjectLayout(root / "proj")
    hs = [sys.executable, "-m", "hybridsplat"]
    if not SceneLayout(scene_dir).scene_json.is_file():
        synth = ["synth", "--preset", scene.preset, "--seed", str(scene.seed), *scene.synth_args]
        subprocess.run([*hs, *synth, "--out", str(scene_dir), "--overwrite"], check=True)
    if not project.fused_ply.is_file():
        subprocess.run([*hs, "sfm", str(scene_dir), "--out", str(project.root)], check=True)
        subprocess.run([*hs, "mvs", str(project.root), "--threads", "1"], check=True)
    return root


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=Path("/work/data_classify"))
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "classify/models/default.skops")
    ap.add_argument("--seed", type=int, default=0, help="forest seed")
    args = ap.parse_args()
    classes = load_classes()
    options = FeatureOptions()
    datas = []
    for scene in DEFAULT_TRAINING_SCENES:
        root = ensure_scene(args.data, scene)
        dense = ProjectLayout(root / "proj").dense
        datas.append(load_scene_data(root / "scene", dense, classes, options, cache=root / "features.npz"))
    info = {
        "trained_by": "scripts/train_default_classifier.py",
        "scenes": [scene.to_dict() for scene in DEFAULT_TRAINING_SCENES],
        "tau_gsd": 3.0,
    }
    model, report = train_on_scenes(datas, classes, options, ForestOptions(seed=args.seed), info=info)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_model(model, args.out)
    rep = report.to_dict()
    summary = {"leave_one_scene_out": rep["needs_splats"], "per_class": rep["per_class"]}
    summary |= {"threshold": model.info["threshold"], "smooth_passes": model.info["smooth_passes"]}
    print(json.dumps(summary, indent=1))
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
