"""Scores per ground-truth material: where MVS fails and what the splats recover (the paper's tables, per material).

Geometry, against a reference cloud with a per-point material label (a data_synth LiDAR cloud's ``material``):

- accuracy: the mean distance from each product point to the nearest reference point, grouped by that reference
  point's material (the product point "belongs" to the material it lies on);
- precision at τ: the share of the product points on a material (as for accuracy) within τ of the reference;
- completeness (recall) at τ: the share of the reference points of a material that have a product point within τ;
- F-score at τ: the harmonic mean of the two (Tanks and Temples, ETH3D), 0 when both are 0.

Images: PSNR over the held-out pixels of each material (from per-pixel material label images), the squared error
summed over every view first, so that a material seen in few pixels of many views is weighed by its pixels.
Distances in metres, world coordinates in float64 (differences taken about the reference's first point).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from eval.image_metrics import psnr_from_mse, to_float_image


@dataclass(frozen=True)
class MaterialGeometry:
    """Geometry scores of one product on one material (metres; None where nothing was measured)."""

    accuracy_mean: float | None
    accuracy_points: int
    completeness: float | None
    reference_points: int
    precision: float | None = None
    fscore: float | None = None

    @classmethod
    def of(cls, distances: np.ndarray, completeness: float, reference_points: int, tau: float) -> MaterialGeometry:
        """The scores of one material from the distances (metres) of the product points on it to the reference, its
        completeness at ``tau`` and its reference point count."""
        d = np.asarray(distances, np.float64)
        precision = float((d <= tau).mean()) if len(d) else None
        return cls(
            accuracy_mean=float(d.mean()) if len(d) else None,
            accuracy_points=int(len(d)),
            completeness=completeness,
            reference_points=int(reference_points),
            precision=precision,
            fscore=_fscore(precision or 0.0, completeness),
        )


@dataclass(frozen=True)
class MaterialImage:
    """PSNR (dB) over the held-out pixels of one material, and how many pixels that was."""

    psnr: float | None
    pixels: int


def geometry_per_material(
    compared_world: np.ndarray, reference_world: np.ndarray, reference_material: np.ndarray, tau: float
) -> dict[int, MaterialGeometry]:
    """Accuracy, precision, completeness and F-score at ``tau`` per material id of the reference.

    compared_world: (N, 3) float64 world coordinates of the product's points; reference_world: (M, 3) float64;
    reference_material: (M,) integer material id per reference point; tau: metres (> 0).
    """
    from scipy.spatial import cKDTree

    ref = np.asarray(reference_world, np.float64)
    materials = np.asarray(reference_material).astype(np.int64).reshape(-1)
    cmp_ = np.asarray(compared_world, np.float64).reshape(-1, 3)
    if len(ref) == 0:
        return {}
    anchor = ref[0]
    ref_local = ref - anchor
    out: dict[int, MaterialGeometry] = {}
    if len(cmp_):
        cmp_local = cmp_ - anchor
        d_acc, nearest = cKDTree(ref_local).query(cmp_local, k=1, workers=-1)
        d_cmp, _ = cKDTree(cmp_local).query(ref_local, k=1, workers=-1)
        owner = materials[nearest]
    else:
        d_acc, owner = np.zeros(0), np.zeros(0, np.int64)
        d_cmp = np.full(len(ref), np.inf)
    for m in np.unique(materials):
        of_m = materials == m
        completeness = float((d_cmp[of_m] <= tau).mean())
        out[int(m)] = MaterialGeometry.of(d_acc[owner == m], completeness, int(of_m.sum()), tau)
    return out


def _fscore(precision: float, recall: float) -> float:
    return 2.0 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0


def psnr_per_material(pairs: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> dict[int, MaterialImage]:
    """PSNR per material over all views: ``pairs`` yields (rendered, photo, labels) with labels (H, W) integers.

    Images are uint8 or float in [0, 1], (H, W, 3); the squared error is averaged over the pixels and channels of
    each material across every view, then turned into PSNR (peak 1.0; clamped, never inf).
    """
    sums: dict[int, float] = {}
    counts: dict[int, int] = {}
    for rendered, photo, labels in pairs:
        a, b = to_float_image(rendered), to_float_image(photo)
        err = ((a - b) ** 2).mean(axis=-1).astype(np.float64)
        lab = np.asarray(labels).astype(np.int64)
        ids, inverse = np.unique(lab.reshape(-1), return_inverse=True)
        per_id = np.bincount(inverse, weights=err.reshape(-1), minlength=len(ids))
        n_id = np.bincount(inverse, minlength=len(ids))
        for m, s, n in zip(ids.tolist(), per_id.tolist(), n_id.tolist(), strict=True):
            sums[m] = sums.get(m, 0.0) + s
            counts[m] = counts.get(m, 0) + n
    return {m: MaterialImage(psnr_from_mse(sums[m] / counts[m]), counts[m]) for m in sorted(sums) if counts[m]}


def as_table(
    geometry: Mapping[int, MaterialGeometry], images: Mapping[int, MaterialImage], names: Mapping[int, str]
) -> dict[str, dict[str, float | int | None]]:
    """One JSON-ready row per material name: accuracy, completeness, PSNR and their counts.

    Ids without a name (e.g. the background label of the label images) are left out.
    """
    rows: dict[str, dict[str, float | int | None]] = {}
    for m in sorted((set(geometry) | set(images)) & set(names)):
        g, i = geometry.get(m), images.get(m)
        rows[names[m]] = {
            "material_id": m,
            "accuracy_mean_m": g.accuracy_mean if g else None,
            "accuracy_points": g.accuracy_points if g else 0,
            "completeness": g.completeness if g else None,
            "reference_points": g.reference_points if g else 0,
            "precision": g.precision if g else None,
            "fscore": g.fscore if g else None,
            "psnr": i.psnr if i else None,
            "pixels": i.pixels if i else 0,
        }
    return rows
