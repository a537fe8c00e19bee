"""Reports a surveyor can hand over: ``report/report.{json,md,html}`` from ``manifest.json`` + ``eval/metrics.json``.

``report.json`` is a stable schema (``hybridsplat.report/1``) users script against::

    products.<name>.{skipped, reason}
    products.<name>.c2c.{count, mean, std, median, rmse, p90, p95, p99, max, outlier_count, outlier_share,
                         tau, completeness, precision, recall, fscore, method, reference, registration, per_class}
    products.<name>.images.{full, masked}.{views, mse, psnr, ssim, ms_ssim, lpips, delta_e, std}
    stages.<name>.{seconds, peak_mb, skipped, reason, cached, counts}
    versions (this report's environment), pipeline_versions (from the manifest), config,
    timings.{total_seconds, stages}

Every key is always present (null when not measured); the products ``mvs``, ``splats`` and ``merged`` are
always listed (skipped with a reason when absent), ``baseline_gs`` and others when measured. Distances in
report.json are metres, whatever the user's unit; ``units`` (added, optional for readers) names the unit the
Markdown and HTML print lengths in: the ``units`` argument, else ``units`` recorded in metrics.json, else the
manifest's ``config.units``, else metres. Image metrics on colours in [0, 1].

The HTML page is self-contained: matplotlib plots inline as SVG (C2C histograms, per-view metric bars, stage
time and memory) or JPEG (C2C colour-mapped views), and render panels as downscaled JPEG thumbnails (at most
``max_panels`` per product, the views with the lowest PSNR), so that a 50-photo project stays within a few MB.
"""

from __future__ import annotations

import html
import json
import math
import platform
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib import metadata
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import DataError, FormatError, InputFileError
from core.io.atomic import output_transaction, write_text_atomic
from core.io.json_io import to_jsonable, write_json_atomic
from core.units import Units
from eval.metrics_io import PRODUCTS, read_metrics
from eval.plots import c2c_views_jpeg, jpeg_data_uri, jpeg_thumbnail, metric_bars_svg, stage_bars_svg, svg_histogram
from eval.report_accuracy import accuracy_html, accuracy_markdown, read_accuracy
from eval.report_options import DEFAULT_MAX_PANELS
from eval.report_summary import SUMMARY_PRODUCTS, split_panel, summary_table

SCHEMA = "hybridsplat.report/1"
REQUIRED_PRODUCTS = PRODUCTS  # always listed, measured or with the reason they were not
C2C_KEYS = (
    "count", "mean", "std", "median", "rmse", "p90", "p95", "p99", "max", "outlier_count", "outlier_share",
    "tau", "completeness", "precision", "recall", "fscore",
)  # fmt: skip
IMAGE_KEYS = ("mse", "psnr", "ssim", "ms_ssim", "lpips", "delta_e")
IMAGE_LABELS = {
    "mse": "MSE",
    "psnr": "PSNR (dB)",
    "ssim": "SSIM",
    "ms_ssim": "MS-SSIM",
    "lpips": "LPIPS",
    "delta_e": "ΔE",
}
STAGE_KEYS = ("seconds", "peak_mb", "skipped", "reason")
THUMBNAIL_MAX_SIDE = 1500  # px, longer side of a render panel thumbnail (a panel is render | photo | error)
LENGTH_KEYS = ("mean", "std", "median", "rmse", "p90", "p95", "p99", "max", "tau")  # metres in report.json
_PACKAGES = (
    "hybridsplat",
    "numpy",
    "scipy",
    "torch",
    "open3d",
    "pycolmap",
    "scikit-image",
    "scikit-learn",
    "plyfile",
    "laspy",
)


@dataclass(frozen=True)
class ReportPaths:
    """The three files a report consists of."""

    json: Path
    markdown: Path
    html: Path


def _read_json(path: Path, what: str) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as err:
        raise FormatError(f"{what} is not valid JSON ({err})", path) from err
    if not isinstance(data, dict):
        raise FormatError(f"{what} must hold a JSON object", path)
    stages = data.get("stages")
    if stages is not None and not (isinstance(stages, dict) and all(isinstance(v, dict) for v in stages.values())):
        raise FormatError(f"{what}: 'stages' must map stage names to objects", path)
    for name, record in (stages or {}).items():
        for key in ("seconds", "peak_mb"):
            value = record.get(key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
                raise FormatError(f"{what}: stages.{name}.{key} must be a number, found {value!r}", path)
        if record.get("counts") is not None and not isinstance(record["counts"], dict):
            raise FormatError(f"{what}: stages.{name}.counts must be an object", path)
    return data


def _versions(manifest: Mapping[str, Any] | None) -> dict[str, str | None]:
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    if manifest is not None:
        out["manifest"] = None if manifest.get("version") is None else str(manifest.get("version"))
    return out


def _c2c_block(raw: Mapping[str, Any] | None) -> dict[str, Any] | None:
    if raw is None:
        return None
    out = {k: raw.get(k) for k in C2C_KEYS}
    out.update(
        method=raw.get("method"),
        reference=raw.get("reference"),
        registration=raw.get("registration"),
        per_class=raw.get("per_class") or {},
        reverse=raw.get("reverse"),
    )
    return out


def _image_summary(raw: Mapping[str, Any] | None) -> dict[str, Any] | None:
    if raw is None:
        return None
    std = raw.get("std") or {}
    return {
        "views": raw.get("views"),
        **{k: raw.get(k) for k in IMAGE_KEYS},
        "std": {k: std.get(k) for k in IMAGE_KEYS},
    }


def _product_block(raw: Mapping[str, Any] | None, missing_reason: str) -> dict[str, Any]:
    if raw is None:
        return {"skipped": True, "reason": missing_reason, "c2c": None, "images": {"full": None, "masked": None}}
    images = raw.get("images") or {}
    return {
        "skipped": bool(raw.get("skipped", False)),
        "reason": raw.get("reason"),
        "c2c": _c2c_block(raw.get("c2c")),
        "images": {"full": _image_summary(images.get("full")), "masked": _image_summary(images.get("masked"))},
    }


def _units(units: Units | str | None, metrics: Mapping[str, Any], manifest: Mapping[str, Any] | None) -> Units:
    """The unit lengths are printed in: the argument, else metrics.json's ``units``, else the manifest config's."""
    if units is not None:
        return Units.parse(units)
    for candidate in (metrics.get("units"), ((manifest or {}).get("config") or {}).get("units")):
        if isinstance(candidate, str):
            return Units.parse(candidate)
    return Units.M


def build_report(
    manifest_file: str | PathLike[str],
    metrics_file: str | PathLike[str],
    units: Units | str | None = None,
    per_material_file: str | PathLike[str] | None = None,
    accuracy_file: str | PathLike[str] | None = None,
) -> dict[str, Any]:
    """The report.json content from a project's manifest and metrics files (either may be missing).

    units: the unit the Markdown/HTML print lengths in (recorded as ``units``; report.json stays in metres).
    per_material_file: scores per ground-truth material (see eval.per_material), shown when the file exists.
    accuracy_file: the survey control's accuracy statement (eval.accuracy), shown when the file exists.
    """
    manifest_file, metrics_file = Path(manifest_file), Path(metrics_file)
    root = manifest_file.parent
    if not root.is_dir():
        raise InputFileError("project folder does not exist", root)
    manifest = _read_json(manifest_file, "manifest")
    metrics = read_metrics(metrics_file) if metrics_file.is_file() else {"products": {}}
    measured: Mapping[str, Any] = metrics["products"]
    if metrics_file.is_file():
        reason = f"not evaluated: no entry for this product in {metrics_file.name}"
    else:
        reason = f"not evaluated: {metrics_file.name} does not exist (run the eval stage)"
    names = list(REQUIRED_PRODUCTS) + sorted(n for n in measured if n not in REQUIRED_PRODUCTS)
    products = {n: _product_block(measured.get(n), reason) for n in names}

    stages: dict[str, Any] = {}
    config: dict[str, Any] = {}
    for name, st in ((manifest or {}).get("stages") or {}).items():
        st = st or {}
        stages[name] = {**{k: st.get(k) for k in STAGE_KEYS}, "cached": bool(st.get("cached", False))}
        stages[name]["counts"] = st.get("counts") or {}
        stages[name]["skipped"] = bool(stages[name]["skipped"])
        if st.get("config") is not None:
            config[name] = st["config"]
    if manifest is not None and isinstance(manifest.get("config"), Mapping):
        config = {"project": manifest["config"], **config}
    total = sum(float(s["seconds"]) for s in stages.values() if isinstance(s.get("seconds"), (int, float)))
    return {
        "schema": SCHEMA,
        "project": str(root.resolve()),
        "generated_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "versions": _versions(manifest),
        "pipeline_versions": dict((manifest or {}).get("versions") or {}),
        "config": config,
        "timings": {"total_seconds": total, "stages": {n: s["seconds"] for n, s in stages.items()}},
        "manifest_found": manifest is not None,
        "units": _units(units, metrics, manifest).value,
        "products": products,
        "per_material": _per_material(per_material_file),
        "accuracy": read_accuracy(accuracy_file),
        "stages": stages,
    }


def _per_material(path: str | PathLike[str] | None) -> dict[str, Any] | None:
    if path is None or not Path(path).is_file():
        return None
    data = _read_json(Path(path), "per-material scores")
    if data is None or not isinstance(data.get("products"), Mapping):
        raise FormatError("per-material scores have no 'products' table", path)
    return data


# -- formatting -------------------------------------------------------------------------------------


def _num(v: Any, digits: int = 4, sci: bool = False) -> str:
    """Fixed-point text (metres to 0.1 mm by default); ``sci`` for quantities that are often tiny (MSE)."""
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if sci and v != 0 and abs(v) < 10 ** (1 - digits):
            return f"{v:.2e}"
        return f"{v:.{digits}f}".replace("-0.0000", "0.0000")
    return str(v)


def _len(v: Any, units: Units) -> str:
    """A length given in metres, printed in ``units`` to 0.1 mm (metres: 4 decimals, mm: 1, cm: 2, ft: 3)."""
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return _num(v)
    digits = max(0, 4 + round(math.log10(units.metres)))
    return _num(float(units.from_metres(float(v))), digits)


def _report_units(report: Mapping[str, Any]) -> Units:
    return Units.parse(report.get("units") or "m")


def _pm(block: Mapping[str, Any] | None, key: str) -> str:
    if block is None or block.get(key) is None:
        return "–"
    std = (block.get("std") or {}).get(key)
    digits = 2 if key in ("psnr", "delta_e") else 4
    sci = key == "mse"
    return _num(block[key], digits, sci) + ("" if std is None else f" ± {_num(std, digits, sci)}")


@dataclass(frozen=True)
class TrainingRun:
    """How a product's training ended: its ``steps`` and whether its early stop ended it (else its whole budget)."""

    steps: int
    stopped_early: bool


@dataclass(frozen=True)
class RunNotes:
    """What the report tells of how the products were made, beside their figures (the pipeline fills it from the
    stages' results, :func:`hybridsplat.stages.report.run_notes`): the fill splats' masked training (``fill``: of
    ``merged`` and ``splats``) and the whole-scene baseline's (None: not trained), the background and survey
    appearance fits' steps (0: none), and the rasteriser that rendered the held-out views (``renderer``: a key of
    :data:`RENDERER_NAMES`; None: not said, as in an older project)."""

    fill: TrainingRun | None = None
    baseline: TrainingRun | None = None
    background_steps: int = 0
    appearance_steps: int = 0
    renderer: str | None = None


def _training_note(run: TrainingRun | None, what: str) -> str:
    if run is None:
        return ""
    end = "ended by its early stop" if run.stopped_early else "its whole step budget"
    return f"{what}: {run.steps} steps ({end})"


def _budget_notes(report: Mapping[str, Any], run: RunNotes) -> dict[str, str]:
    """What each product's figures cost in training, for the note column: a product trained for fewer steps is
    not compared as if it had plateaued."""
    notes = {
        "mvs": "no training",
        "mvs_filtered": "control: the MVS part of merged alone (no splats)",
        "merged_no_background": "control: merged without its background layer",
        "merged_unrefined": "control: merged with every layer as before the appearance stage (no refinement)",
    }
    notes["baseline"] = _training_note(run.baseline, "whole scene")
    notes["merged"] = notes["splats"] = _training_note(run.fill, "splats in the masks")
    for steps, what in ((run.background_steps, "background"), (run.appearance_steps, "survey appearance")):
        if steps:
            notes["merged"] += f"; {what}: {steps} steps"
    for name in report.get("products") or {}:
        if name.startswith("baseline_") and name.split("_", 1)[1].isdigit():
            notes[name] = f"whole scene: {int(name.split('_', 1)[1])} steps (a checkpoint of the baseline)"
    return notes


#: how the report names the rasteriser that rendered the held-out views (the eval stage's ``renderer`` count)
RENDERER_NAMES = {
    "cpu": "the CPU rasteriser",
    "gsplat": "gsplat (CUDA)",
    "reference": "the PyTorch reference rasteriser",
}


def _renderer_note(run: RunNotes) -> str:
    """The image tables' title suffix " (rendered with …)": which rasteriser the eval stage rendered the held-out
    views with (gsplat on a GPU, the CPU rasteriser elsewhere; compared in docs/experiments/2026-11-27-gpu-paths.md);
    empty when the eval record does not say (an older project)."""
    renderer = run.renderer
    return f" (rendered with {RENDERER_NAMES.get(renderer, str(renderer))})" if renderer else ""


def _tables(report: Mapping[str, Any], run: RunNotes = RunNotes()) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, rows) of every table, shared by Markdown and HTML; ``run``: how the products were made."""
    products = report["products"]
    u = _report_units(report)
    unit_name = "metres" if u is Units.M else u.value
    c2c_rows = []
    taus = set()
    for name, p in products.items():
        c = p["c2c"]
        if c is None:
            c2c_rows.append([name, "–", "–", "–", "–", "–", "–", "–", "–", "–", "–", p["reason"] or "not measured"])
            continue
        if c.get("tau") is not None:
            taus.add(float(c["tau"]))
        c2c_rows.append(
            [name, _num(c.get("precision")), _num(c["completeness"]), _num(c["fscore"]), _len(c["mean"], u),
             _len(c["std"], u), _len(c["median"], u), _len(c["rmse"], u), _len(c["p95"], u), _len(c["max"], u),
             _num(c["count"]), f"{c.get('method') or 'c2c'}" + (", ICP" if c.get("registration") else "")]
        )  # fmt: skip
    at_tau = f" at τ = {_len(next(iter(taus)), u)} {u.value}" if len(taus) == 1 else " at τ"
    tables = [
        (
            f"Table 2 — survey accuracy: precision, recall (completeness) and F-score{at_tau}, and distance to the "
            f"reference ({unit_name})",
            ["product", "precision", "recall", "F-score", "mean", "st. dev.", "median", "RMSE", "P95", "max", "points",
             "note"],
            c2c_rows,
        )
    ]  # fmt: skip
    rendered = _renderer_note(run)
    for part, title in (
        ("full", f"Table 3 — image metrics, whole image{rendered}"),
        ("masked", f"Table 4 — image metrics, non-collaborative mask{rendered}"),
    ):
        rows = []
        notes = _budget_notes(report, run)
        for name, p in products.items():
            block = p["images"][part]
            if block is None:
                rows.append([name] + ["–"] * len(IMAGE_KEYS) + ["–", p["reason"] or "not measured"])
            else:
                rows.append(
                    [name] + [_pm(block, k) for k in IMAGE_KEYS] + [_num(block.get("views")), notes.get(name, "")]
                )
        tables.append((title, ["product"] + [IMAGE_LABELS[k] for k in IMAGE_KEYS] + ["views", "note"], rows))
    class_rows = [
        [name, str(k), _num(st.get("count")), _len(st.get("mean"), u), _len(st.get("std"), u),
         _len(st.get("rmse"), u), _len(st.get("p95"), u), _len(st.get("max"), u), _num(st.get("outlier_count"))]
        for name, p in products.items() if p["c2c"] is not None
        for k, st in (p["c2c"].get("per_class") or {}).items()
    ]  # fmt: skip
    if class_rows:
        header = ["product", "class", "points", "mean", "st. dev.", "RMSE", "P95", "max", "outliers"]
        tables.append((f"Distances per class ({unit_name})", header, class_rows))
    reg_rows = []
    for name, p in products.items():
        reg = (p["c2c"] or {}).get("registration")
        if reg:
            # about the local origin: a world-frame translation of a UTM block mixes in rotation × origin
            t = reg.get("local_transform") or reg.get("world_transform") or [[0.0] * 4] * 3
            shift = ", ".join(_len(t[i][3], u) for i in range(3))
            reg_rows.append([name, reg.get("method", "icp"), _num(reg.get("fitness")), _len(reg.get("inlier_rmse"), u),
                             f"({shift})", json.dumps([[round(v, 6) for v in row[:3]] for row in t[:3]])])  # fmt: skip
    if reg_rows:
        header = ["product", "method", "fitness", f"inlier RMSE ({u.value})", f"translation at origin ({u.value})",
                  "rotation"]  # fmt: skip
        tables.append(("Registration applied before measuring", header, reg_rows))
    tables.extend(_per_material_tables(report.get("per_material"), u))
    stage_rows = [
        [name, _num(s["seconds"], 2), _num(s["peak_mb"], 0), _num(s["skipped"]), s["reason"] or ""]
        for name, s in report["stages"].items()
    ]
    tables.append(("Pipeline stages", ["stage", "seconds", "peak MB", "skipped", "reason"], stage_rows))
    return tables


Table = tuple[str, list[str], list[list[str]]]


def _per_material_tables(per_material: Mapping[str, Any] | None, u: Units) -> list[Table]:
    """Table 5: per ground-truth material, each product's F-score at τ (precision / recall), then its accuracy and
    held-out PSNR. One column per product, so that the tables stay as narrow as the products are few."""
    if not per_material:
        return []
    products: Mapping[str, Any] = per_material["products"]
    kinds: Mapping[str, Any] = per_material.get("materials") or {}
    names = list(dict.fromkeys(m for table in products.values() for m in table))
    tau = _len(per_material.get("tau_m"), u)
    f_rows, geo_rows = [], []
    for m in names:
        info = kinds.get(m) or {}
        kind = str(info.get("kind", "")) + ("" if info.get("collaborative", True) else " (non-collab.)")
        f_row, geo_row = [m, kind], [m, kind]
        for table in products.values():
            r = table.get(m) or {}
            pr = f"{_num(r.get('precision'), 2)} / {_num(r.get('completeness'), 2)}"
            f_row.append(f"{_num(r.get('fscore'), 3)} ({pr})")
            geo_row.append(f"{_len(r.get('accuracy_mean_m'), u)} · {_num(r.get('psnr'), 2)}")
        f_rows.append(f_row)
        geo_rows.append(geo_row)
    header = ["material", "kind", *products]
    tables = [
        (f"Table 5 — per ground-truth material: F-score at τ = {tau} {u.value} (precision / recall)", header, f_rows),
        (f"Table 5b — per ground-truth material: accuracy mean ({u.value}) · PSNR on held-out pixels (dB)", header,
         geo_rows),
    ]  # fmt: skip
    return tables + _sigma_calibration_tables(per_material.get("sigma_calibration"), u)


def _sigma_calibration_tables(calibration: Mapping[str, Any] | None, u: Units) -> list[Table]:
    """Table 6: the σ of the points of ``merged`` that carry one (else of the first product whose points do; a
    ``sigma`` field) against their distance to the reference surface (:mod:`eval.sigma_calibration`), all points and
    per material; none when no product's points carry a σ."""
    if not calibration:
        return []
    product = "merged" if "merged" in calibration else next(iter(calibration))
    table = calibration[product]
    header = ["material", "points", "within 1σ (0.683 if calibrated)", "within 1.96σ (0.95)",
              f"median σ ({u.value})", f"median distance ({u.value})"]  # fmt: skip
    rows = [[m, str(r.get("points", 0)), _num(r.get("within_1sigma"), 3), _num(r.get("within_95"), 3),
             _len(r.get("median_sigma_m"), u), _len(r.get("median_distance_m"), u)]
            for m, r in table.items()]  # fmt: skip
    title = (
        f"Table 6 — σ of the points of `{product}` that carry one against their distance to the reference "
        "surface (local plane of the 8 nearest reference points)"
    )
    return [(title, header, rows)]


def to_markdown(report: Mapping[str, Any], run: RunNotes = RunNotes()) -> str:
    """The report as Markdown (tables like the paper's Tables 2–4, stage timings, versions); ``run``: how the
    products were made (the notes beside their figures)."""
    lines = [
        "# hybridsplat evaluation report",
        "",
        f"Project: `{report['project']}`  ",
        f"Generated: {report['generated_utc']}",
        "",
    ]
    if not report.get("manifest_found", True):
        lines += ["_No manifest.json found: stage timings are unavailable._", ""]
    title, header, rows, findings = _summary(report)
    if rows:
        lines += [f"## {title}", "", *findings, ""] if findings else [f"## {title}", ""]
        lines.append("| " + " | ".join(header) + " |")
        lines.append("|" + "|".join("---" for _ in header) + "|")
        lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
    for title, header, rows in _tables(report, run):
        lines += [f"## {title}", ""]
        if not rows:
            lines += ["_none recorded_", ""]
            continue
        lines.append("| " + " | ".join(header) + " |")
        lines.append("|" + "|".join("---" for _ in header) + "|")
        lines += ["| " + " | ".join(cell.replace("|", "\\|") for cell in row) + " |" for row in rows]
        lines.append("")
    lines += accuracy_markdown(report.get("accuracy"), _report_units(report))
    lines += _sections_markdown(report)
    skipped = [(n, p["reason"]) for n, p in report["products"].items() if p["skipped"]]
    if skipped:
        lines += ["## Skipped products", ""] + [f"- **{n}**: {r}" for n, r in skipped] + [""]
    lines += [f"Total pipeline time: {_num(report['timings']['total_seconds'], 1)} s", "", "## Versions", ""]
    lines += [f"- {k}: {v if v is not None else 'not installed'}" for k, v in report["versions"].items()]
    return "\n".join(lines) + "\n"


_CSS = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1200px;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1.5em}th,td{border:1px solid #ccc;padding:4px 8px;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left;font-weight:600}
figure{display:inline-block;margin:0.5em;vertical-align:top}figcaption{font-size:0.85em;color:#555}
img{max-width:100%;border:1px solid #ddd}.note{color:#777}svg{max-width:100%;height:auto}
pre{white-space:pre-wrap;overflow-wrap:anywhere}table.grid td{padding:2px;text-align:center}
table.grid img{max-width:200px}table.grid td:first-child{font-size:0.8em}
"""


def _thumbnail_tag(path: Path, alt: str, max_side: int = THUMBNAIL_MAX_SIDE) -> str:
    """An <img> with the image at ``path`` as an inline JPEG thumbnail ('' when the file is missing/unreadable)."""
    if not path.is_file():
        return ""
    try:
        data = jpeg_thumbnail(path, max_side=max_side)
    except (InputFileError, DataError):
        return ""
    return f'<img src="{jpeg_data_uri(data)}" alt="{html.escape(alt)}">'


def _c2c_views_tag(eval_dir: Path, name: str, c2c: Mapping[str, Any], units: Units) -> str:
    """The C2C colour-mapped views of a product from its distance cloud (``files.cloud_ply``, field ``c2c``);
    falls back to the stored preview image; '' when neither can be read."""
    from core.io.ply import read_ply

    files = c2c.get("files") or {}
    cloud_file = eval_dir / files["cloud_ply"] if files.get("cloud_ply") else None
    if cloud_file is not None and cloud_file.is_file():
        try:
            cloud = read_ply(cloud_file)
            dist = cloud.fields.get("c2c") if cloud.fields else None
            if dist is not None and len(cloud):
                p95 = c2c.get("p95")
                vmax = float(p95) if isinstance(p95, (int, float)) and p95 > 0 else float(np.percentile(dist, 95))
                data = c2c_views_jpeg(cloud.positions, dist, vmax, name, units)
                return f'<img src="{jpeg_data_uri(data)}" alt="C2C views {html.escape(name)}">'
        except (InputFileError, FormatError, DataError):
            pass  # fall back to the preview written by the eval stage
    if files.get("preview"):
        return _thumbnail_tag(eval_dir / files["preview"], f"C2C preview {name}", max_side=900)
    return ""


def _per_view(raw_products: Mapping[str, Any]) -> dict[str, list[Mapping[str, Any]]]:
    return {
        name: list(((raw or {}).get("images") or {}).get("per_view") or [])
        for name, raw in raw_products.items()
        if ((raw or {}).get("images") or {}).get("per_view")
    }


def _metric_series(per_view: Mapping[str, list[Mapping[str, Any]]], key: str) -> tuple[list[str], list]:
    """Views (in the first product's order) and one series per product of metric ``key`` (None where missing)."""
    labels: list[str] = []
    for views in per_view.values():
        for v in views:
            if str(v["view"]) not in labels:
                labels.append(str(v["view"]))
    series = []
    for name, views in per_view.items():
        by_view = {str(v["view"]): (v.get("full") or {}).get(key) for v in views}
        vals = [by_view.get(label) for label in labels]
        if any(isinstance(x, (int, float)) for x in vals):
            series.append((name, vals))
    return labels, series


def _panel_views(per_view: Mapping[str, list[Mapping[str, Any]]], max_panels: int) -> list[str]:
    """The views shown as panels: those with a panel file, lowest mean PSNR first, at most ``max_panels``."""
    psnr: dict[str, list[float]] = {}
    for views in per_view.values():
        for v in views:
            if (v.get("files") or {}).get("panel"):
                value = (v.get("full") or {}).get("psnr")
                psnr.setdefault(str(v["view"]), []).append(float(value) if isinstance(value, (int, float)) else 1e9)
    ranked = sorted(psnr, key=lambda view: (sum(psnr[view]) / len(psnr[view]), view))
    return ranked[: max(0, int(max_panels))]


def _sections_html(report: Mapping[str, Any]) -> list[str]:
    """HTML of the stages' own sections (``report["sections"]``: title, lines, figures relative to the project, in
    pipeline order; sections of the same title are shown under one heading)."""
    e = html.escape
    root = Path(str(report.get("project", ".")))
    parts: list[str] = []
    title = None
    for section in report.get("sections") or []:
        if section["title"] != title:
            title = section["title"]
            parts.append(f"<h2>{e(title)}</h2>")
        parts += [f"<p>{e(line)}</p>" for line in section.get("lines", [])]
        for rel, caption in section.get("figures", []):
            tag = _thumbnail_tag(root / str(rel), caption, max_side=1100)
            if tag:
                parts.append(f"<figure style='max-width:1100px'>{tag}<figcaption>{e(caption)}</figcaption></figure>")
    return parts


def _sections_markdown(report: Mapping[str, Any]) -> list[str]:
    """Markdown of the stages' own sections (their lines; figures by path)."""
    lines: list[str] = []
    title = None
    for section in report.get("sections") or []:
        if section["title"] != title:
            title = section["title"]
            lines += [f"## {title}", ""]
        lines += [*section.get("lines", []), ""]
        lines += [f"- figure: `{rel}` ({caption})" for rel, caption in section.get("figures", [])]
    return lines


def _summary(report: Mapping[str, Any]) -> tuple[str, list[str], list[list[str]], list[str]]:
    u = _report_units(report)
    return summary_table(report, lambda v: _len(v, u), u.value)


def _html_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A table; a cell written ``**text**`` (the best value of a summary column) is shown in bold."""
    e = html.escape

    def cell(c: str) -> str:
        bold = len(c) > 4 and c.startswith("**") and c.endswith("**")
        return f"<td><strong>{e(c[2:-2])}</strong></td>" if bold else f"<td>{e(c)}</td>"

    parts = ["<table><tr>" + "".join(f"<th>{e(h)}</th>" for h in header) + "</tr>"]
    parts += ["<tr>" + "".join(cell(c) for c in row) + "</tr>" for row in rows]
    return "\n".join(parts + ["</table>"])


GRID_THUMBNAIL_SIDE = 300  # px, longer side of each picture of the grid (five to a row fit a 1280 px page)


def _picture_grid(per_view: Mapping[str, list[Mapping[str, Any]]], eval_dir: Path, max_panels: int) -> list[str]:
    """Per held-out view with a merged panel (the lowest-PSNR views first, at most ``max_panels``): the photo, the
    renders of MVS only, the baseline and merged, and merged's error map, in one row."""
    from core.io.images import read_image

    e = html.escape
    panels = {name: {str(v["view"]): (v.get("files") or {}).get("panel") for v in views}
              for name, views in per_view.items()}  # fmt: skip
    merged = {v: f for v, f in (panels.get("merged") or {}).items() if f}
    chosen = [v for v in _panel_views({"merged": per_view.get("merged", [])}, max_panels) if v in merged]
    if not chosen:
        return []
    columns = ["photo"] + [label for name, label in SUMMARY_PRODUCTS if panels.get(name)] + ["merged: error"]
    head = "".join(f"<th>{e(c)}</th>" for c in ["view", *columns])
    rows = []
    for view in chosen:
        cut = {}
        for name, _ in SUMMARY_PRODUCTS:
            path = eval_dir / str((panels.get(name) or {}).get(view) or "")
            if path.is_file():
                try:
                    cut[name] = split_panel(read_image(path))
                except (InputFileError, DataError, ValueError):
                    continue
        if "merged" not in cut:
            continue
        render, photo, error = cut["merged"]
        pictures = [photo] + [cut[n][0] if n in cut else None for n, _ in SUMMARY_PRODUCTS if panels.get(n)]
        pictures.append(error)
        cells = [f"<td>{e(view)}</td>"]
        for picture in pictures:
            if picture is None:
                cells.append("<td>–</td>")
                continue
            data = jpeg_thumbnail(np.ascontiguousarray(picture), max_side=GRID_THUMBNAIL_SIDE)
            cells.append(f'<td><img src="{jpeg_data_uri(data)}" alt="{e(view)}"></td>')
        rows.append("<tr>" + "".join(cells) + "</tr>")
    if not rows:
        return []
    note = ("<p class='note'>Held-out views (never trained on), the lowest merged PSNR first; the error map is the "
            "per-pixel RMS colour error of merged (viridis, 0–0.25).</p>")  # fmt: skip
    return ["<h2>Held-out views: photo, products and merged's error</h2>", note,
            "<table class='grid'><tr>" + head + "</tr>", *rows, "</table>"]  # fmt: skip


def _distance_figures(raw_products: Mapping[str, Any], eval_dir: Path | None, u: Units) -> list[str]:
    """Per product with C2C distances: their histogram and, from its distance cloud, the colour-mapped views."""
    e = html.escape
    figs = []
    for name, raw in raw_products.items():
        c2c = (raw or {}).get("c2c")
        if not c2c:
            continue
        hist = c2c.get("histogram") or {}
        if hist.get("edges") and hist.get("counts"):
            title = f"{(c2c.get('method') or 'c2c').upper()} distances: {name}"
            figs.append(f"<figure>{svg_histogram(hist['edges'], hist['counts'], title, units=u)}</figure>")
        if eval_dir is not None:
            tag = _c2c_views_tag(eval_dir, name, c2c, u)
            if tag:
                caption = f"{e(name)}: distance to the reference, colour-mapped (viridis, 0 to P95, {e(u.value)})"
                figs.append(f"<figure style='max-width:900px'>{tag}<figcaption>{caption}</figcaption></figure>")
    return figs


def to_html(
    report: Mapping[str, Any],
    eval_dir: Path | None,
    metrics: Mapping[str, Any] | None,
    max_panels: int = DEFAULT_MAX_PANELS,
    run: RunNotes = RunNotes(),
) -> str:
    """A self-contained HTML page: tables, C2C plots and views, metric and stage bars, render panels (max_panels)."""
    e = html.escape
    u = _report_units(report)
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>hybridsplat report</title>",
        f"<style>{_CSS}</style></head><body>",
        "<h1>hybridsplat evaluation report</h1>",
        f"<p>Project <code>{e(report['project'])}</code> · generated {e(report['generated_utc'])} · "
        f"total pipeline time {_num(report['timings']['total_seconds'], 1)} s · lengths in {e(u.value)}</p>",
    ]
    title, header, rows, findings = _summary(report)
    raw_products: Mapping[str, Any] = (metrics or {}).get("products", {})
    per_view = _per_view(raw_products)
    if rows:
        parts.append(f"<h2>{e(title)}</h2>")
        parts += [f"<p>{e(line)}</p>" for line in findings]
        parts.append(_html_table(header, rows))
    if eval_dir is not None:
        parts += _picture_grid(per_view, eval_dir, max_panels)
    for title, header, rows in _tables(report, run):
        parts.append(f"<h2>{e(title)}</h2>")
        if not rows:
            parts.append("<p class='note'>none recorded</p>")
            continue
        parts.append(_html_table(header, rows))
    figs = _distance_figures(raw_products, eval_dir, u)
    if figs:
        parts += ["<h2>Distance distributions</h2>"] + figs
    metric_figs = []
    for key in ("psnr", "ssim", "lpips"):
        labels, series = _metric_series(per_view, key)
        if series:
            metric_figs.append(f"<figure>{metric_bars_svg(series, labels, IMAGE_LABELS[key])}</figure>")
    if metric_figs:
        parts += ["<h2>Image metrics per held-out view</h2>"] + metric_figs
    chosen = _panel_views(per_view, max_panels)
    panels = []
    for name, views in per_view.items():
        for v in views:
            panel = (v.get("files") or {}).get("panel")
            if panel and str(v["view"]) in chosen and eval_dir is not None:
                tag = _thumbnail_tag(eval_dir / panel, f"{name} {v['view']}")
                if tag:
                    panels.append(f"<figure style='max-width:1150px'>{tag}<figcaption>{e(name)} · {e(str(v['view']))}: "
                                  "render | photo | RMS colour error (0–0.25)</figcaption></figure>")  # fmt: skip
    if panels:
        parts += [f"<h2>Renders and error maps</h2><p class='note'>The {len(chosen)} held-out view(s) with the "
                  "lowest PSNR (downscaled).</p>"] + panels  # fmt: skip
    parts += accuracy_html(report.get("accuracy"), u, _html_table)
    parts += _sections_html(report)
    stages = report.get("stages") or {}
    if stages:
        names = list(stages)
        parts += [
            "<h2>Stage time and memory</h2>",
            stage_bars_svg(names, [stages[n].get("seconds") for n in names], [stages[n].get("peak_mb") for n in names]),
        ]
    parts.append("<h2>Versions</h2><ul>")
    parts += [f"<li>{e(k)}: {e(str(v))}</li>" for k, v in report["versions"].items()]
    parts.append("</ul>")
    if report.get("config"):
        parts.append("<h2>Configuration</h2><pre>" + e(json.dumps(report["config"], indent=2, default=str)) + "</pre>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(
    manifest_file: str | PathLike[str],
    metrics_file: str | PathLike[str],
    paths: ReportPaths,
    max_panels: int = DEFAULT_MAX_PANELS,
    units: Units | str | None = None,
    per_material_file: str | PathLike[str] | None = None,
    sections: Sequence[Mapping[str, Any]] = (),
    accuracy_file: str | PathLike[str] | None = None,
    notes: RunNotes = RunNotes(),
) -> ReportPaths:
    """Build and write the report's JSON, Markdown and HTML files (``paths``) atomically.

    sections: what the pipeline's stages show of themselves (``{"title", "lines", "figures": [[path, caption]]}``
    each, paths relative to the project), in pipeline order. notes: how the products were made (the training
    steps and renderer told beside their figures).

    Renders and plots referenced by the metrics lie next to ``metrics_file``. max_panels: render panels shown per
    product (the lowest-PSNR views). units: the unit lengths are printed in (default: as recorded in the metrics
    or the manifest, else metres).
    """
    metrics_file = Path(metrics_file)
    report = build_report(manifest_file, metrics_file, units, per_material_file, accuracy_file)
    report["sections"] = [dict(s) for s in sections]
    eval_dir = metrics_file.parent
    metrics = read_metrics(metrics_file) if metrics_file.is_file() else None
    strict = to_jsonable(json.loads(json.dumps(report, default=str)))  # NaN/inf -> null: report.json stays JSON
    with output_transaction():  # the three files appear together or not at all
        write_json_atomic(paths.json, strict)
        write_text_atomic(paths.markdown, to_markdown(report, notes))
        write_text_atomic(paths.html, to_html(report, eval_dir, metrics, max_panels, notes))
    return paths
