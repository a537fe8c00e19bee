"""Transparent and reflective regions: the union of early training snapshots, opacity raised to 1, for those regions.

Splats of glass, mirrors and shiny metal end up sparse and faint once training converges (the photos are explained by
what is seen through or in them), so a mesh from the final splats has holes there. Following the transparent-surface
study (union of the Gaussians of several early iterations of the same run, opacity set to 1, before surface
extraction), the snapshots are stacked and every snapshot Gaussian counts fully.

"For those regions only": a snapshot Gaussian is kept when the nearest Gaussian of the merged set is a trained splat
(``source`` = 2) — i.e. it lies where splats, not MVS, describe the scene — and that splat is within
``region_radius``. Collaborative (MVS) surfaces are therefore meshed from the merged set alone, and snapshot
Gaussians of the frozen MVS context, if a snapshot holds them, are dropped.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from core.errors import DataError
from core.gaussians import GaussianSet, logit
from fusion.convert import Source
from fusion.merge import subset
from fusion.mesh.options import SnapshotOptions  # noqa: F401 (re-exported)


@dataclass
class SnapshotStats:
    """Per snapshot, Gaussians read; then how many were kept in total, the radius used."""

    per_snapshot: list[int]
    dropped_faint: int
    dropped_outside: int
    kept: int
    region_radius: float


def snapshot_union(
    snapshots: Sequence[GaussianSet], merged: GaussianSet, options: SnapshotOptions | None = None
) -> tuple[GaussianSet, SnapshotStats]:
    """The snapshot Gaussians in the merged set's splat regions, in ``merged.origin``, opacity raised to 1.

    The result has a ``source`` field (all ``Source.SPLAT``) and may be empty (no splats in ``merged``, or no
    snapshot Gaussian in their regions). :class:`DataError` when ``merged`` has no ``source`` field.
    """
    options = options or SnapshotOptions()
    if "source" not in merged.fields:
        raise DataError(
            "the merged Gaussian set has no 'source' field (1 = MVS, 2 = splat): the splat regions are unknown; "
            "write merged.ply with extra fields"
        )
    counts = [len(s) for s in snapshots]
    is_splat = np.asarray(merged.fields["source"]) == Source.SPLAT
    parts = [s.with_origin(merged.origin) for s in snapshots if len(s)]
    if not parts or not is_splat.any():
        empty = subset(merged, np.zeros(len(merged), dtype=bool))
        return empty, SnapshotStats(counts, 0, sum(counts), 0, float(options.region_radius or 0.0))
    for i, p in enumerate(parts):
        p.validate(f"snapshot {i}")
    stacked = GaussianSet.concatenate(
        [GaussianSet(p.means, p.log_scales, p.quats, p.logit_opacities, p.sh_dc, p.sh_rest, p.origin) for p in parts]
    )
    faint = stacked.opacities < options.min_opacity
    radius = options.region_radius
    if radius is None:
        splats = merged.means[is_splat]
        if len(splats) > 1:
            d, _ = cKDTree(splats).query(splats, k=2)
            radius = 4.0 * float(np.median(d[:, 1]))
        radius = radius if radius and radius > 0 else float(np.max(merged.scales[is_splat]) * 3.0)
    d, nearest = cKDTree(merged.means).query(stacked.means, k=1)
    inside = is_splat[nearest] & (d <= radius)
    keep = inside & ~faint
    out = subset(stacked, keep)
    out.logit_opacities = np.full(len(out), logit(np.array([1.0]))[0], dtype=np.float32)  # α = 1 − 1e-7
    out.fields = {"source": np.full(len(out), Source.SPLAT, dtype=np.uint8)}
    stats = SnapshotStats(counts, int((faint & inside).sum()), int((~inside).sum()), len(out), float(radius))
    return out, stats
