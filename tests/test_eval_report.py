"""metrics.json writer/reader, report.json schema, Markdown and self-contained HTML."""

import json
import re

import numpy as np
import pytest
from report_helpers import build_project_report as _build
from report_helpers import metrics_file as _metrics
from report_helpers import write_project_report as _write

from core.errors import FormatError, InputFileError
from core.pointcloud import PointCloud
from eval.geometry import GeometryOptions, evaluate_geometry
from eval.image_metrics import psnr
from eval.metrics_io import ProductMetrics, read_metrics, update_metrics, write_metrics
from eval.render_eval import ImagePair, evaluate_folders, evaluate_pairs
from eval.report import C2C_KEYS, IMAGE_KEYS


def _images(seed: int, n: int = 3, size=(48, 64)):
    rng = np.random.default_rng(seed)
    pairs = []
    for i in range(n):
        photo = rng.random((*size, 3))
        rendered = np.clip(photo + rng.normal(0, 0.02 * (i + 1), photo.shape), 0, 1)
        mask = np.zeros(size, bool)
        mask[10:30, 20:50] = True
        pairs.append(ImagePair(f"view_{i:02d}.png", rendered, photo, mask if i != 1 else None))
    return pairs


@pytest.fixture()
def project(tmp_path):
    rng = np.random.default_rng(0)
    origin = np.array([600_000.0, 5_100_000.0, 300.0])
    ref = PointCloud(rng.uniform(0, 20, (4000, 3)) * [1, 1, 0.1], origin)
    eval_dir = tmp_path / "eval"
    products = {}
    for name, noise in (("mvs", 0.03), ("merged", 0.015)):
        cmp = PointCloud(ref.positions[::2] + rng.normal(0, noise, (2000, 3)), origin)
        c2c = evaluate_geometry(cmp, ref, eval_dir, name, GeometryOptions(tau=0.05))
        images = evaluate_pairs(_images(1 if name == "mvs" else 2), None, eval_dir, name)
        products[name] = ProductMetrics(c2c=c2c, images=images)
    write_metrics(_metrics(tmp_path), products)
    update_metrics(
        _metrics(tmp_path), "splats", ProductMetrics.skip("no non-collaborative region: splat training skipped")
    )
    manifest = {
        "version": "0.1.0",
        "stages": {
            "recon.sfm": {"seconds": 12.5, "peak_mb": 800.0, "skipped": False, "reason": None, "counts": {"images": 3}},
            "fusion.train": {
                "seconds": 0.0,
                "peak_mb": 0.0,
                "skipped": True,
                "reason": "no region",
                "config": {"iters": 7},
            },
        },
    }
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    return tmp_path


def test_metrics_round_trip(project):
    data = read_metrics(_metrics(project))
    assert set(data["products"]) == {"mvs", "merged", "splats"}
    assert data["products"]["splats"]["skipped"] is True
    mvs = data["products"]["mvs"]
    assert mvs["c2c"]["count"] == 2000 and 0 < mvs["c2c"]["fscore"] <= 1
    views = mvs["images"]["per_view"]
    assert len(views) == 3 and views[1]["masked"] is None and views[0]["masked"] is not None
    assert mvs["images"]["masked"]["views"] == 2 and mvs["images"]["full"]["views"] == 3
    expected = np.mean([psnr(p.rendered, p.photo) for p in _images(1)])
    assert mvs["images"]["full"]["psnr"] == pytest.approx(expected, abs=1e-9)
    (project / "eval" / "broken.json").write_text("{")
    with pytest.raises(FormatError):
        read_metrics(project / "eval" / "broken.json")


def test_report_json_schema(project):
    rep = _build(project)
    assert list(rep["products"])[:4] == ["mvs", "baseline", "splats", "merged"]
    assert rep["products"]["baseline"]["skipped"] and "no entry" in rep["products"]["baseline"]["reason"]
    for name in ("mvs", "merged"):
        p = rep["products"][name]
        assert p["skipped"] is False
        assert set(C2C_KEYS) <= set(p["c2c"])
        for part in ("full", "masked"):
            assert set(IMAGE_KEYS) <= set(p["images"][part])
            assert p["images"][part]["lpips"] is None  # no LPIPS model was given
    assert rep["products"]["merged"]["c2c"]["mean"] < rep["products"]["mvs"]["c2c"]["mean"]
    splats = rep["products"]["splats"]
    assert splats["skipped"] and "skipped" in splats["reason"] and splats["c2c"] is None
    assert rep["stages"]["recon.sfm"] == {
        "seconds": 12.5,
        "peak_mb": 800.0,
        "skipped": False,
        "reason": None,
        "cached": False,
        "counts": {"images": 3},
    }
    assert rep["stages"]["fusion.train"]["skipped"] is True
    assert rep["config"]["fusion.train"] == {"iters": 7}
    assert rep["timings"]["total_seconds"] == pytest.approx(12.5)
    assert rep["versions"]["numpy"] == np.__version__


def test_report_files_self_contained(project):
    paths = _write(project)
    rep = json.loads(paths.json.read_text())
    assert rep["schema"] == "hybridsplat.report/1"
    md = paths.markdown.read_text()
    assert "Table 2" in md and "Table 3" in md and "Table 4" in md and "| mvs |" in md
    assert "no non-collaborative region" in md
    page = paths.html.read_text()
    assert page.count("<svg") >= 3  # two C2C histograms + per-view PSNR
    # C2C colour-mapped views + render panels (3 views of 2 products, within max_panels), as JPEG thumbnails
    assert page.count("data:image/jpeg;base64,") >= 2 + 2 * 3
    # self-contained: no external references
    assert not re.search(r"""(src|href)=["'](?!data:|#)""", page)
    assert "fusion.train" in page


@pytest.mark.parametrize("renderer, named", [("gsplat", "gsplat (CUDA)"), ("cpu", "the CPU rasteriser")])
def test_report_names_the_renderer_of_the_image_tables(project, renderer, named):
    paths = _write(project)
    assert "rendered with" not in paths.markdown.read_text()  # the eval record does not say: nothing claimed
    manifest = json.loads((project / "manifest.json").read_text())
    manifest["stages"]["eval"] = {"seconds": 1.0, "peak_mb": 1.0, "skipped": False, "reason": None,
                                  "counts": {"renderer": renderer, "views": 3}}  # fmt: skip
    (project / "manifest.json").write_text(json.dumps(manifest))
    paths = _write(project)
    md, page = paths.markdown.read_text(), paths.html.read_text()
    for table in ("Table 3 — image metrics, whole image", "Table 4 — image metrics, non-collaborative mask"):
        assert f"## {table} (rendered with {named})" in md
        assert f"{table} (rendered with {named})" in page
    table2 = next(line for line in md.splitlines() if line.startswith("## Table 2"))
    assert table2.endswith("distance to the reference (metres)")  # geometry tables are not rendered


def test_report_without_inputs(tmp_path):
    rep = _build(tmp_path)
    for name in ("mvs", "splats", "merged"):
        assert rep["products"][name]["skipped"] and "metrics.json" in rep["products"][name]["reason"]
    assert rep["stages"] == {} and rep["manifest_found"] is False
    _write(tmp_path)
    assert (tmp_path / "report" / "report.html").is_file()
    with pytest.raises(InputFileError):
        _build(tmp_path / "nope")


def test_evaluate_folders_matches_pairs(tmp_path):
    from core.io.images import write_image

    pairs = _images(3, n=2)
    for sub in ("r", "p", "m"):
        (tmp_path / sub).mkdir()
    for p in pairs:
        write_image(tmp_path / "r" / p.view, p.rendered)
        write_image(tmp_path / "p" / p.view, p.photo)
        if p.mask is not None:
            write_image(tmp_path / "m" / p.view, p.mask.astype(np.uint8) * 255)
    res = evaluate_folders(tmp_path / "r", tmp_path / "p", tmp_path / "m")
    assert [v.view for v in res.per_view] == [p.view for p in pairs]
    q = lambda x: np.round(x * 255).astype(np.uint8)  # noqa: E731 - files hold 8-bit colours
    assert res.per_view[0].full.psnr == pytest.approx(psnr(q(pairs[0].rendered), q(pairs[0].photo)), abs=1e-9)
    assert res.per_view[1].masked is None and res.per_view[0].mask_share == pytest.approx(pairs[0].mask.mean())
    with pytest.raises(InputFileError):
        evaluate_folders(tmp_path / "r", tmp_path / "m2")


def test_evaluate_product_records_skips_and_geometry(tmp_path):
    from eval.evaluate import evaluate_product

    rng = np.random.default_rng(5)
    ref = PointCloud(rng.uniform(0, 3, (500, 3)))
    p = evaluate_product(_metrics(tmp_path), "mvs", cloud=PointCloud(ref.positions[:200] + 0.01), reference=ref)
    assert p.c2c is not None and p.images is None and not p.skipped
    evaluate_product(_metrics(tmp_path), "splats")  # no inputs: recorded as skipped with a reason
    data = read_metrics(_metrics(tmp_path))
    assert data["products"]["mvs"]["c2c"]["mean"] == pytest.approx(np.sqrt(3) * 0.01, abs=1e-12)
    assert data["products"]["splats"]["skipped"] and "nothing to measure" in data["products"]["splats"]["reason"]


def test_svg_plots_are_well_formed():
    import xml.etree.ElementTree as ET

    from eval.plots import svg_bars, svg_histogram

    # parsing raises on malformed XML (unescaped <, & in titles and labels)
    hist = ET.fromstring(svg_histogram([0.0, 0.1, 0.2], [3, 5], "h <&> title"))
    bars = ET.fromstring(svg_bars([("a", [1.0, 2.0]), ("b", [0.5, 0.0])], ["v<1>", "v2"], "t", "x", "y"))
    assert hist.tag.endswith("svg") and bars.tag.endswith("svg")
    assert "h <&> title" in "".join(hist.itertext())


def test_registration_and_classes_reach_the_report(tmp_path):
    from eval.evaluate import evaluate_product

    rng = np.random.default_rng(6)
    n = 2000
    u = rng.uniform(0, 5, size=(3, n, 2))
    corner = np.concatenate(
        [np.c_[u[0], np.zeros(n)], np.c_[u[1][:, 0], np.zeros(n), u[1][:, 1]], np.c_[np.zeros(n), u[2]]]
    )
    origin = np.array([300_000.0, 6_000_000.0, 50.0])
    classes = rng.integers(1, 3, len(corner)).astype(np.uint8)
    moved = PointCloud(corner + [0.02, -0.01, 0.0], origin, fields={"classification": classes})
    opts = GeometryOptions(icp_max_correspondence=0.1, tau=0.01)
    p = evaluate_product(_metrics(tmp_path), "mvs", cloud=moved, reference=PointCloud(corner, origin), geometry=opts)
    assert p.c2c.stats.max < 1e-6 and p.c2c.scores.fscore == 1.0  # ICP removed the 2 cm shift
    local = np.asarray(p.c2c.registration["local_transform"])
    np.testing.assert_allclose(local[:3, 3], [-0.02, 0.01, 0.0], atol=1e-6)
    md = _write(tmp_path).markdown.read_text()
    assert "Registration applied before measuring" in md and "-0.0200" in md
    assert "Distances per class" in md and "| mvs | 2 |" in md


def test_metrics_json_has_no_nan(tmp_path):
    from eval.c2c import DistanceStats
    from eval.metrics_io import C2CSummary

    stats = DistanceStats(1, float("nan"), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, float("inf"))
    write_metrics(_metrics(tmp_path), {"mvs": ProductMetrics(c2c=C2CSummary(stats=stats))})
    text = (tmp_path / "eval" / "metrics.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert read_metrics(_metrics(tmp_path))["products"]["mvs"]["c2c"]["mean"] is None
