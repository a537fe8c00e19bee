"""The report's opening: the summary table (best value per column, run time per product, the findings), the panel
cut into its pictures, and a page that fits 1280 px with every product and material (headless chromium)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from report_helpers import metrics_file as _metrics
from report_helpers import write_project_report as _write

from core.pointcloud import PointCloud
from eval.accuracy import PointResidual, accuracy_statement
from eval.geometry import GeometryOptions, evaluate_geometry
from eval.metrics_io import ProductMetrics, write_metrics
from eval.per_material import as_table, geometry_per_material
from eval.render_eval import ImagePair, evaluate_pairs, side_by_side
from eval.report_summary import PRODUCT_STAGES, product_seconds, split_panel, summary_table
from hybridsplat.layout import ProjectLayout
from hybridsplat.viewer.browser import CHROMIUM, FLAGS, browser_missing


def _report(products: dict, stages: dict) -> dict:
    return {"products": products, "stages": stages}


def _product(fscore=None, mean=None, psnr=None, masked=None, lpips=None, tau=0.01) -> dict:
    return {"skipped": False, "c2c": {"fscore": fscore, "mean": mean, "tau": tau},
            "images": {"full": {"psnr": psnr, "lpips": lpips}, "masked": {"psnr": masked}}}  # fmt: skip


STAGE_NAMES = ("mvs", "convert", "classify", "masks", "train", "clean", "background", "appearance", "merge", "baseline")
STAGES = {name: {"seconds": float(i + 1), "skipped": False} for i, name in enumerate(STAGE_NAMES)}


def test_summary_marks_the_best_of_each_column_and_says_by_how_much() -> None:
    products = {
        "mvs": _product(0.80, 0.002, 11.5, 11.7, 0.52),
        "baseline": _product(0.50, 0.019, 23.8, 20.4, 0.35),
        "merged": _product(0.81, 0.0021, 26.4, 22.6, 0.15),
    }
    title, header, rows, findings = summary_table(_report(products, STAGES), lambda v: f"{v * 1000:.1f}", "mm")
    assert header[0] == "product" and header[-1] == "run time (s)" and "τ = 10.0 mm" in header[1]
    by = {r[0]: r for r in rows}
    assert by["hybrid (merged)"][1] == "**0.810**" and by["MVS only"][1] == "0.800"
    assert by["MVS only"][2] == "**2.0**" and by["hybrid (merged)"][2] == "2.1"  # the lower mean is better
    assert by["hybrid (merged)"][5] == "**0.150**"
    # run time: mvs + convert = 1 + 2; baseline = 10; merged = every stage but the baseline = 45
    assert by["MVS only"][6] == "**3**" and by["whole-scene 3DGS (baseline)"][6] == "10"
    assert by["hybrid (merged)"][6] == str(sum(range(1, 10)))
    assert findings[0] == "Best survey F-score at τ: hybrid (merged), 0.810 (+0.010 over MVS only)."
    assert findings[1].startswith("Best whole-image PSNR: hybrid (merged), 26.40 dB (+2.60 dB over whole-scene")


def test_summary_leaves_out_unmeasured_products_and_marks_nothing_alone() -> None:
    products = {"mvs": _product(0.8, 0.002, 11.0, 11.0, 0.5), "baseline": {"skipped": True, "c2c": None}}
    _, _, rows, findings = summary_table(_report(products, {}), str, "m")
    assert [r[0] for r in rows] == ["MVS only"] and not any("**" in c for c in rows[0]) and findings == []
    assert rows[0][-1] == "–"  # no stage times recorded


def test_product_seconds_skip_stages_the_scene_did_not_need() -> None:
    stages = {**STAGES, "train": {"seconds": None, "skipped": True}}
    assert product_seconds("merged", stages) == sum(range(1, 10)) - 5
    assert product_seconds("merged", {k: v for k, v in STAGES.items() if k != "train"}) is None  # not run at all
    assert set(PRODUCT_STAGES["merged"]) >= set(PRODUCT_STAGES["mvs"])


def test_split_panel_returns_the_pictures_side_by_side_joined() -> None:
    rng = np.random.default_rng(0)
    render, photo = rng.random((5, 7, 3)), rng.random((5, 7, 3))
    a, b, err = split_panel(side_by_side(render, photo))
    assert np.array_equal(a, np.round(render * 255).astype(np.uint8))
    assert np.array_equal(b, np.round(photo * 255).astype(np.uint8)) and err.shape == (5, 7, 3)
    with pytest.raises(ValueError, match="not a render"):
        split_panel(np.zeros((5, 21, 3), np.uint8))


MATERIALS = ("bricks", "text_label", "wood", "stone_noise", "textureless_paint", "polished_metal", "mirror",
             "glass", "wire", "cabinet_metal_sheet", "glass_roof_panels")  # fmt: skip
PRODUCTS = ("mvs", "baseline", "splats", "merged", "merged_no_background", "merged_unrefined", "mvs_filtered")


@pytest.fixture(scope="module")
def full_project(tmp_path_factory) -> Path:
    """A project with every product, eleven materials and render panels at 320 × 240 (the demo's size)."""
    root = tmp_path_factory.mktemp("full")
    rng = np.random.default_rng(1)
    ref = PointCloud(rng.uniform(0, 2, (2000, 3)) * [1, 1, 0.1], fields={"material": rng.integers(0, 11, 2000)})
    eval_dir = root / "eval"
    products, tables = {}, {}
    for k, name in enumerate(PRODUCTS):
        cmp = PointCloud(ref.positions[::2] + rng.normal(0, 0.002 * (k + 1), (1000, 3)))
        pairs = [ImagePair(f"test_{i:03d}.png", np.clip(p + rng.normal(0, 0.03 * (k + 1), p.shape), 0, 1), p)
                 for i, p in ((i, rng.random((240, 320, 3))) for i in range(4))]  # fmt: skip
        products[name] = ProductMetrics(c2c=evaluate_geometry(cmp, ref, eval_dir, name, GeometryOptions(tau=0.01)),
                                        images=evaluate_pairs(pairs, None, eval_dir, name))  # fmt: skip
        geometry = geometry_per_material(cmp.world_positions, ref.world_positions, ref.fields["material"], 0.01)
        tables[name] = as_table(geometry, {}, dict(enumerate(MATERIALS)))
    write_metrics(_metrics(root), products)
    kinds = {m: {"kind": "textured", "collaborative": i < 4} for i, m in enumerate(MATERIALS)}
    layout = ProjectLayout(root)
    layout.per_material_json.write_text(json.dumps({"tau_m": 0.01, "materials": kinds, "products": tables}))
    stages = {s: {"seconds": 12.3, "peak_mb": 900.0, "skipped": False, "reason": None} for s in STAGES}
    layout.manifest.write_text(json.dumps({"version": "0.3.1", "stages": stages}))
    residuals = [PointResidual(f"T{k:02d}", "control" if k < 6 else "check", (float(k * 9), float(k % 4 * 7), 0.05),
                               *rng.normal(0, 0.01, 3), marks=int(k + 3), reprojection_px=0.12, sigma_xy_m=0.005,
                               sigma_z_m=0.01) for k in range(12)]  # fmt: skip
    layout.accuracy_json.write_text(json.dumps(accuracy_statement(residuals).to_json()))
    return root


def test_the_summary_opens_the_report_with_a_picture_per_held_out_view(full_project: Path, tmp_path: Path) -> None:
    layout = ProjectLayout(full_project)
    paths = _write(
        full_project, tmp_path, per_material_file=layout.per_material_json, accuracy_file=layout.accuracy_json
    )
    md = paths.markdown.read_text()
    headings = [line for line in md.splitlines() if line.startswith("## ")]
    assert headings[0].startswith("## Summary") and headings[1].startswith("## Table 2")
    page = paths.html.read_text()
    assert page.index("Summary") < page.index("Held-out views: photo") < page.index("Table 2")
    section = page[page.index("Survey control: accuracy statement") :]
    assert "RMSE_3D" in section and "<svg" in section and section.count("<tr>") >= 9 + 1 + 12 + 1
    assert "informal" in section  # 6 check points < 30
    grid = page[page.index("<table class='grid'>") : page.index("</table>", page.index("<table class='grid'>"))]
    assert grid.count("<tr>") == 1 + 4 and grid.count("<img") == 4 * 5  # photo, three products, the error map


@pytest.mark.skipif(browser_missing() is not None, reason=str(browser_missing()))
def test_every_table_fits_a_1280_px_page(full_project: Path, tmp_path: Path) -> None:
    from playwright.sync_api import sync_playwright

    layout = ProjectLayout(full_project)
    paths = _write(
        full_project, tmp_path, per_material_file=layout.per_material_json, accuracy_file=layout.accuracy_json
    )
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=list(FLAGS), timeout=60_000)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto(paths.html.as_uri())
            right = page.evaluate("Math.max(...Array.from(document.querySelectorAll('table, pre, figure, img'))"
                                  ".map(e => e.getBoundingClientRect().right))")  # fmt: skip
            scroll = page.evaluate("document.documentElement.scrollWidth")
        finally:
            browser.close()
    assert scroll <= 1280 and right <= 1280, (scroll, right)
