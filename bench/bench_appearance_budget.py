"""The appearance stage's step budget (issue 32): its held-back-pixel curve, where each early-stop rule ends it, and
a held-back *training view* scored at chosen budgets.

    python bench/bench_appearance_budget.py PROJECT --steps 2000
    python bench/bench_appearance_budget.py PROJECT --view 0005.jpg --budgets 0 1200 2000

PROJECT is a finished project (``hybridsplat run``: export/mvs_gaussians.ply, the classified points, the cleaned
splats and the background layer). Without ``--view``: :func:`fusion.appearance.refine_survey_appearance` runs
``--steps`` steps with its early stop off (the stage's other defaults), prints the trainer's PSNR on its held-back
pixels after each evaluation window with the seconds so far, then for each rule (patience × least gain in dB) the
step where :class:`fusion.train.early_stop.EarlyStop` would have ended the run, its PSNR against the last window's
and its share of the time. With ``--view``: that training photo is left out of the refinement (and only of it:
the fill and background layers and the MVS points of the project saw it), and survey + fill + background are
rendered at its camera and full dense size and scored (PSNR) for each budget in ``--budgets`` (0 = unrefined; each
budget run to its end, no early stop). Neither mode reads a held-out (scored) view. A figure taken while something
else runs on the machine is not a figure: note the load (uptime).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RULES = [(patience, gain) for patience in (1, 2, 3) for gain in (0.02, 0.05, 0.1)]


def _project_inputs(root: Path):
    """(training cameras, photos by name, survey Gaussians, context or None, seed), read as the appearance
    stage reads them (:func:`hybridsplat.stages.appearance.survey_layer_inputs`)."""
    from hybridsplat import project_io
    from hybridsplat.config import read_config
    from hybridsplat.layout import ProjectLayout
    from hybridsplat.source import resolve_source
    from hybridsplat.stages import stage_options_types
    from hybridsplat.stages.appearance import context_of, survey_layer_inputs

    layout = ProjectLayout(root)
    config = read_config(layout.config, stage_options_types())
    cameras, images = project_io.read_training_photos(layout, set(resolve_source(config.input).holdout_names))
    files = [p for p in (layout.cleaned_splats, layout.background_splats) if p.is_file()]
    mvs, needs, layers = survey_layer_inputs(layout, files)
    return cameras, images, mvs.subset(np.flatnonzero(~needs)), context_of(layers, cameras.origin), config.seed


def _refine(cameras, images, survey, context, steps: int, seed: int):
    """The stage's refinement for exactly ``steps`` steps (early stop off)."""
    from fusion.appearance import AppearanceOptions, refine_survey_appearance

    base = AppearanceOptions()
    options = replace(base, max_passes=0, training=replace(base.training, iterations=steps, patience=10**6))
    return refine_survey_appearance(cameras, images, survey, context, options, seed)


def curve(root: Path, steps: int) -> None:
    """Print the held-back-pixel curve and where each early-stop rule ends it."""
    from fusion.appearance import AppearanceOptions
    from fusion.train.early_stop import EarlyStop

    cameras, images, survey, context, seed = _project_inputs(root)
    history = _refine(cameras, images, survey, context, steps, seed).training.history
    print(f"{len(survey)} survey Gaussians, {len(images)} training photos, {steps} steps, early stop off")
    for c in history:
        print(f"  step {c.step:5d}  held-back PSNR {c.holdout_psnr:7.3f} dB  {c.seconds:7.1f} s")
    last = history[-1]
    min_steps = AppearanceOptions().training.min_iterations  # no stop before it
    print(f"rule (no stop before step {min_steps}) | stop step | PSNR - last window | share of the time")
    for patience, gain in RULES:
        stop = EarlyStop(gain, patience, min_steps, last.step)
        end = next((c for c in history if stop.update(c.holdout_psnr, c.step)), last)
        behind = end.holdout_psnr - last.holdout_psnr
        print(f"  patience {patience}, gain {gain:.2f} dB | {end.step:5d} | {behind:+.3f} dB | "
              f"{end.seconds / last.seconds:.2f}")  # fmt: skip


def held_back_view(root: Path, name: str, budgets: list[int]) -> None:
    """Score survey + fill + background at the training photo ``name`` refined without it, per budget (the fill
    and background as refined beside the survey layer with ``refine_context``, the default; else as trained)."""
    from core.cameras import Cameras
    from core.gaussians import GaussianSet
    from eval.image_metrics import psnr
    from fusion.render.scene import render_gaussian_set

    cameras, images, survey, context, seed = _project_inputs(root)
    target = next((v for v in cameras if v.name == name), None)
    if target is None:
        raise SystemExit(f"{name} is not a training photo of {root}")
    photo = images.pop(name)
    reference = photo.astype(np.float64) / (255.0 if photo.dtype == np.uint8 else 1.0)
    others = Cameras(cameras.cameras, {i: v for i, v in cameras.views.items() if v.name != name}, cameras.origin)
    camera = cameras.cameras[target.camera_id]
    for steps in budgets:
        t0 = time.perf_counter()
        result = _refine(others, images, survey, context, steps, seed) if steps else None
        seconds = time.perf_counter() - t0
        refined = result.gaussians if result is not None else survey
        beside = result.context if result is not None and result.context is not None else context  # refine_context
        layers = [refined.with_origin(cameras.origin)]
        layers += [beside.with_origin(cameras.origin)] if beside is not None else []
        degree = max(g.sh_degree for g in layers)
        scene = GaussianSet.concatenate([g.with_sh_degree(degree) for g in layers])
        colour = render_gaussian_set(scene, camera, target, cameras_origin=cameras.origin).colour.numpy()
        score = psnr(np.clip(colour, 0, 1), reference)
        print(f"{name} held back, {steps:5d} steps ({seconds:5.0f} s): PSNR {score:.3f} dB at {camera.width} x "
              f"{camera.height}")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("project", type=Path)
    parser.add_argument("--steps", type=int, default=2000, help="steps of the curve (early stop off)")
    parser.add_argument("--view", help="a training photo to hold back from the refinement and score")
    parser.add_argument("--budgets", type=int, nargs="+", default=[0, 1000, 2000], help="steps per --view run")
    args = parser.parse_args()
    if args.view:
        held_back_view(args.project, args.view, args.budgets)
    else:
        curve(args.project, args.steps)


if __name__ == "__main__":
    main()
