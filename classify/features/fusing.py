"""The fusing views of each point, chunk by chunk: the sampling loop the view-based feature groups share.

:mod:`classify.features.fusion_evidence`, :mod:`classify.features.view_dependent` and
:mod:`classify.features.image_boundaries` all look at a point in the photos (and depth maps) of the views that
fused it. This module walks the points in chunks (outer) and the views of the dense reconstruction (inner, the
same photos :class:`~classify.features.multiview.ViewData` exposes: held-out photos never take part) and hands each
group, per view, the chunk's points that view fused with their pixels, depths and viewing rays. Pixels follow
COLMAP's convention (the centre of pixel (c, r) is at (c + 0.5, r + 0.5)); ``sample_nearest`` reads pixel
``floor(col), floor(row)`` like the multi-view group.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from classify.features.multiview import ViewData, fused_by_view, sample_nearest
from core.cameras import Camera, View
from core.errors import DataError

__all__ = ["FusingSamples", "fusing_chunks", "sample_nearest", "segment_bounds", "to_camera"]

sample_nearest = sample_nearest


@dataclass(frozen=True)
class FusingSamples:
    """One view's samples of one chunk of M points (S of them fused by the view, inside its image, z > 0).

    idx: (S,) int64 chunk-local indices of those points. col / row: (S,) float64 camera pixels of their projections.
    cam_pts: (S, 3) float64 the points in the view's camera frame (metres; z = ``cam_pts[:, 2]`` > 0).
    ray: (S, 3) float64 unit viewing rays, camera centre → point (local frame)."""

    view: View
    camera: Camera
    idx: np.ndarray
    col: np.ndarray
    row: np.ndarray
    cam_pts: np.ndarray
    ray: np.ndarray

    @property
    def z(self) -> np.ndarray:
        """(S,) float64 z-depths (metres) of the samples."""
        return self.cam_pts[:, 2]

    def sample(self, image: np.ndarray) -> np.ndarray:
        """(S, ...) values of ``image`` (H, W[, C]: a photo, depth map or per-view feature map covering the camera's
        image at any resolution proportional to it) at the nearest pixel of each sample's projection."""
        sx, sy = image.shape[1] / self.camera.width, image.shape[0] / self.camera.height
        return sample_nearest(image, self.col * sx, self.row * sy)


def fusing_chunks(
    positions: np.ndarray,
    visibility: list[np.ndarray] | None,
    views: ViewData,
    chunk_size: int,
    tolerance: float,
) -> Iterator[tuple[slice, Iterator[FusingSamples]]]:
    """Per chunk of points (N, 3) float64 (the cameras' local frame): its slice and an iterator over the views'
    :class:`FusingSamples` (views that fused none of the chunk's points are skipped; consume it before the next chunk).

    visibility: per point, the image ids that fused it (``PointCloud.visibility``); None treats every view whose
    frustum holds the point and whose depth map agrees with it (|d − z| / z ≤ ``tolerance``; every frustum view
    when the view has no depth map) as fusing, as :func:`~classify.features.multiview.multiview_features` does.
    """
    pts = np.asarray(positions, dtype=np.float64)
    n = len(pts)
    if visibility is not None and len(visibility) != n:
        raise DataError(f"visibility lists {len(visibility)} points, the cloud has {n}")
    view_list = list(views.cameras)
    if not view_list:
        raise DataError("view-based features need at least one registered view")
    if visibility is not None:
        counts = np.fromiter((len(v) for v in visibility), dtype=np.int64, count=n)
        flat_ids = np.concatenate(visibility).astype(np.int64) if n and counts.sum() else np.zeros(0, np.int64)
        flat_pts = np.repeat(np.arange(n), counts)
    for start in range(0, n, max(1, chunk_size)):
        stop = min(n, start + max(1, chunk_size))
        fused_of = None if visibility is None else fused_by_view(flat_ids, flat_pts, start, stop, view_list)
        yield slice(start, stop), _view_samples(pts[start:stop], views, view_list, fused_of, tolerance)


def _view_samples(
    p: np.ndarray,
    views: ViewData,
    view_list: list[View],
    fused_of: dict[int, np.ndarray] | None,
    tolerance: float,
) -> Iterator[FusingSamples]:
    for v in view_list:
        s = _samples_of_view(p, views, v, None if fused_of is None else fused_of[v.image_id], tolerance)
        if s is not None:
            yield s


def _samples_of_view(
    p: np.ndarray, views: ViewData, v: View, fused: np.ndarray | None, tolerance: float
) -> FusingSamples | None:
    """The samples of view ``v`` for the chunk's points ``p`` (M, 3); ``fused``: chunk-local indices of the points
    the view fused (None: decide from the depth map)."""
    cam = views.cameras.camera_of(v)
    if fused is not None:
        if len(fused) == 0:
            return None
        cand = np.asarray(fused, dtype=np.int64)
    else:
        cand = np.arange(len(p), dtype=np.int64)
    q = to_camera(v, p[cand])
    z = q[:, 2]
    front = z > 0
    uv = np.full((len(cand), 2), -1.0)
    uv[front] = cam.project(q[front])
    col, row = uv[:, 0], uv[:, 1]
    keep = front & (col >= 0) & (row >= 0) & (col < cam.width) & (row < cam.height)
    if fused is None:
        depth = views.depth(v.name)
        if depth is not None:
            sx, sy = depth.shape[1] / cam.width, depth.shape[0] / cam.height
            d = np.zeros(len(cand))
            d[keep] = sample_nearest(depth, col[keep] * sx, row[keep] * sy)
            keep &= (d > 0) & (np.abs(d - z) <= tolerance * np.where(z > 0, z, 1.0))
    if not keep.any():
        return None
    idx, q = cand[keep], q[keep]
    ray = p[idx] - v.center
    ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-300)
    return FusingSamples(v, cam, idx, col[keep], row[keep], q, ray)


def to_camera(view: View, points: np.ndarray) -> np.ndarray:
    """``view.world_to_camera`` for (S, 3) float64 points, as three column updates: a (S, 3) @ (3, 3) product goes
    through BLAS, several times slower for this shape (and slower still on a loaded machine)."""
    r, t = view.rotation, view.translation
    out = np.empty_like(points, dtype=np.float64)
    for a in range(3):
        out[:, a] = points[:, 0] * r[a, 0] + points[:, 1] * r[a, 1] + points[:, 2] * r[a, 2] + t[a]
    return out


def segment_bounds(owner: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """For entries sorted by ``owner`` (E,) int64 in [0, m): per owner the count (m,) int64 and the first entry's
    index (m,) int64."""
    counts = np.bincount(owner, minlength=m).astype(np.int64)
    starts = np.zeros(m, dtype=np.int64)
    np.cumsum(counts[:-1], out=starts[1:])
    return counts, starts
