"""Train the default classifier shipped as classify/models/default.skops, reproducibly.

Training data: the data_synth presets ``tabletop`` and ``aerial`` with seed 7 (TRAINING_SEEDS), reduced to 24
views at 320×240 with 2 held-out views, reconstructed with ``hybridsplat sfm`` (the scene's known cameras) and
``hybridsplat mvs`` (CPU MVS). Labels: the scenes' truth (τ = 3 GSD). Forest: 32 trees, depth ≤ 14, leaves ≥ 10
points, balanced class weights, seed 0. Scoring (``bench/bench_classify.py``) uses seed 1, never a training seed.

    python scripts/train_default_classifier.py --data D        # reuses D/<preset>_s7/{scene,proj}, builds missing
    python scripts/train_default_classifier.py --data D --out classify/models/default.skops

Steps that exist are reused (scenes, reconstructions, cached features), so a rerun only retrains.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from classify.classes import load_classes  # noqa: E402
from classify.features import FeatureOptions, FeatureTable  # noqa: E402
from classify.model import ForestOptions, save_model, train  # noqa: E402
from classify.synthetic import load_scene_data  # noqa: E402

TRAINING_SEEDS = (7,)
PRESETS = ("tabletop", "aerial")
SCENE_ARGS = ["--views", "24", "--test-views", "2", "--width", "320", "--height", "240"]


def ensure_scene(data: Path, preset: str, seed: int) -> Path:
    """data/<preset>_s<seed>/{scene,proj}: generated and reconstructed when missing."""
    root = data / f"{preset}_s{seed}"
    hs = [sys.executable, "-m", "hybridsplat"]
    if not (root / "scene" / "scene.json").is_file():
        cmd = [*hs, "synth", "--preset", preset, "--seed", str(seed), *SCENE_ARGS, "--out", str(root / "scene")]
        subprocess.run([*cmd, "--overwrite"], check=True)
    if not (root / "proj" / "dense" / "fused.ply").is_file():
        subprocess.run([*hs, "sfm", str(root / "scene"), "--out", str(root / "proj")], check=True)
        subprocess.run([*hs, "mvs", str(root / "proj")], check=True)
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
    for preset in PRESETS:
        for seed in TRAINING_SEEDS:
            root = ensure_scene(args.data, preset, seed)
            datas.append(
                load_scene_data(root / "scene", root / "proj" / "dense", classes, options, cache=root / "features.npz")
            )
    names = options.selected()
    import numpy as np

    table = FeatureTable(names, np.concatenate([d.table.values for d in datas]), 0.0)
    codes = np.concatenate([d.truth.codes for d in datas])
    info = {
        "trained_by": "scripts/train_default_classifier.py",
        "presets": list(PRESETS),
        "scene_seeds": list(TRAINING_SEEDS),
        "scene_args": SCENE_ARGS,
        "tau_gsd": 3.0,
    }
    model, report = train(table, codes, classes, options, ForestOptions(seed=args.seed), info=info)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_model(model, args.out)
    rep = report.to_dict()
    print(json.dumps({"needs_splats": rep["needs_splats"], "per_class": rep["per_class"],
                      "threshold": model.info["threshold"]}, indent=1))  # fmt: skip
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
