"""The report's opening: which product is best and by how much (one table), and a picture per held-out view.

The summary compares the three products a surveyor chooses between — MVS only, the whole-scene 3DGS baseline and
the hybrid's merged product — on the survey's F-score at τ, the C2C mean, held-out PSNR over the whole image and
inside the non-collaborative masks, LPIPS and run time, and marks the best value of each column. A product's run
time is the sum of its stages' wall times after the shared SfM (:data:`PRODUCT_STAGES`), as the benchmarks count
it. The picture grid shows, per held-out view, the photo, each product's render and the merged product's error
map, cut from the panels the eval stage writes (:func:`eval.render_eval.side_by_side`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

PRODUCT_STAGES: dict[str, tuple[str, ...]] = {
    "mvs": ("mvs", "convert"),
    "baseline": ("baseline",),
    "mvs_filtered": ("mvs", "classify", "masks", "convert", "merge"),
    "merged_no_background": ("mvs", "classify", "masks", "convert", "train", "clean", "appearance", "merge"),
    "merged_unrefined": ("mvs", "classify", "masks", "convert", "train", "clean", "background", "merge"),
    "merged": ("mvs", "classify", "masks", "convert", "train", "clean", "background", "appearance", "merge"),
}
"""The stages whose wall times make a product's run time (after the shared SfM model; eval, report and mesh
excluded): MVS only = mvs + convert; the baseline = its training; the hybrid = every stage its product reads."""

SUMMARY_PRODUCTS: tuple[tuple[str, str], ...] = (
    ("mvs", "MVS only"),
    ("baseline", "whole-scene 3DGS (baseline)"),
    ("merged", "hybrid (merged)"),
)


@dataclass(frozen=True)
class SummaryColumn:
    """One column of the summary: its label, how to read it from a report product, and which way is better."""

    label: str
    read: Callable[[Mapping[str, Any]], float | None]
    higher_is_better: bool
    format: Callable[[float], str]


def _number(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and np.isfinite(v) else None


def _c2c(key: str) -> Callable[[Mapping[str, Any]], float | None]:
    return lambda p: _number((p.get("c2c") or {}).get(key))


def _image(part: str, key: str) -> Callable[[Mapping[str, Any]], float | None]:
    return lambda p: _number(((p.get("images") or {}).get(part) or {}).get(key))


def product_seconds(name: str, stages: Mapping[str, Any]) -> float | None:
    """Seconds of ``name``'s stages (:data:`PRODUCT_STAGES`) from the report's stage records; None when a stage it
    needs has no time (not run, or skipped)."""
    total = 0.0
    for stage in PRODUCT_STAGES.get(name, ()):
        seconds = _number((stages.get(stage) or {}).get("seconds"))
        if seconds is None:
            if (stages.get(stage) or {}).get("skipped"):
                continue  # a stage the scene does not need costs nothing
            return None
        total += seconds
    return total if PRODUCT_STAGES.get(name) else None


def summary_table(
    report: Mapping[str, Any], length: Callable[[float], str], unit: str
) -> tuple[str, list[str], list[list[str]], list[str]]:
    """(title, header, rows, findings) of the summary: one row per product of :data:`SUMMARY_PRODUCTS` that was
    measured at all, the best value of each column in ``**bold**``; ``findings`` says in words which product is best
    on the survey figure and on the picture, and by how much."""
    products: Mapping[str, Any] = report["products"]
    stages: Mapping[str, Any] = report.get("stages") or {}
    tau = next((_c2c("tau")(products[n]) for n, _ in SUMMARY_PRODUCTS if n in products), None)
    columns = (
        SummaryColumn("F-score at τ" + (f" = {length(tau)} {unit}" if tau else ""), _c2c("fscore"), True,
                      lambda v: f"{v:.3f}"),
        SummaryColumn(f"C2C mean ({unit})", _c2c("mean"), False, length),
        SummaryColumn("PSNR whole (dB)", _image("full", "psnr"), True, lambda v: f"{v:.2f}"),
        SummaryColumn("PSNR masked (dB)", _image("masked", "psnr"), True, lambda v: f"{v:.2f}"),
        SummaryColumn("LPIPS", _image("full", "lpips"), False, lambda v: f"{v:.3f}"),
    )  # fmt: skip
    rows_of: dict[str, list[float | None]] = {}
    for name, _ in SUMMARY_PRODUCTS:
        p = products.get(name)
        if p is None or p.get("skipped"):
            continue
        values = [c.read(p) for c in columns] + [product_seconds(name, stages)]
        if any(v is not None for v in values[:-1]):
            rows_of[name] = values
    better = [c.higher_is_better for c in columns] + [False]
    formats = [c.format for c in columns] + [lambda v: f"{v:.0f}"]
    best = []
    for j, higher in enumerate(better):
        present = [r[j] for r in rows_of.values() if r[j] is not None]
        best.append((max(present) if higher else min(present)) if len(present) > 1 else None)
    labels = dict(SUMMARY_PRODUCTS)
    rows = []
    for name, values in rows_of.items():
        cells = [labels[name]]
        for j, v in enumerate(values):
            text = "–" if v is None else formats[j](v)
            cells.append(f"**{text}**" if v is not None and best[j] is not None and v == best[j] else text)
        rows.append(cells)
    header = ["product"] + [c.label for c in columns] + ["run time (s)"]
    title = "Summary — which product is best (best value in bold; run time after the shared SfM)"
    return title, header, rows, _findings(rows_of, labels)


def _findings(rows_of: Mapping[str, list[float | None]], labels: Mapping[str, str]) -> list[str]:
    """Sentences: the best product on the survey F-score and on whole-image PSNR, with its margin over the next."""
    out = []
    for j, what, unit, digits in ((0, "survey F-score at τ", "", 3), (2, "whole-image PSNR", " dB", 2)):
        ranked = sorted(((v[j], n) for n, v in rows_of.items() if v[j] is not None), reverse=True)
        if len(ranked) >= 2:
            (v1, n1), (v2, n2) = ranked[0], ranked[1]
            out.append(f"Best {what}: {labels[n1]}, {v1:.{digits}f}{unit} ({v1 - v2:+.{digits}f}{unit} over "
                       f"{labels[n2]}).")  # fmt: skip
    return out


def split_panel(panel: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The render, the photo and the error map of a panel of :func:`eval.render_eval.side_by_side` ((H, 3W + 8, 3):
    three images of width W separated by 4-pixel gaps)."""
    w = (panel.shape[1] - 8) // 3
    if panel.ndim != 3 or w <= 0 or 3 * w + 8 != panel.shape[1]:
        raise ValueError(f"not a render | photo | error panel: shape {panel.shape}")
    return panel[:, :w], panel[:, w + 4 : 2 * w + 4], panel[:, 2 * w + 8 :]
