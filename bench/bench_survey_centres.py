"""What the fill's splat centres add to the survey point product: its F-score at τ with and without them (issue 54).

``python bench/bench_survey_centres.py PROJECT [PROJECT ...]`` (finished projects whose eval stage ran, e.g. the
``shipped`` projects of ``bench/bench_regret.py``)

The survey point product (export/merged_points.ply) holds the trusted MVS points (``source`` = 1) and the splat
centres that pass :func:`fusion.clean.select_survey_points` (``source`` = 2), which carry no σ. From the eval
stage's per-point distances (eval/c2c_merged.ply, field ``c2c``) and its reference cloud, this recomputes the
precision / recall / F-score at the eval stage's τ for the product as it is (checked against the eval stage's own
figures, which it must reproduce) and for the product without its splat centres, and the share of the centres
within τ. No pipeline stage runs again.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from plyfile import PlyData
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from core.io import read_point_cloud  # noqa: E402
from fusion.convert_options import Source  # noqa: E402
from hybridsplat.layout import ProjectLayout  # noqa: E402


def threshold_scores(distances: np.ndarray, positions: np.ndarray, reference: np.ndarray, tau: float) -> list[float]:
    """[precision, recall, F] at ``tau`` metres: ``distances`` (N,) of the product's points to the reference,
    ``positions`` (N, 3) and ``reference`` (M, 3) metres in one local frame (float64)."""
    precision = float(np.count_nonzero(distances < tau) / max(len(distances), 1))
    back, _ = cKDTree(positions).query(reference, distance_upper_bound=tau)
    recall = float(np.count_nonzero(back < tau) / max(len(reference), 1))
    total = precision + recall
    return [precision, recall, 2 * precision * recall / total if total > 0 else 0.0]


def centre_scores(project: Path) -> dict[str, Any]:
    layout = ProjectLayout(project)
    c2c = json.loads(layout.metrics_json.read_text())["products"]["merged"]["c2c"]
    tau = float(c2c["tau"])
    reference = read_point_cloud(c2c["reference"])
    ref = np.asarray(reference.positions, np.float64) + np.asarray(reference.origin, np.float64)
    vertex = PlyData.read(project / "eval" / "c2c_merged.ply")["vertex"]
    positions = np.stack([np.asarray(vertex[c], np.float64) for c in "xyz"], axis=1)
    distances = np.asarray(vertex["c2c"], np.float64)
    centres = np.asarray(vertex["source"]) == Source.SPLAT
    kept = ~centres
    anchor = ref[0].copy()  # a local origin for the k-d tree (georeferenced coordinates are large)
    ref, positions = ref - anchor, positions - anchor
    return {
        "tau_m": tau,
        "eval": [c2c["precision"], c2c["recall"], c2c["fscore"]],
        "with_centres": threshold_scores(distances, positions, ref, tau),
        "without_centres": threshold_scores(distances[kept], positions[kept], ref, tau),
        "centres": int(centres.sum()),
        "points": len(distances),
        "centres_within_tau": float(np.mean(distances[centres] < tau)) if centres.any() else None,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("projects", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, default=None, help="also write the figures as JSON here")
    args = parser.parse_args()
    results = {}
    print("| project | P / R / F (eval) | P / R / F without the centres | ΔF | centres | within τ |")
    print("|---|---|---|---:|---:|---:|")
    for project in args.projects:
        s = centre_scores(project)
        with_, without = s["with_centres"], s["without_centres"]
        if not np.allclose(with_, s["eval"], atol=1e-9):
            raise SystemExit(f"{project}: recomputed {with_} differs from the eval stage's {s['eval']}")
        results[str(project)] = s
        within = "–" if s["centres_within_tau"] is None else f"{s['centres_within_tau']:.3f}"
        cells = [" / ".join(f"{v:.4f}" for v in with_), " / ".join(f"{v:.4f}" for v in without)]
        print(f"| {project.parent.name}/{project.name} | {cells[0]} | {cells[1]} | {without[2] - with_[2]:+.4f} "
              f"| {s['centres']} | {within} |")  # fmt: skip
    if args.out is not None:
        args.out.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
