"""The HTML report of a 50-photo project: size budget, max_panels, lengths in the user's unit, matplotlib plots."""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from report_helpers import build_project_report as _build
from report_helpers import metrics_file as _metrics
from report_helpers import write_project_report as _write

from core.io.images import write_image
from core.pointcloud import PointCloud
from eval.geometry import GeometryOptions, evaluate_geometry
from eval.metrics_io import ProductMetrics, write_metrics
from eval.render_eval import ImagePair, evaluate_pairs, side_by_side

NUM_VIEWS = 50
PANEL_VIEWS = 5  # views per product that get a full-size panel file (the eval stage's own max_panels)


def _photo(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A photo-like float image: smooth structure plus sensor noise (compresses like a real photo, not like noise)."""
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    base = np.stack([np.sin(8 * x + 3 * c) * np.cos(5 * y - c) for c in range(3)], axis=-1) * 0.3 + 0.5
    return np.clip(base + rng.normal(0, 0.012, (h, w, 3)), 0, 1)


@pytest.fixture(scope="module")
def big_project(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("project50")
    rng = np.random.default_rng(0)
    eval_dir = root / "eval"
    ref = PointCloud(rng.uniform(0, 4, (3000, 3)) * [1, 1, 0.2])
    # full-size panels as the default dense resolution gives them (1000 px longer side): render | photo | error
    photo = _photo(rng, 667, 1000)
    panel = side_by_side(np.clip(photo + rng.normal(0, 0.02, photo.shape), 0, 1), photo)
    products = {}
    for k, name in enumerate(("mvs", "splats", "merged")):
        small = [
            ImagePair(f"{i:04d}.jpg", np.clip(p + rng.normal(0, 0.01 * (k + 1 + i % 5), p.shape), 0, 1), p)
            for i, p in ((i, _photo(rng, 24, 32)) for i in range(NUM_VIEWS))
        ]
        images = evaluate_pairs(small, None, eval_dir, name, max_panels=PANEL_VIEWS)
        for v in images.per_view[:PANEL_VIEWS]:
            write_image(eval_dir / v.files["panel"], panel)
        cmp = PointCloud(ref.positions[::2] + rng.normal(0, 0.002 * (k + 1), (1500, 3)))
        c2c = evaluate_geometry(cmp, ref, eval_dir, name, GeometryOptions(tau=0.01))
        products[name] = ProductMetrics(c2c=c2c, images=images)
    write_metrics(_metrics(root), products)
    return root


def _jpegs(page: str) -> list[np.ndarray]:
    out = []
    for b64 in re.findall(r"data:image/jpeg;base64,([A-Za-z0-9+/=]+)", page):
        img = cv2.imdecode(np.frombuffer(base64.b64decode(b64), np.uint8), cv2.IMREAD_COLOR)
        assert img is not None
        out.append(img)
    return out


def test_html_of_a_50_view_project_stays_small(big_project: Path, tmp_path: Path):
    from eval.report import THUMBNAIL_MAX_SIDE

    panel_bytes = sum(p.stat().st_size for p in (big_project / "eval" / "plots").glob("render_*.png"))
    paths = _write(big_project, tmp_path / "r4")
    page = paths.html.read_text()
    size = paths.html.stat().st_size
    assert size <= 5 * 2**20, f"report.html is {size / 2**20:.1f} MB"
    assert "data:image/png" not in page and not re.search(r"""(src|href)=["'](?!data:|#)""", page)
    images = _jpegs(page)
    panels = [im for im in images if im.shape[1] > 3 * im.shape[0]]  # render | photo | error: 4.5:1
    assert len(panels) == 3 * 4  # default max_panels = 4 views, for each of the 3 products
    assert max(max(im.shape[:2]) for im in panels) <= THUMBNAIL_MAX_SIDE
    # 12 of these panels embedded as before (full-size PNG, base64) would weigh more than the whole page now
    before = panel_bytes / (3 * PANEL_VIEWS) * 12 * 4 / 3
    assert before > size
    # per-view metric bars over all 50 views and stage-independent plots are there (SVG text kept as text)
    assert "PSNR (dB) per held-out view" in page and "SSIM per held-out view" in page
    assert page.count("distances: mvs") == 1 and page.count("<svg") >= 3 + 2


def test_max_panels_picks_the_lowest_psnr_views(big_project: Path, tmp_path: Path):
    from eval.metrics_io import read_metrics

    page = _write(big_project, tmp_path / "r2", max_panels=2).html.read_text()
    shown = sorted(set(re.findall(r"(\d{4}\.jpg): render \| photo", page)))
    per_view = {
        p: read_metrics(_metrics(big_project))["products"][p]["images"]["per_view"] for p in ("mvs", "splats", "merged")
    }
    with_panels = [v["view"] for v in per_view["mvs"] if v["files"].get("panel")]
    mean_psnr = {n: np.mean([next(v["full"]["psnr"] for v in per_view[p] if v["view"] == n) for p in per_view])
                 for n in with_panels}  # fmt: skip
    assert shown == sorted(sorted(with_panels, key=lambda n: mean_psnr[n])[:2])
    page0 = _write(big_project, tmp_path / "r0", max_panels=0).html.read_text()
    assert "render | photo" not in page0


def test_lengths_are_printed_in_the_users_unit(tmp_path: Path):

    ref = PointCloud(np.random.default_rng(1).uniform(0, 2, (800, 3)))
    cmp = PointCloud(ref.positions[:400] + [0.0123, 0.0, 0.0])  # every point 12.3 mm from its reference point
    write_metrics(
        _metrics(tmp_path), {"mvs": ProductMetrics(c2c=evaluate_geometry(cmp, ref, tmp_path / "eval", "mvs"))}
    )
    assert _build(tmp_path)["units"] == "m"
    md = _write(tmp_path, units="mm").markdown.read_text()
    assert "distance to the reference (mm)" in next(line for line in md.splitlines() if "Table 2" in line)
    header = next(line for line in md.splitlines() if line.startswith("| product | precision | recall | F-score |"))
    row = next(line for line in md.splitlines() if line.startswith("| mvs |"))
    assert row.split("|")[header.split("|").index(" mean ")].strip() == "12.3"  # mean, to 0.1 mm
    rep = json.loads((tmp_path / "report" / "report.json").read_text())
    assert rep["units"] == "mm" and rep["products"]["mvs"]["c2c"]["mean"] == pytest.approx(0.0123)  # JSON: metres
    # recorded in metrics.json: picked up without the argument
    data = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    (tmp_path / "eval" / "metrics.json").write_text(json.dumps({**data, "units": "ft"}))
    md = _write(tmp_path).markdown.read_text()
    row = next(line for line in md.splitlines() if line.startswith("| mvs |"))
    assert "(ft)" in md and row.split("|")[header.split("|").index(" mean ")].strip() == f"{0.0123 / 0.3048:.3f}"


def test_plot_helpers():
    import xml.etree.ElementTree as ET

    from eval.plots import jpeg_thumbnail, stage_bars_svg, svg_histogram

    a = svg_histogram([0.0, 0.001, 0.002], [3, 5], "C2C <&>", units="mm")
    assert a == svg_histogram([0.0, 0.001, 0.002], [3, 5], "C2C <&>", units="mm")  # deterministic bytes
    text = "".join(ET.fromstring(a).itertext())
    assert "C2C <&>" in text and "distance (mm)" in text and "2.0" in text  # the 2 mm edge, drawn in mm
    stages = "".join(ET.fromstring(stage_bars_svg(["sfm", "mvs"], [1.5, None], [100.0, 2500.0])).itertext())
    assert "sfm" in stages and "mvs" in stages and "time (s)" in stages and "peak memory (MB)" in stages
    thumb = jpeg_thumbnail(np.zeros((1000, 3008, 3), np.uint8), max_side=1500)
    img = cv2.imdecode(np.frombuffer(thumb, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (499, 1500, 3)
    small = cv2.imdecode(np.frombuffer(jpeg_thumbnail(np.zeros((10, 20), np.uint8)), np.uint8), cv2.IMREAD_COLOR)
    assert small.shape[:2] == (10, 20)  # never upscaled
