"""Source-view selection and depth ranges for MVS, from a sparse model's points and tracks.

Score of source j for reference i: sum over the 3D points both see of a triangulation-angle weight
(MVSNet/COLMAP style: angles below ``min_angle_deg`` count little, around ``best_angle_deg`` most), times a
penalty for very different viewing distances (resolution mismatch). Depth range of view i: robust
percentiles of the z-depths of the sparse points it observes, widened by a margin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import ReconstructionError


@dataclass(frozen=True)
class ViewSelection:
    """Per reference image id: ordered source image ids and the z-depth range (metres, camera frame)."""

    sources: dict[int, list[int]]
    depth_range: dict[int, tuple[float, float]]
    scores: dict[int, list[float]]


def select_views(
    rec,  # pycolmap.Reconstruction
    num_sources: int = 5,
    min_angle_deg: float = 2.0,
    best_angle_deg: float = 10.0,
    depth_margin: float = 0.15,
    exclude: frozenset[int] = frozenset(),
) -> ViewSelection:
    """Choose up to ``num_sources`` source views per registered image and its depth range.

    Images in ``exclude`` (image ids, e.g. held-out photos) are neither given sources nor used as one.

    Raises :class:`ReconstructionError` when the model has no 3D points (fusion and depth ranges need them).
    """
    image_ids = sorted(int(i) for i in rec.reg_image_ids() if int(i) not in exclude)
    if rec.num_points3D() == 0:
        raise ReconstructionError("the sparse model has no 3D points: triangulate first (hybridsplat sfm)")
    index = {iid: k for k, iid in enumerate(image_ids)}
    centers = np.stack([np.asarray(rec.image(i).projection_center()) for i in image_ids])
    n = len(image_ids)
    score = np.zeros((n, n))
    depths: list[list[float]] = [[] for _ in range(n)]
    poses = [np.asarray(rec.image(i).cam_from_world().matrix()) for i in image_ids]
    sigma_lo = max(min_angle_deg, 1e-3)
    for p in rec.points3D.values():
        ids = [index[int(el.image_id)] for el in p.track.elements if int(el.image_id) in index]
        ids = sorted(set(ids))
        if len(ids) < 2:
            continue
        xyz = np.asarray(p.xyz, dtype=np.float64)
        rays = xyz[None] - centers[ids]
        dist = np.linalg.norm(rays, axis=1)
        rays /= np.maximum(dist[:, None], 1e-12)
        cos = np.clip(rays @ rays.T, -1.0, 1.0)
        ang = np.degrees(np.arccos(cos))
        w = np.where(ang <= best_angle_deg, np.exp(-((ang - best_angle_deg) ** 2) / (2 * sigma_lo**2)), 1.0)
        w = np.where(ang < min_angle_deg * 0.5, 0.0, w)
        ratio = np.minimum(dist[:, None], dist[None]) / np.maximum(np.maximum(dist[:, None], dist[None]), 1e-12)
        w = w * np.clip(ratio / 0.5, 0.0, 1.0)  # distances differing by > 2x count less
        score[np.ix_(ids, ids)] += w
        for k in ids:
            z = poses[k][2, :3] @ xyz + poses[k][2, 3]
            if z > 0:
                depths[k].append(float(z))
    np.fill_diagonal(score, 0.0)
    sources: dict[int, list[int]] = {}
    scores: dict[int, list[float]] = {}
    ranges: dict[int, tuple[float, float]] = {}
    for k, iid in enumerate(image_ids):
        order = [j for j in np.argsort(-score[k], kind="stable") if score[k, j] > 0][:num_sources]
        sources[iid] = [image_ids[j] for j in order]
        scores[iid] = [float(score[k, j]) for j in order]
        if len(depths[k]) >= 3:
            d = np.asarray(depths[k])
            lo, hi = np.percentile(d, 1), np.percentile(d, 99)
            ranges[iid] = (float(lo * (1 - depth_margin)), float(hi * (1 + depth_margin)))
    if ranges:  # views without enough points borrow the global range
        glo = min(r[0] for r in ranges.values())
        ghi = max(r[1] for r in ranges.values())
        for iid in image_ids:
            ranges.setdefault(iid, (glo, ghi))
    return ViewSelection(sources, ranges, scores)
