"""Splat-surface points: survey points from the rendered depth of trained splats, kept where the views agree.

A 3D Gaussian's centre is not a surface sample; the surface the splats *render* is (issue 31). Per training view,
:func:`splat_surface_points` renders the given splats (the trained fill layer) with their geometry
(``fusion.render.render(..., render_geometry=True)``, ``cpu`` backend) and takes the plane depth (PGSR; or the
median depth) inside the view's region mask. A pixel's 3D point is kept when

- the rendered depth is valid there (alpha ≥ 0.5 and the blended plane faces the ray, or a median Gaussian);
- it is not a virtual image: with a *front surface* depth map for a view (the surface estimate of a mirror or a
  glass pane: an MVS depth map, the z-buffer of trusted MVS points (:func:`front_depths_from_points`) or a fitted
  plane; 0 = unknown), a depth more than ``front_margin`` (relative) behind it is the reflection or refraction
  placed behind the surface and is rejected, in the reference view and in every agreeing view;
- at least ``min_agreeing`` *other* views agree, by the forward–backward reprojection test of MVS's geometric
  consistency (:func:`recon.mvs_cpu.geometric_filter`): the point projected into view j (inside j's mask, j's
  depth valid at the pixel it lands on), j's depth there back-projected and projected back into the reference
  view lands within ``max_reproj_px`` of the pixel's centre, at a depth within ``max_rel_depth`` (relative) of the
  reference depth. Written again here rather than called: that filter works on COLMAP's dense pixel convention
  (ray through (col, row)), float32 and returns only the mean depth; here pixel centres are at +0.5 (the
  renderer's convention), everything is float64, and the agreeing estimates are needed for σ.

Fusion (as COLMAP's stereo fusion consumes pixels): views are taken in order as references; a reference pixel
whose point is kept marks the agreeing pixels of the other views as used, so the same surface patch is not
emitted once per view. A kept point is the reference point moved along its rendered normal n by the mean of the
signed normal offsets δ_j = n · (X_j − X_ref) of the agreeing estimates (δ_ref = 0): offsets along the surface
(the other views sample it at their own pixel centres) do not count as disagreement. The sample standard
deviation of those m offsets (m = 1 + agreeing views), floored at ``sigma_floor_px`` pixel footprints (depth /
focal length) of the reference view, is its *spread*; the spread misses the bias that every view shares (they all
render the same fill layer: ±2σ of the spread held far fewer than 95 % of the true errors on the demo,
docs/experiments/2026-11-27-splat-surface.md), so its σ
(metres) is the spread widened by :func:`sigma_model` (footprint, local roughness, disagreement with the MVS
surface along the normal); confidence = agreeing views / the other views in which the point
lands on a valid rendered depth inside the mask (∈ (0, 1]).

Frames: positions in the cameras' local frame (``cameras.origin``), float64; splats of any origin; renders in a
frame centred on each camera (the float64 shift of :func:`fusion.render.render_gaussian_set`). Not yet used by
the pipeline by default: the merge stage's ``splat_surface`` option puts them into the survey point product
(:func:`fusion.survey.with_splat_surface`) as :func:`as_point_set` makes them, ``source`` = 4
(``Source.SPLAT_SURFACE``), ``classification`` = :data:`fusion.convert_options.SPLAT_SURFACE_CLASS`, ``sigma``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from typing import ClassVar

import numpy as np

from core.cameras import Camera, Cameras, View
from core.constraints import Choice, Constrained, Constraints, Interval
from core.errors import DataError
from core.gaussians import GaussianSet

SIGMA_FOOTPRINT = 1.5
"""σ model: weight of the reference view's pixel footprint (z / f) — see :func:`sigma_model`. The three weights
were chosen on the demo preset at seed 12 (a scene no figure is scored on): the smallest median σ on a grid
(footprint, roughness 0–8, anchor 0–3) whose ±1.96σ holds ≥ 95 % of the points' true distances to the GT mesh,
at ``splat_surface_support`` = 2 (docs/experiments/2026-11-27-splat-surface.md, "seed 12 choice, seed 0 score")."""
SIGMA_ROUGHNESS = 0.5
"""σ model: weight of the RMS normal offset of the nearest fused surface points."""
SIGMA_ANCHOR = 2.0
"""σ model: weight of the median normal offset of the nearest anchor (fused MVS) points."""


class SurfaceDepth(str, Enum):
    """The rendered depth a point is taken from: the ray–plane depth of the blended flat splats, or the median
    Gaussian's depth (:class:`fusion.render.types.RenderGeometry`)."""

    PLANE = "plane"
    MEDIAN = "median"


@dataclass(frozen=True)
class SplatSurfaceOptions(Constrained):
    """Options of :func:`splat_surface_points` (see the module docstring).

    depth: :class:`SurfaceDepth`. min_agreeing: other views that must agree (k ≥ 1). max_reproj_px: forward–backward
    reprojection error (px). max_rel_depth: relative depth difference of the round trip. front_margin: relative
    depth behind the front surface beyond which a point is a virtual image. sigma_floor_px: smallest spread in pixel
    footprints of the reference view (the rendered depth is one sample per pixel). sigma_footprint,
    sigma_roughness, sigma_anchor, sigma_neighbours: the σ model (:func:`sigma_model`): weights of the pixel
    footprint, of the local roughness among the fused points and of the disagreement with the anchor (MVS)
    surface along the normal, over ``sigma_neighbours`` nearest points each.
    """

    depth: SurfaceDepth = SurfaceDepth.PLANE
    min_agreeing: int = 2
    max_reproj_px: float = 1.0
    max_rel_depth: float = 0.01
    front_margin: float = 0.01
    sigma_floor_px: float = 0.1
    sigma_footprint: float = SIGMA_FOOTPRINT
    sigma_roughness: float = SIGMA_ROUGHNESS
    sigma_anchor: float = SIGMA_ANCHOR
    sigma_neighbours: int = 8

    constraints: ClassVar[Constraints] = {
        "depth": Choice(SurfaceDepth),
        "min_agreeing": Interval(int, 1, None),
        "max_reproj_px": Interval(float, 0, math.inf, closed="right"),
        "max_rel_depth": Interval(float, 0, math.inf, closed="right"),
        "front_margin": Interval(float, 0, math.inf),
        "sigma_floor_px": Interval(float, 0, math.inf),
        "sigma_footprint": Interval(float, 0, math.inf),
        "sigma_roughness": Interval(float, 0, math.inf),
        "sigma_anchor": Interval(float, 0, math.inf),
        "sigma_neighbours": Interval(int, 1, None),
    }


@dataclass(frozen=True)
class SplatSurfacePoints:
    """Fused splat-surface points (N of them).

    positions: (N, 3) float64 metres, cameras' local frame. normals: (N, 3) float64 unit, the rendered normal,
    facing the reference camera. colours: (N, 3) float32 rendered colour in [0, 1]. sigma: (N,) float64 metres,
    the point's σ (:func:`sigma_model`). confidence: (N,) float64 in (0, 1]. n_views: (N,) int32 views that agree,
    the reference included (≥ 1 + min_agreeing). reference: (N,) int32 index (among the masked views, in
    ``cameras`` order) of the view the point was taken from. counts: pixels per outcome (``candidates``: mask
    pixels with a valid depth; ``virtual``; ``inconsistent``: fewer than k views agree; ``used``: already fused
    from an earlier view; ``kept``). spread: (N,) float64 metres, the spread of the agreeing views along the normal
    (floored at ``sigma_floor_px`` footprints). footprint: (N,) float64 metres, the reference view's pixel
    footprint at the point (z / f).
    """

    positions: np.ndarray
    normals: np.ndarray
    colours: np.ndarray
    sigma: np.ndarray
    confidence: np.ndarray
    n_views: np.ndarray
    reference: np.ndarray
    counts: dict[str, int] = field(default_factory=dict)
    spread: np.ndarray = field(default_factory=lambda: np.zeros(0))
    footprint: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __len__(self) -> int:
        return int(self.positions.shape[0])


@dataclass(frozen=True)
class _ViewSurface:
    """One view's rendered surface: depth (H, W) float64 z (0 where invalid or outside the mask), normal (H, W, 3)
    float64 unit in the local frame, colour (H, W, 3) float32, front (H, W) float64 (0 = unknown); the camera's K,
    rotation R (world → camera) and centre c (local frame)."""

    depth: np.ndarray
    normal: np.ndarray
    colour: np.ndarray
    front: np.ndarray
    K: np.ndarray
    R: np.ndarray
    c: np.ndarray

    def points(self, rows: np.ndarray, cols: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """(n, 3) local-frame points of pixels (rows, cols) at z-depths ``depth`` (pixel centres at +0.5)."""
        K = self.K
        cam = np.stack([(cols + 0.5 - K[0, 2]) / K[0, 0], (rows + 0.5 - K[1, 2]) / K[1, 1], np.ones(len(rows))], 1)
        return self.c + (cam * depth[:, None]) @ self.R

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(u, v, z) of local-frame points (n, 3): pixel coordinates (centres at +0.5) and camera z."""
        cam = (points - self.c) @ self.R.T
        z = cam[:, 2]
        zs = np.where(z > 1e-9, z, 1.0)
        return self.K[0, 0] * cam[:, 0] / zs + self.K[0, 2], self.K[1, 1] * cam[:, 1] / zs + self.K[1, 2], z


def _render_surface(
    splats: GaussianSet, camera: Camera, view: View, origin: np.ndarray, mask: np.ndarray,
    front: np.ndarray | None, kind: SurfaceDepth,
) -> _ViewSurface:  # fmt: skip
    """Render ``splats`` into ``view`` with geometry (camera-centred frame, float64 shift) → :class:`_ViewSurface`."""
    import torch

    from fusion.render import render

    R, centre = view.rotation, view.center
    means = splats.means + (splats.origin - origin) - centre
    viewmat = np.eye(4)
    viewmat[:3, :3] = R
    with torch.no_grad():
        res = render(
            torch.from_numpy(means.astype(np.float32)), torch.from_numpy(splats.quats.astype(np.float32)),
            torch.from_numpy(splats.log_scales.astype(np.float32)),
            torch.from_numpy(splats.logit_opacities.astype(np.float32)),
            torch.from_numpy(np.ascontiguousarray(splats.sh_coeffs, np.float32)),
            torch.from_numpy(viewmat.astype(np.float32)), torch.from_numpy(camera.K().astype(np.float32)),
            camera.width, camera.height, backend="cpu", render_geometry=True,
        )  # fmt: skip
    geo = res.geometry
    if kind == SurfaceDepth.MEDIAN:
        depth, valid = geo.median_depth.numpy().astype(np.float64), geo.median_valid.numpy()
    else:
        depth, valid = geo.plane_depth.numpy().astype(np.float64), geo.plane_valid.numpy()
    n_cam = geo.normal.numpy().astype(np.float64)
    norm = np.linalg.norm(n_cam, axis=-1)
    valid = valid & mask & (depth > 0) & (norm > 1e-6) & np.isfinite(depth)
    normal = np.where(valid[..., None], n_cam / np.maximum(norm, 1e-12)[..., None], 0.0) @ R  # camera → local: Rᵀ n
    front_map = np.zeros(depth.shape) if front is None else np.asarray(front, np.float64)
    colour = res.colour.numpy().astype(np.float32)
    return _ViewSurface(np.where(valid, depth, 0.0), normal, colour, front_map, camera.K().astype(np.float64), R,
                        centre)  # fmt: skip


def _behind_front(surface: _ViewSurface, rows: np.ndarray, cols: np.ndarray, margin: float) -> np.ndarray:
    """(n,) bool: the rendered depth at (rows, cols) lies more than ``margin`` (relative) behind the front surface."""
    front = surface.front[rows, cols]
    return (front > 0) & (surface.depth[rows, cols] > front * (1.0 + margin))


@dataclass
class _Agreement:
    """Per candidate pixel of a reference view: agreeing views, views seen, Σδ and Σδ² of the normal offsets, a
    virtual flag from the other views, and per other view the pixel each candidate landed on (−1 = none agreed)."""

    count: np.ndarray
    seen: np.ndarray
    s1: np.ndarray
    s2: np.ndarray
    virtual: np.ndarray
    hits: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]


def _agreement(ref: int, rows: np.ndarray, cols: np.ndarray, surfaces: list[_ViewSurface],
               options: SplatSurfaceOptions) -> _Agreement:  # fmt: skip
    """The forward–backward test of reference view ``ref``'s pixels (rows, cols) against every other view."""
    s = surfaces[ref]
    d = s.depth[rows, cols]
    X = s.points(rows, cols, d)
    n = s.normal[rows, cols]
    m = len(rows)
    out = _Agreement(np.zeros(m, np.int32), np.zeros(m, np.int32), np.zeros(m), np.zeros(m), np.zeros(m, bool), {})
    for j, o in enumerate(surfaces):
        if j == ref:
            continue
        u, v, z = o.project(X)
        h, w = o.depth.shape
        inside = (z > 1e-9) & (u >= 0) & (v >= 0) & (u < w) & (v < h)
        cj = np.where(inside, np.floor(u), 0).astype(np.int64).clip(0, w - 1)
        rj = np.where(inside, np.floor(v), 0).astype(np.int64).clip(0, h - 1)
        dj = np.where(inside, o.depth[rj, cj], 0.0)
        seen = dj > 0
        Xj = o.points(rj, cj, np.where(seen, dj, 1.0))
        ub, vb, zb = s.project(Xj)
        err = np.hypot(ub - (cols + 0.5), vb - (rows + 0.5))
        agree = seen & (zb > 0) & (err <= options.max_reproj_px) & (np.abs(zb - d) <= options.max_rel_depth * d)
        delta = np.where(agree, ((Xj - X) * n).sum(axis=1), 0.0)
        out.count += agree
        out.seen += seen
        out.s1 += delta
        out.s2 += delta * delta
        out.virtual |= agree & _behind_front(o, rj, cj, options.front_margin)
        out.hits[j] = (agree, rj, cj)
    return out


def _fuse_view(
    ref: int, surfaces: list[_ViewSurface], used: list[np.ndarray], options: SplatSurfaceOptions,
    counts: dict[str, int],
) -> tuple[np.ndarray, ...] | None:  # fmt: skip
    """The kept points of reference view ``ref`` (positions, normals, colours, spread, confidence, n_views,
    footprint), marking the pixels they consumed in ``used``; None when none is kept."""
    s = surfaces[ref]
    rows, cols = np.nonzero(s.depth > 0)
    counts["candidates"] += len(rows)
    fresh = ~used[ref][rows, cols]
    counts["used"] += int((~fresh).sum())
    rows, cols = rows[fresh], cols[fresh]
    virtual = _behind_front(s, rows, cols, options.front_margin)
    ag = _agreement(ref, rows, cols, surfaces, options)
    virtual |= ag.virtual
    counts["virtual"] += int(virtual.sum())
    keep = ~virtual & (ag.count >= options.min_agreeing)
    counts["inconsistent"] += int((~virtual & ~keep).sum())
    counts["kept"] += int(keep.sum())
    if not keep.any():
        return None
    for j, (agree, rj, cj) in ag.hits.items():
        take = agree & keep
        used[j][rj[take], cj[take]] = True
    r, c = rows[keep], cols[keep]
    d = s.depth[r, c]
    m = 1.0 + ag.count[keep]
    mean = ag.s1[keep] / m  # the reference's own offset is 0
    var = np.maximum(ag.s2[keep] - m * mean * mean, 0.0) / (m - 1.0)
    footprint = d / np.sqrt(s.K[0, 0] * s.K[1, 1])
    sigma = np.maximum(np.sqrt(var), options.sigma_floor_px * footprint)
    normal = s.normal[r, c]
    positions = s.points(r, c, d) + mean[:, None] * normal
    confidence = ag.count[keep] / np.maximum(ag.seen[keep], 1)
    return positions, normal, s.colour[r, c], sigma, confidence, (1 + ag.count[keep]).astype(np.int32), footprint


def splat_surface_points(
    splats: GaussianSet,
    cameras: Cameras,
    masks: Mapping[str, np.ndarray],
    front_depths: Mapping[str, np.ndarray] | None = None,
    options: SplatSurfaceOptions | None = None,
    anchors: np.ndarray | None = None,
) -> SplatSurfacePoints:
    """Survey points of the surface ``splats`` render, checked across views (see the module docstring).

    splats: the trained fill layer (any origin; flat splats render the truest plane depth). cameras: pinhole
    views (undistorted), the local frame of the output. masks: image name → (H, W) bool region mask at the
    camera's size (views without a mask are skipped; they neither give nor check points). front_depths: image
    name → (H, W) z-depth (metres) of the front surface of mirrors / glass in that view, 0 where unknown.
    anchors: (M, 3) points of an independent surface estimate in the cameras' local frame (the fused MVS cloud)
    for the σ model's anchor term (None or empty: that term is 0).
    """
    opts = options or SplatSurfaceOptions()
    views = [v for v in cameras if v.name in masks]
    surfaces = []
    for v in views:
        cam = cameras.camera_of(v)
        mask = np.asarray(masks[v.name], bool)
        front = None if front_depths is None else front_depths.get(v.name)
        for name, arr in (("mask", mask), ("front depth", front)):
            if arr is not None and arr.shape != (cam.height, cam.width):
                raise DataError(f"{name} of {v.name} is {arr.shape[1]}×{arr.shape[0]}, its camera "
                                f"{cam.width}×{cam.height}")  # fmt: skip
        surfaces.append(_render_surface(splats, cam, v, cameras.origin, mask, front, opts.depth))
    used = [np.zeros(s.depth.shape, bool) for s in surfaces]
    counts = dict.fromkeys(("candidates", "virtual", "inconsistent", "used", "kept"), 0)
    parts, refs = [], []
    for i in range(len(surfaces)):
        part = _fuse_view(i, surfaces, used, opts, counts) if len(surfaces) > opts.min_agreeing else None
        if part is not None:
            parts.append(part)
            refs.append(np.full(len(part[0]), i, np.int32))
    if not parts:
        empty = np.zeros((0, 3))
        return SplatSurfacePoints(empty, empty.copy(), np.zeros((0, 3), np.float32), np.zeros(0), np.zeros(0),
                                  np.zeros(0, np.int32), np.zeros(0, np.int32), counts)  # fmt: skip
    cols = [np.concatenate([p[k] for p in parts]) for k in range(7)]
    sigma = sigma_model(cols[0], cols[1], cols[3], cols[6], anchors, opts)
    return SplatSurfacePoints(cols[0], cols[1], cols[2].astype(np.float32), sigma, cols[4], cols[5].astype(np.int32),
                              np.concatenate(refs), counts, cols[3], cols[6])  # fmt: skip


def sigma_model(
    positions: np.ndarray, normals: np.ndarray, spread: np.ndarray, footprint: np.ndarray,
    anchors: np.ndarray | None, options: SplatSurfaceOptions,
) -> np.ndarray:  # fmt: skip
    """σ (N,) float64 metres of fused splat-surface points: σ² = spread² + (a·footprint)² + (b·roughness)² +
    (c·anchor)², a, b, c = ``sigma_footprint``, ``sigma_roughness``, ``sigma_anchor``.

    The spread of the agreeing views misses the bias that all views share (they render the same fill layer), so
    two terms measure the rendered surface against its neighbourhood: roughness = the RMS normal offset
    n·(X_k − X) of the ``sigma_neighbours`` nearest other fused points (a surface the views agree on but that
    is rough or layered); anchor = |median n·(M_k − X)| over the ``sigma_neighbours`` nearest ``anchors`` M (the
    MVS surface at and around the hole: how far the point lies off it along its normal, a floater above a table
    or a virtual layer behind a pane). positions, normals: (N, 3) local frame; spread, footprint: (N,) metres.
    """
    from scipy.spatial import cKDTree

    pos = np.asarray(positions, np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    var = np.asarray(spread, np.float64) ** 2 + (options.sigma_footprint * np.asarray(footprint, np.float64)) ** 2
    k = options.sigma_neighbours
    if options.sigma_roughness > 0 and len(pos) > 1:
        _, nb = cKDTree(pos).query(pos, k=min(k + 1, len(pos)))
        off = np.einsum("ikj,ij->ik", pos[nb[:, 1:]] - pos[:, None], nrm)
        var += options.sigma_roughness**2 * (off**2).mean(axis=1)
    if options.sigma_anchor > 0 and anchors is not None and len(anchors) and len(pos):
        ref = np.asarray(anchors, np.float64).reshape(-1, 3)
        _, nb = cKDTree(ref).query(pos, k=min(k, len(ref)))
        nb = nb.reshape(len(pos), -1)
        off = np.median(np.einsum("ikj,ij->ik", ref[nb] - pos[:, None], nrm), axis=1)
        var += (options.sigma_anchor * off) ** 2
    return np.sqrt(var)


def front_depths_from_points(
    points: np.ndarray, cameras: Cameras, names: list[str] | None = None
) -> dict[str, np.ndarray]:
    """Front-surface depth maps from points of the front surface (N, 3, cameras' local frame; e.g. the MVS points
    of a mirror's frame or a glass pane's own surface): per view, the z of the nearest point landing in each pixel
    (0 where none: unknown). names: the views to make (default: all)."""
    from fusion.render.zbuffer import zbuffer

    out = {}
    for v in cameras:
        if names is not None and v.name not in names:
            continue
        cam = cameras.camera_of(v)
        out[v.name] = zbuffer(np.asarray(points, np.float64), v.viewmat, cam.K(), cam.width, cam.height)
    return out


def as_point_set(points: SplatSurfacePoints, origin: np.ndarray) -> GaussianSet:
    """Splat-surface points as the survey point product holds points (a Gaussian set whose centres are the points).

    points: from :func:`splat_surface_points`, positions relative to ``origin`` (3,) float64 world coordinates (the
    cameras' origin). Each point: an isotropic Gaussian of σ = its ``sigma`` (metres), opacity = its confidence
    (clipped to [0.01, 0.99]: a logit stays finite), DC colour = its rendered colour, SH degree 0; fields ``source``
    (uint8, ``Source.SPLAT_SURFACE``), ``classification`` (uint8, ``SPLAT_SURFACE_CLASS``) and ``sigma`` (float32,
    metres: the per-point uncertainty the exports carry).
    """
    from core.gaussians import SH_C0, logit
    from fusion.convert_options import SPLAT_SURFACE_CLASS, Source

    n = len(points)
    sigma = np.asarray(points.sigma, np.float64)
    colour = np.clip(np.asarray(points.colours, np.float64), 0.0, 1.0)
    return GaussianSet(
        np.asarray(points.positions, np.float64).reshape(n, 3),
        np.repeat(np.log(np.maximum(sigma, 1e-9))[:, None], 3, axis=1),
        np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (n, 1)),
        logit(np.clip(np.asarray(points.confidence, np.float64), 0.01, 0.99)),
        ((colour - 0.5) / SH_C0).reshape(n, 3),
        np.zeros((n, 0, 3)),
        np.asarray(origin, np.float64).copy(),
        {"source": np.full(n, Source.SPLAT_SURFACE, np.uint8),
         "classification": np.full(n, SPLAT_SURFACE_CLASS, np.uint8), "sigma": sigma.astype(np.float32)},
    )  # fmt: skip
