"""The survey product at τ, product by product, and the collaborative-only scene's time budget (issue 54).

``python bench/bench_survey_products.py --data D [--layouts demo:0,textured:0,aerial:1,random-object:100]
[--out bench_out/survey_products]``

For each layout it makes the scene (``hybridsplat synth``; ``aerial`` and the procedural layouts at the demo's size,
24 + 4 views of 320×240, the demo and ``textured`` at their own) and runs the pipeline with every default and the
whole-scene baseline (``hybridsplat run SCENE --out D/<layout>/project --baseline --mesh 0``). From the eval stage
it tables, for MVS only, filtered MVS and merged, the precision / recall / F-score at τ (τ = the eval stage's, 3 GSD)
and the C2C mean against the LiDAR cloud, overall and per material.

For ``textured`` (every surface collaborative) it tables the decision-4 budget of issue 54: the seconds of the
stages after MVS (classify, masks, convert, train, clean, background, appearance, merge) against the baseline
stage's on the same scene, the merged product's held-out LPIPS against the baseline's, and the fill training's
(train stage) seconds against the demo's, with the share of training pixels the region masks cover. Times are wall
seconds of the stages in one sitting; the machine's load is printed before and after.

Writes ``OUT/bench_survey_products.json`` and ``OUT/bench_survey_products.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from hybridsplat.layout import ProjectLayout  # noqa: E402

DEFAULT_LAYOUTS = "demo:0,textured:0,aerial:1,random-object:100"
REDUCED_SIZE = ("--views", "24", "--test-views", "4", "--width", "320", "--height", "240")
"""``aerial`` and the procedural layouts at the demo's size (24 training + 4 held-out views of 320×240)."""
SURVEY_PRODUCTS = ("mvs", "mvs_filtered", "merged")
AFTER_MVS = ("classify", "masks", "convert", "train", "clean", "background", "appearance", "merge")
"""The stages after MVS whose seconds decision 4 bounds (sfm, mvs, baseline, eval, report and mesh excluded)."""


def load() -> str:
    return "load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def cli(*args: str, log: Path) -> None:
    """``hybridsplat ARGS`` in a subprocess, output appended to ``log``; raises on failure."""
    with open(log, "a") as f:
        f.write(f"$ hybridsplat {' '.join(args)}\n")
        f.flush()
        done = subprocess.run([sys.executable, "-m", "hybridsplat", *args], stdout=f, stderr=subprocess.STDOUT)
    if done.returncode != 0:
        raise RuntimeError(f"hybridsplat {' '.join(args)} failed ({done.returncode}); see {log}")


def make_project(root: Path, preset: str, seed: int) -> Path:
    """The layout's scene and its pipeline run with every default and the baseline (reused when complete)."""
    folder = root / f"{preset}_s{seed}"
    scene, project, log = folder / "scene", folder / "project", folder / "log.txt"
    if not (scene / "scene.json").is_file():
        if scene.exists():
            shutil.rmtree(scene)
        folder.mkdir(parents=True, exist_ok=True)
        size = REDUCED_SIZE if preset.startswith("random-") or preset == "aerial" else ()
        cli("synth", "--preset", preset, "--seed", str(seed), *size, "--out", str(scene), log=log)
    if not ProjectLayout(project).report_json.is_file():
        cli("run", str(scene), "--out", str(project), "--baseline", "--mesh", "0", "--quiet", log=log)
    return project


def survey_scores(project: Path) -> dict[str, Any]:
    """Per survey product: P / R / F at τ and the C2C mean (m), overall and per material; τ in metres."""
    layout = ProjectLayout(project)
    metrics = json.loads(layout.metrics_json.read_text())["products"]
    table = json.loads(layout.per_material_json.read_text())
    out: dict[str, Any] = {"tau_m": table["tau_m"], "products": {}}
    for product in SURVEY_PRODUCTS:
        c2c = metrics[product]["c2c"]
        materials = table["products"].get(product, {})
        out["products"][product] = {
            "precision": c2c["precision"], "recall": c2c["recall"], "fscore": c2c["fscore"], "c2c_mean_m": c2c["mean"],
            "points": c2c["count"],
            "per_material": {name: {k: m.get(k) for k in ("precision", "completeness", "fscore", "accuracy_points")}
                             for name, m in materials.items()},
        }  # fmt: skip
    return out


def stage_seconds(project: Path) -> dict[str, float]:
    stages = json.loads(ProjectLayout(project).manifest.read_text())["stages"]
    return {name: 0.0 if s["skipped"] else float(s["seconds"]) for name, s in stages.items()}


def image_scores(project: Path, product: str) -> dict[str, float]:
    full = json.loads(ProjectLayout(project).metrics_json.read_text())["products"][product]["images"]["full"]
    return {"psnr": full["psnr"], "lpips": full["lpips"]}


def mask_share(project: Path) -> float:
    """Share of the training photos' pixels the region masks mark as needing splats (the masks stage's record)."""
    record = json.loads(ProjectLayout(project).manifest.read_text())["stages"]["masks"]
    return float(record["counts"]["mean_coverage"])


def textured_budget(textured: Path, demo: Path | None) -> dict[str, Any]:
    seconds = stage_seconds(textured)
    after = sum(seconds.get(s, 0.0) for s in AFTER_MVS)
    out = {
        "after_mvs_s": after, "stages_s": {s: seconds.get(s, 0.0) for s in AFTER_MVS},
        "baseline_s": seconds["baseline"], "after_mvs_over_baseline": after / max(seconds["baseline"], 1e-9),
        "merged": image_scores(textured, "merged"), "baseline": image_scores(textured, "baseline"),
        "mask_coverage": mask_share(textured),
    }  # fmt: skip
    out["lpips_excess"] = out["merged"]["lpips"] - out["baseline"]["lpips"]
    if demo is not None:
        demo_train = stage_seconds(demo)["train"]
        out |= {"demo_train_s": demo_train, "demo_mask_coverage": mask_share(demo),
                "train_over_demo": seconds["train"] / max(demo_train, 1e-9)}  # fmt: skip
    return out


def _share(value: float | None) -> str:
    return "–" if value is None else f"{value:.3f}"


def to_markdown(out: dict[str, Any]) -> str:
    lines = [f"# Survey products at τ ({out['load_before']} before, {out['load_after']} after)", ""]
    for name, layout in out["layouts"].items():
        lines += [f"## {name} (τ = {layout['tau_m'] * 1000:.2f} mm)", "",
                  "| product | points | precision | recall | F | C2C mean (mm) |",
                  "|---|---:|---:|---:|---:|---:|"]  # fmt: skip
        for product, s in layout["products"].items():
            lines.append(f"| {product} | {s['points']} | {s['precision']:.4f} | {s['recall']:.4f} | {s['fscore']:.4f} "
                         f"| {s['c2c_mean_m'] * 1000:.2f} |")  # fmt: skip
        materials = sorted({m for s in layout["products"].values() for m in s["per_material"]})
        lines += ["", "| material | " + " | ".join(f"{p} P / R / F" for p in layout["products"]) + " |",
                  "|---|" + "---:|" * len(layout["products"])]  # fmt: skip
        for m in materials:
            cells = []
            for s in layout["products"].values():
                row = s["per_material"].get(m)
                shares = ("–",) if row is None else (_share(row[k]) for k in ("precision", "completeness", "fscore"))
                cells.append(" / ".join(shares))
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
        lines.append("")
    if (t := out.get("textured")) is not None:
        lines += ["## textured: the collaborative-only budget", "",
                  f"- stages after MVS {t['after_mvs_s']:.1f} s against the baseline's {t['baseline_s']:.1f} s: "
                  f"{t['after_mvs_over_baseline']:.3f} (bar ≤ 0.5)",
                  f"- LPIPS merged {t['merged']['lpips']:.4f}, baseline {t['baseline']['lpips']:.4f}: excess "
                  f"{t['lpips_excess']:+.4f} (bar ≤ +0.02); PSNR {t['merged']['psnr']:.2f} / "
                  f"{t['baseline']['psnr']:.2f} dB",
                  "- per stage: " + ", ".join(f"{k} {v:.1f} s" for k, v in t["stages_s"].items())]  # fmt: skip
        if "demo_train_s" in t:
            lines.append(f"- fill training {t['stages_s']['train']:.1f} s at mask coverage {t['mask_coverage']:.4f}, "
                         f"the demo's {t['demo_train_s']:.1f} s at {t['demo_mask_coverage']:.4f}: "
                         f"{t['train_over_demo']:.3f} (bar ≤ 0.10 when coverage ≤ 0.01)")  # fmt: skip
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="folder for the scenes and projects (reused)")
    parser.add_argument("--layouts", default=DEFAULT_LAYOUTS, help="preset:seed items, comma-separated")
    parser.add_argument("--out", type=Path, default=Path("bench_out/survey_products"))
    args = parser.parse_args()
    out: dict[str, Any] = {"load_before": load(), "layouts": {}}
    projects = {}
    for item in filter(None, (t.strip() for t in args.layouts.split(","))):
        preset, _, seed = item.partition(":")
        project = make_project(args.data, preset, int(seed or 0))
        projects[preset] = project
        out["layouts"][f"{preset}_s{seed}"] = survey_scores(project)
        print(f"{preset} seed {seed} done ({load()})", flush=True)
    if "textured" in projects:
        out["textured"] = textured_budget(projects["textured"], projects.get("demo"))
    out["load_after"] = load()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_survey_products.json").write_text(json.dumps(out, indent=2))
    text = to_markdown(out)
    (args.out / "bench_survey_products.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
