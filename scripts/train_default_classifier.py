"""Train the default classifier shipped as classify/models/default.skops, reproducibly.

Training data: data_synth scenes of both presets (``tabletop``, ``aerial``) and several seeds (TRAINING_SCENES),
each generated with its own size overrides (seed 7, and aerial seed 11: 24 views at 320×240; seeds 8–10: 16
requested views (the rigs make 18–20) at 288×216, so the model sees two sampling densities), 2 held-out views,
reconstructed with ``hybridsplat sfm`` (the scene's known cameras) and ``hybridsplat mvs --threads 1`` (CPU
MVS). Labels: the scenes' truth (τ = 3 GSD). Forest: 32 trees, depth ≤ 14, leaves ≥ 5 points, balanced
class weights, seed 0, probabilities smoothed once over the finest neighbourhood; the needs-splats threshold is
chosen on leave-one-scene-out predictions (each scene predicted by a forest that never saw it).
Scoring (``bench/bench_classify.py``) uses seed 1, never a training seed.

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
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from classify.classes import load_classes  # noqa: E402
from classify.features import FeatureOptions  # noqa: E402
from classify.model import ForestOptions, save_model, train  # noqa: E402
from classify.synthetic import load_scene_data, stack_scenes  # noqa: E402

FULL = ("--views", "24", "--test-views", "2", "--width", "320", "--height", "240")
SMALL = ("--views", "16", "--test-views", "2", "--width", "288", "--height", "216")
TRAINING_SCENES: tuple[tuple[str, int, tuple[str, ...]], ...] = (
    ("tabletop", 7, FULL),
    ("aerial", 7, FULL),
    ("tabletop", 8, SMALL),
    ("aerial", 8, SMALL),
    ("aerial", 9, SMALL),
    ("tabletop", 9, SMALL),
    ("aerial", 10, SMALL),
    ("aerial", 11, FULL),
)
"""(preset, seed, ``hybridsplat synth`` size arguments) of every training scene."""


def ensure_scene(data: Path, preset: str, seed: int, scene_args: tuple[str, ...]) -> Path:
    """data/<preset>_s<seed>/{scene,proj}: generated and reconstructed when missing."""
    root = data / f"{preset}_s{seed}"
    hs = [sys.executable, "-m", "hybridsplat"]
    if not (root / "scene" / "scene.json").is_file():
        cmd = [*hs, "synth", "--preset", preset, "--seed", str(seed), *scene_args, "--out", str(root / "scene")]
        subprocess.run([*cmd, "--overwrite"], check=True)
    if not (root / "proj" / "dense" / "fused.ply").is_file():
        subprocess.run([*hs, "sfm", str(root / "scene"), "--out", str(root / "proj")], check=True)
        subprocess.run([*hs, "mvs", str(root / "proj"), "--threads", "1"], check=True)
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
    for preset, seed, scene_args in TRAINING_SCENES:
        root = ensure_scene(args.data, preset, seed, scene_args)
        dense = root / "proj" / "dense"
        datas.append(load_scene_data(root / "scene", dense, classes, options, cache=root / "features.npz"))
    table, codes, scene_of_row = stack_scenes(datas, options.selected(), by_scene=True)
    info = {
        "trained_by": "scripts/train_default_classifier.py",
        "scenes": [{"preset": p, "seed": s, "synth_args": list(a)} for p, s, a in TRAINING_SCENES],
        "tau_gsd": 3.0,
    }
    forest = replace(ForestOptions(seed=args.seed), folds=len(datas))
    model, report = train(table, codes, classes, options, forest, info=info, groups=scene_of_row)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_model(model, args.out)
    rep = report.to_dict()
    summary = {"leave_one_scene_out": rep["needs_splats"], "per_class": rep["per_class"]}
    summary |= {"threshold": model.info["threshold"], "smooth_passes": model.info["smooth_passes"]}
    print(json.dumps(summary, indent=1))
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
