"""What the classifier's mistakes cost the product: the shipped project against its oracle variant.

``python bench/bench_regret.py --data D [--layouts random-object:120-125,random-aerial:120-125,demo:0]
[--variants oracle] [--out bench_out/regret]``

For each layout it makes the scene (``hybridsplat synth``; procedural layouts at 24 + 4 views of 320×240, the demo
at its own size) and runs the pipeline with every default (``hybridsplat run SCENE --out D/<layout>/shipped
--mesh 0``): the *shipped* project. Each variant is a copy of that project with one thing changed, every stage
upstream of the change reused from the copy (the runner finds it current) and every stage downstream rerun. The one
variant (:data:`VARIANTS`):

- ``oracle``: the classify stage writes the scene's true classes instead of the shipped model's (the truth of
  :func:`classify.labels.scene_point_truth`: the class of the nearest true surface's material within τ = 3 GSD,
  needs-splats farther than τ), everything else identical. This path exists only here: no user option gives it.
  *Product regret* = oracle − shipped.

Per layout and variant: merged held-out PSNR (whole image and inside the true non-collaborative masks), LPIPS, and
the survey product's precision / recall / F-score at τ and C2C mean against the LiDAR (the eval stage's figures);
for the shipped project also the classifier's needs-splats F1 with the truth's ambiguity band left out, its
confusion counts (pooled over the layouts: the micro-averaged F1) and where its mistakes lie (truth class,
material, distance to the true surface). Writes ``OUT/bench_regret.json`` and ``OUT/bench_regret.md``.

Choose on tuning layouts (procedural seeds 0-99), score once on 100-199: the defaults are seeds 120-125, which no
default and no earlier log used.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402

from hybridsplat.layout import ProjectLayout  # noqa: E402

PROCEDURAL_SIZE = ("--views", "24", "--test-views", "4", "--width", "320", "--height", "240")
"""The procedural layouts at the demo's size (24 training + 4 held-out views of 320×240)."""

DEFAULT_LAYOUTS = "random-object:120-125,random-aerial:120-125,demo:0"
VARIANTS = ("oracle",)
DISTANCE_BINS_TAU = (0.0, 1.0, 2.0, 4.0, np.inf)
"""Bins of a misclassified point's distance to the nearest true surface, in τ (the truth's threshold)."""


def load() -> str:
    return "load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def parse_layouts(text: str) -> list[tuple[str, int]]:
    """``preset:seeds`` items separated by commas, seeds as ``a-b`` (inclusive) or ``a+b+c``."""
    out = []
    for item in filter(None, (t.strip() for t in text.split(","))):
        preset, _, seeds = item.partition(":")
        if "-" in seeds:
            lo, hi = (int(s) for s in seeds.split("-"))
            out += [(preset, s) for s in range(lo, hi + 1)]
        else:
            out += [(preset, int(s)) for s in seeds.split("+")]
    return out


def layout_name(preset: str, seed: int) -> str:
    return f"{preset}_s{seed}"


def python() -> list[str]:
    return [sys.executable]


def cli(*args: str, log: Path) -> None:
    """``hybridsplat ARGS`` in a subprocess (its own peak memory), output to ``log``; raises on failure."""
    with open(log, "a") as f:
        f.write(f"$ hybridsplat {' '.join(args)}\n")
        f.flush()
        done = subprocess.run([*python(), "-m", "hybridsplat", *args], stdout=f, stderr=subprocess.STDOUT)
    if done.returncode != 0:
        raise RuntimeError(f"hybridsplat {' '.join(args)} failed ({done.returncode}); see {log}")


def make_scene(root: Path, preset: str, seed: int) -> Path:
    scene = root / layout_name(preset, seed) / "scene"
    if not (scene / "scene.json").is_file():
        if scene.exists():
            shutil.rmtree(scene)
        size = PROCEDURAL_SIZE if preset.startswith("random-") else ()
        scene.parent.mkdir(parents=True, exist_ok=True)
        cli("synth", "--preset", preset, "--seed", str(seed), *size, "--out", str(scene), log=scene.parent / "log.txt")
    return scene


def make_shipped(root: Path, preset: str, seed: int) -> Path:
    scene = make_scene(root, preset, seed)
    project = scene.parent / "shipped"
    if not ProjectLayout(project).report_json.is_file():
        cli("run", str(scene), "--out", str(project), "--mesh", "0", "--quiet", log=scene.parent / "log.txt")
    return project


# -- variants ----------------------------------------------------------------------------------------------------
def oracle_classify_stage():
    """The classify stage with the scene's true classes in place of the model's prediction (benchmark only).

    The features and the model run as in the pipeline (the report's spacing, the figures and the record are the
    stage's own); only the prediction written to classify/points.ply is replaced: classification = the truth's
    class, needs_splats = the truth's, probability 1.
    """
    from hybridsplat.stages.classify import ClassifyResult, ClassifyStage

    class OracleClassifyStage(ClassifyStage):
        def inputs(self, ctx):
            return [*super().inputs(ctx), Path(ctx.config.input.path) / "scene.json"]

        def fingerprint(self, ctx):
            return {**super().fingerprint(ctx), "classes": "scene truth (bench_regret oracle)"}

        def run(self, ctx):
            from classify.model import Prediction
            from classify.run import classify_dense, write_classified, write_classify_figures
            from core.io.json_io import write_json_atomic
            from data_synth import load_scene

            opts = ctx.options(self)
            result = classify_dense(ctx.layout.dense, opts.model, opts.threshold)
            truth = point_truth(result.cloud, load_scene(ctx.config.input.path), result.classes)
            needs = truth.needs_splats.astype(bool)
            result.prediction = Prediction(
                classification=truth.codes.astype(np.uint8),
                probability=np.ones(len(needs), np.float32),
                needs_splats=needs,
                p_needs_splats=needs.astype(np.float32),
            )
            result.model = "scene truth (oracle)"
            write_classified(ctx.layout.classified_points, result)
            report = result.report()
            write_json_atomic(ctx.layout.classify_report, report)
            figures = write_classify_figures(result, ctx.layout.classes_figure, None)
            return ClassifyResult(points=report["points"], needs_splats=report["needs_splats"], model=report["model"],
                                  per_class=report["per_class"], spacing_m=report["spacing_m"],
                                  seconds=report["seconds"],
                                  figures=tuple(str(f.relative_to(ctx.layout.root)) for f in figures))  # fmt: skip

        def outputs(self, ctx):
            return [ctx.layout.classified_points, ctx.layout.classify_report, ctx.layout.classes_figure]

    return OracleClassifyStage()


def point_truth(cloud, scene, classes):
    from classify.labels import scene_point_truth

    return scene_point_truth(cloud, scene, classes)


def rerun_variant(project: Path, variant: str) -> None:
    """In this process: the copy ``project`` rerun with ``variant`` (upstream stages stay current)."""
    from hybridsplat.pipeline import load_config, run_pipeline
    from hybridsplat.stages import registered_stages
    from hybridsplat.terminal import Terminal

    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; choose from {', '.join(VARIANTS)}")
    stages = [oracle_classify_stage() if s.name == "classify" else s for s in registered_stages()]
    run_pipeline(project, load_config(project), stages=stages, terminal=Terminal(quiet=False))


def make_variant(shipped: Path, variant: str) -> Path:
    project = shipped.parent / variant
    if ProjectLayout(project).report_json.is_file():
        return project
    if project.exists():
        shutil.rmtree(project)
    shutil.copytree(shipped, project, ignore=shutil.ignore_patterns("report", ".hybridsplat.lock*"), symlinks=True)
    log = shipped.parent / "log.txt"
    with open(log, "a") as f:
        f.write(f"$ bench_regret rerun {project} --variant {variant}\n")
        f.flush()
        done = subprocess.run([*python(), __file__, "rerun", str(project), "--variant", variant], stdout=f,
                              stderr=subprocess.STDOUT)  # fmt: skip
    if done.returncode != 0:
        raise RuntimeError(f"variant {variant} of {shipped} failed; see {log}")
    return project


# -- scores ------------------------------------------------------------------------------------------------------
def product_scores(project: Path) -> dict[str, Any]:
    """The merged product's figures from the eval stage: held-out PSNR / LPIPS (whole, masked) and the survey
    product's P / R / F at τ and C2C mean; the stages' seconds after MVS."""
    layout = ProjectLayout(project)
    metrics = json.loads(layout.metrics_json.read_text())["products"]
    merged = metrics["merged"]
    c2c = merged.get("c2c") or {}
    full = (merged.get("images") or {}).get("full") or {}
    masked = (merged.get("images") or {}).get("masked") or {}
    manifest = json.loads(layout.manifest.read_text())["stages"]
    after_mvs = ("classify", "masks", "convert", "train", "clean", "background", "appearance", "merge")
    seconds = sum(float((manifest.get(s) or {}).get("seconds") or 0.0) for s in after_mvs)
    out = {
        "psnr": full.get("psnr"),
        "masked_psnr": masked.get("psnr"),
        "lpips": full.get("lpips"),
        "masked_lpips": masked.get("lpips"),
        "precision": c2c.get("precision"),
        "recall": c2c.get("recall"),
        "fscore": c2c.get("fscore"),
        "c2c_mean_m": c2c.get("mean"),
        "tau_m": c2c.get("tau"),
        "survey_points": c2c.get("count"),
        "seconds_after_mvs": seconds,
    }
    per_material = layout.per_material_json
    if per_material.is_file():
        table = json.loads(per_material.read_text())
        out["per_material"] = {
            m: {k: r.get(k) for k in ("precision", "completeness", "fscore", "accuracy_mean_m", "psnr")}
            for m, r in (table.get("products", {}).get("merged") or {}).items()
        }
    return out


def classifier_scores(shipped: Path) -> dict[str, Any]:
    """The shipped model's needs-splats decisions on the fused cloud against the scene's truth (band left out):
    F1, confusion counts and the misclassified points by truth class, material and distance to the truth."""
    from classify.classes import load_classes
    from core.io import read_point_cloud
    from data_synth import load_scene
    from hybridsplat.pipeline import load_config
    from recon.workspace import read_fused

    layout = ProjectLayout(shipped)
    scene = load_scene(load_config(shipped).input.path)
    classes = load_classes()
    cloud = read_fused(layout.dense)
    classified = read_point_cloud(layout.classified_points)
    if len(classified) != len(cloud):
        raise RuntimeError(f"{layout.classified_points}: {len(classified)} points, the fused cloud {len(cloud)}")
    pred = np.asarray(classified.fields["needs_splats"]).astype(bool)
    truth = point_truth(cloud, scene, classes)
    scored = truth.scored
    t, p = truth.needs_splats[scored].astype(bool), pred[scored]
    tp, fp, fn = int((t & p).sum()), int((~t & p).sum()), int((t & ~p).sum())
    f1 = 2 * tp / max(2 * tp + fp + fn, 1)
    names = {m.id: m.name for m in scene.materials}
    errors: dict[str, dict[str, int]] = {}
    wrong = scored & (truth.needs_splats.astype(bool) != pred)
    bins = np.digitize(truth.distance / truth.tau, DISTANCE_BINS_TAU[1:-1])
    labels = ["<1τ", "1-2τ", "2-4τ", ">4τ"]
    for i in np.flatnonzero(wrong):
        kind = "missed" if truth.needs_splats[i] else "false alarm"
        key = f"{kind}: {names.get(int(truth.material[i]), '?')}, {labels[bins[i]]}"
        errors.setdefault(key, {"points": 0})["points"] += 1
    return {
        "points": int(len(pred)),
        "scored": int(scored.sum()),
        "band": int((~scored).sum()),
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "f1": f1,
        "truth_needs": int(truth.needs_splats.sum()),
        "errors": dict(sorted(errors.items(), key=lambda kv: -kv[1]["points"])),
    }


# -- tables ------------------------------------------------------------------------------------------------------
def _f(v: Any, digits: int) -> str:
    return "–" if v is None else f"{v:+.{digits}f}" if digits < 0 else f"{v:.{digits}f}"


def regret_rows(results: dict[str, Any], variant: str) -> tuple[list[list[str]], dict[str, float]]:
    """One row per layout: shipped → variant (merged PSNR whole / masked, LPIPS, survey F at τ) and the difference
    (variant − shipped), and the means of the differences."""
    keys = (("psnr", 2), ("masked_psnr", 2), ("lpips", 3), ("fscore", 4), ("precision", 4), ("recall", 4))
    rows, diffs = [], {k: [] for k, _ in keys}
    for name, r in results.items():
        a, b = r["shipped"], r.get(variant)
        if b is None:
            continue
        row = [name]
        for k, d in keys:
            delta = None if a.get(k) is None or b.get(k) is None else b[k] - a[k]
            if delta is not None:
                diffs[k].append(delta)
            row.append(f"{_f(a.get(k), d)} → {_f(b.get(k), d)} ({'–' if delta is None else f'{delta:+.{d}f}'})")
        rows.append(row)
    means = {k: float(np.mean(v)) for k, v in diffs.items() if v}
    return rows, means


def to_markdown(out: dict[str, Any]) -> str:
    results = out["layouts"]
    lines = [f"# bench_regret ({out['date']}, {out['load_before']} → {out['load_after']})", ""]
    header = ["layout", "PSNR whole (dB)", "PSNR masked (dB)", "LPIPS", "survey F at τ", "precision", "recall"]
    for variant in out["variants"]:
        rows, means = regret_rows(results, variant)
        if not rows:
            continue
        lines += [f"## shipped → {variant} (product regret: {variant} − shipped)", ""]
        lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        lines += ["", "mean difference: " + ", ".join(f"{k} {v:+.4f}" for k, v in means.items()), ""]
    pooled = out.get("pooled_classifier")
    if pooled:
        lines += ["## The shipped classifier (needs splats, ambiguity band left out)", ""]
        lines += ["| layout | points | band | F1 | tp | fp | fn | largest errors |", "|---" * 8 + "|"]
        for name, r in results.items():
            c = r.get("classifier")
            if c:
                top = "; ".join(f"{k} {v['points']}" for k, v in list(c["errors"].items())[:3])
                lines.append(f"| {name} | {c['points']} | {c['band']} | {c['f1']:.3f} | {c['tp']} | {c['fp']} | "
                             f"{c['fn']} | {top} |")  # fmt: skip
        lines += ["", f"pooled (micro-averaged) F1 {pooled['f1']:.3f} (tp {pooled['tp']}, fp {pooled['fp']}, "
                  f"fn {pooled['fn']}); mean per-layout F1 {pooled['mean_f1']:.3f}", ""]  # fmt: skip
    return "\n".join(lines) + "\n"


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "rerun":
        ap = argparse.ArgumentParser(prog="bench_regret.py rerun")
        ap.add_argument("rerun")
        ap.add_argument("project", type=Path)
        ap.add_argument("--variant", required=True)
        a = ap.parse_args()
        rerun_variant(a.project, a.variant)
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True, help="Folder of the scenes and projects (reused).")
    ap.add_argument("--layouts", default=DEFAULT_LAYOUTS, help=f"preset:seeds,... (default {DEFAULT_LAYOUTS}).")
    ap.add_argument("--variants", default="oracle", help=f"Comma-separated, of: {', '.join(VARIANTS)}.")
    ap.add_argument("--out", type=Path, default=Path("bench_out/regret"))
    a = ap.parse_args()
    variants = [v for v in a.variants.split(",") if v]
    for v in variants:
        if v not in VARIANTS:
            ap.error(f"unknown variant {v!r}; choose from {', '.join(VARIANTS)}")
    out: dict[str, Any] = {"date": time.strftime("%Y-%m-%d %H:%M"), "load_before": load(), "variants": variants,
                           "layouts": {}}  # fmt: skip
    tp = fp = fn = 0
    f1s = []
    for preset, seed in parse_layouts(a.layouts):
        name = layout_name(preset, seed)
        print(f"{name}: shipped ({load()})", flush=True)
        shipped = make_shipped(a.data, preset, seed)
        entry: dict[str, Any] = {"shipped": product_scores(shipped), "classifier": classifier_scores(shipped)}
        c = entry["classifier"]
        tp, fp, fn = tp + c["tp"], fp + c["fp"], fn + c["fn"]
        f1s.append(c["f1"])
        for v in variants:
            print(f"{name}: {v} ({load()})", flush=True)
            entry[v] = product_scores(make_variant(shipped, v))
        out["layouts"][name] = entry
        out["pooled_classifier"] = {"tp": tp, "fp": fp, "fn": fn, "f1": 2 * tp / max(2 * tp + fp + fn, 1),
                                    "mean_f1": float(np.mean(f1s))}  # fmt: skip
        out["load_after"] = load()
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "bench_regret.json").write_text(json.dumps(out, indent=1))
        (a.out / "bench_regret.md").write_text(to_markdown(out))
    print(to_markdown(out))


if __name__ == "__main__":
    main()
