"""Coded survey targets in the synthetic scenes: flat squares with an ArUco marker, laid on the ground or support.

A target is a square of side ``size_m`` lying flat (normal +z) at ``center_m`` (local frame, metres), turned by
``yaw_deg`` about +z. Its face carries the marker of ``marker_id`` from :data:`DICTIONARY` (``cv2.aruco``): the
marker's 6 × 6 cells (one black border cell each side) inside a one-cell white quiet zone, 8 × 8 cells in all.
Seen from above with the image's up along the target's +y axis (turned by yaw), the marker reads as printed: row 0
of the bitmap is the target's +y edge, column 0 its −x edge. The exact centre of the marker is ``center_m``.

Placement (:func:`place_targets`) picks spots on the ground or support (the material most flat spots are on) where
the surface is flat over the target and a margin around it, no object stands over it, and at least ``min_views``
training views (and half as many as the best spot) see it whole and unoccluded; among those, farthest-point
sampling from a seeded random start spreads them over the site. The first half (rounded up) of that order are
flagged ``control``, the rest ``check``. The ray tracer reads the target's albedo from the bitmap
(:meth:`TargetSet.albedo`) on the faces the targets add to the mesh.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from core.cameras import Cameras

DICTIONARY = "DICT_4X4_50"
"""The ``cv2.aruco`` predefined dictionary of the synthetic targets (ids 0–49)."""
CELLS = 8
"""Cells across a target: 4 data cells, one black border cell and one white quiet-zone cell each side."""
WHITE_ALBEDO = 0.85
BLACK_ALBEDO = 0.03
MAX_TARGETS = 50


def aruco_dictionary(name: str = DICTIONARY):
    """The ``cv2.aruco.Dictionary`` called ``name`` (e.g. ``DICT_4X4_50``)."""
    import cv2

    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def marker_bits(marker_id: int, dictionary: str = DICTIONARY) -> np.ndarray:
    """(CELLS, CELLS) bool, True = white: the marker ``marker_id`` with its black border and a white quiet zone."""
    import cv2

    inner = cv2.aruco.generateImageMarker(aruco_dictionary(dictionary), int(marker_id), CELLS - 2, borderBits=1)
    bits = np.ones((CELLS, CELLS), dtype=bool)
    bits[1:-1, 1:-1] = inner > 127
    return bits


@dataclass(frozen=True)
class Target:
    """One coded target: ``marker_id`` of :data:`DICTIONARY`, ``center_m`` (3,) float64 local metres,
    ``size_m`` side of the whole square (quiet zone included), ``yaw_deg`` about +z, ``role`` control or check."""

    marker_id: int
    center_m: tuple[float, float, float]
    size_m: float
    yaw_deg: float
    role: str

    @property
    def point_id(self) -> str:
        """The id of the target's point in ``control/gcp.csv`` and in marks files."""
        return f"T{self.marker_id:02d}"

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """The target's unit x and y axes (3,) in the local frame."""
        a = math.radians(self.yaw_deg)
        return np.array([math.cos(a), math.sin(a), 0.0]), np.array([-math.sin(a), math.cos(a), 0.0])

    def corners(self) -> np.ndarray:
        """(4, 3) float64 corners of the square: (−x, +y), (+x, +y), (+x, −y), (−x, −y) (the marker image's
        top-left, top-right, bottom-right, bottom-left when it reads as printed)."""
        ex, ey = self.axes()
        h = self.size_m / 2
        c = np.asarray(self.center_m, dtype=np.float64)
        return np.stack([c + h * (-ex + ey), c + h * (ex + ey), c + h * (ex - ey), c + h * (-ex - ey)])

    def marker_corners(self) -> np.ndarray:
        """(4, 3) float64 corners of the black marker square (quiet zone excluded), in :meth:`corners`' order."""
        c = np.asarray(self.center_m, dtype=np.float64)
        return c + (self.corners() - c) * (CELLS - 2) / CELLS


@dataclass(frozen=True)
class TargetSet:
    """The targets of a scene and where their faces start in the mesh (two triangles per target, in order)."""

    targets: tuple[Target, ...] = ()
    first_face: int = 0
    dictionary: str = DICTIONARY
    _bits: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        bits = np.stack([marker_bits(t.marker_id, self.dictionary) for t in self.targets]) if self.targets else None
        object.__setattr__(self, "_bits", bits)

    def albedo(self, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Linear RGB albedo (N, 3) at hit ``points`` (N, 3) on target ``faces`` (N,) int (mesh face indices)."""
        k = (np.asarray(faces, dtype=np.int64) - self.first_face) // 2
        centers = np.array([t.center_m for t in self.targets], dtype=np.float64)[k]
        yaw = np.radians([t.yaw_deg for t in self.targets])[k]
        size = np.array([t.size_m for t in self.targets])[k]
        d = np.asarray(points, dtype=np.float64) - centers
        x = (d[:, 0] * np.cos(yaw) + d[:, 1] * np.sin(yaw)) / size + 0.5  # 0 at the −x edge
        y = (-d[:, 0] * np.sin(yaw) + d[:, 1] * np.cos(yaw)) / size + 0.5  # 0 at the −y edge
        col = np.clip(np.floor(x * CELLS).astype(np.int64), 0, CELLS - 1)
        row = np.clip(np.floor((1.0 - y) * CELLS).astype(np.int64), 0, CELLS - 1)
        white = self._bits[k, row, col]
        value = np.where(white, WHITE_ALBEDO, BLACK_ALBEDO)
        return np.repeat(value[:, None], 3, axis=1)

    def describe(self, origin: np.ndarray) -> dict[str, object]:
        """``scene.json``'s ``targets``: dictionary, and per target its id, marker, role, size and exact centre
        (world = origin + local, metres)."""
        return {
            "dictionary": self.dictionary,
            "cells": CELLS,
            "points": [
                {
                    "id": t.point_id,
                    "marker_id": t.marker_id,
                    "role": t.role,
                    "size_m": t.size_m,
                    "yaw_deg": t.yaw_deg,
                    "center_local_m": list(t.center_m),
                    "center_world_m": [float(v) for v in np.asarray(origin, np.float64) + np.asarray(t.center_m)],
                }
                for t in self.targets
            ],
        }


def with_targets(mesh, targets: tuple[Target, ...]):
    """``mesh`` (a :class:`data_synth.geometry.SceneMesh`) with the targets' squares appended (material
    :data:`~data_synth.materials.TARGET_MATERIAL_ID`), and their :class:`TargetSet`."""
    from data_synth.geometry import SceneMesh
    from data_synth.materials import TARGET_MATERIAL_ID

    verts, faces = [mesh.vertices], [mesh.faces]
    offset = len(mesh.vertices)
    for t in targets:
        v, f = target_faces(t)
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    mats = np.concatenate([mesh.face_material, np.full(2 * len(targets), TARGET_MATERIAL_ID, np.int32)])
    out = SceneMesh(np.concatenate(verts), np.concatenate(faces), mats)
    return out, TargetSet(tuple(targets), first_face=len(mesh.faces))


def target_faces(target: Target) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (4, 3) and two upward-facing triangles (2, 3) of a target's square."""
    v = target.corners()  # TL, TR, BR, BL seen from above: counter-clockwise is BL, BR, TR, TL
    return v, np.array([[3, 2, 1], [3, 1, 0]], dtype=np.int64)


@dataclass(frozen=True)
class TargetPlacement:
    """How targets are placed: ``pixels`` across a target at the lower quartile of the training views' distances
    to the site centre; ``lift_fraction`` of the side the square floats above the surface (so it is hit before the
    ground); ``min_views`` training views that must see it (at most half the views, at least 2); ``candidates``
    spots tried per axis (a grid, jittered)."""

    pixels: float = 40.0
    lift_fraction: float = 0.002
    min_views: int = 4
    candidates: int = 48


def target_size_m(cameras: Cameras, site_center: np.ndarray, pixels: float) -> float:
    """Side (metres) that ``pixels`` span at the lower quartile of the training views' distances to ``site_center``
    (the nadir views of an aerial block, any view of an orbit), rounded to 3 digits."""
    fx = next(iter(cameras.cameras.values())).focal[0]
    dist = float(np.quantile([np.linalg.norm(v.center - site_center) for v in cameras], 0.25))
    return float(f"{pixels * dist / fx:.3g}")


def place_targets(
    tracer,
    cameras: Cameras,
    count: int,
    rng: np.random.Generator,
    placement: TargetPlacement | None = None,
) -> tuple[Target, ...]:
    """Up to ``count`` targets on flat, unobstructed, well-seen spots of ``tracer``'s mesh (see the module
    docstring); ``tracer`` is a :class:`data_synth.raytrace.RayTracer` of the scene without targets."""
    if count <= 0:
        return ()
    placement = placement or TargetPlacement()
    count = min(int(count), MAX_TARGETS)
    lo, hi = tracer.mesh.bounds()
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    size = target_size_m(cameras, centre, placement.pixels)
    n = placement.candidates
    gx, gy = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n)
    jitter = rng.uniform(-0.4, 0.4, (n * n, 2)) / n
    xy = lo[:2] + (np.stack([gx.ravel(), gy.ravel()], axis=1) + jitter) * (hi[:2] - lo[:2])
    surface, material = _flat_surface(tracer, xy, size, hi[2] + 1.0)
    ok = np.isfinite(surface)
    if ok.any():  # the ground or support: the material most of the flat spots are on (not a flat roof)
        support = int(np.bincount(material[ok]).argmax())
        ok &= material == support
    centres = np.concatenate([xy, (surface + placement.lift_fraction * size)[:, None]], axis=1)[ok]
    yaws = np.round(rng.uniform(0.0, 360.0, len(centres)), 2)
    seen = _views_seeing(tracer, cameras, centres, size)
    least = min(placement.min_views, max(2, len(cameras) // 2))
    keep = seen >= max(least, int(0.5 * seen.max())) if len(seen) else seen > 0  # the better-seen spots
    centres, yaws = centres[keep], yaws[keep]
    if len(centres) == 0:
        return ()
    order = _farthest_points(centres[:, :2], count, 1.5 * size, rng)
    n_control = (len(order) + 1) // 2
    return tuple(
        Target(i, tuple(float(v) for v in centres[k]), size, float(yaws[k]), "control" if i < n_control else "check")
        for i, k in enumerate(order)
    )


def _flat_surface(tracer, xy: np.ndarray, size: float, top: float) -> tuple[np.ndarray, np.ndarray]:
    """(N,) surface height under each spot where a square of ``size`` (any yaw, with a margin) lies on one flat,
    upward-facing surface seen from above (NaN elsewhere), and (N,) the material at the spot's centre."""
    ring = 0.9 * size
    angles = np.arange(12) * (2 * np.pi / 12)
    offsets = np.concatenate([[[0.0, 0.0]], ring * np.stack([np.cos(angles), np.sin(angles)], 1), [[0.5 * size, 0]]])
    pts = (xy[:, None, :] + offsets[None, :, :]).reshape(-1, 2)
    origins = np.concatenate([pts, np.full((len(pts), 1), top)], axis=1)
    dirs = np.broadcast_to(np.array([0.0, 0.0, -1.0]), origins.shape).copy()
    hits = tracer.cast(origins, dirs)
    z = np.where(hits.hit, hits.points[:, 2], np.nan).reshape(len(xy), -1)
    up = (hits.normal[:, 2] > 0.9999).reshape(len(xy), -1)
    mat = hits.material.reshape(len(xy), -1)
    flat = np.all(np.abs(z - z[:, :1]) < 1e-6 * max(1.0, size), axis=1) & up.all(axis=1)
    flat &= np.all(mat == mat[:, :1], axis=1)
    return np.where(flat, z[:, 0], np.nan), mat[:, 0].astype(np.int64)


def _views_seeing(tracer, cameras: Cameras, centres: np.ndarray, size: float) -> np.ndarray:
    """(N,) number of training views that see a target at the spot whole: a 6 × 6 grid of points over its square
    (corners included), inside the image by a tenth of a target and unoccluded."""
    if len(centres) == 0:  # no flat spot on the support (a tiny or cluttered layout): no target is seen
        return np.zeros(0, dtype=np.int64)
    g = np.linspace(-size / 2, size / 2, 6)
    gx, gy = np.meshgrid(g, g)
    offsets = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    pts = (centres[:, None, :] + offsets[None]).reshape(-1, 3)
    count = np.zeros(len(centres), dtype=np.int64)
    for view in cameras:
        cam = cameras.camera_of(view)
        uv, z = cameras.project(view, pts)
        margin = 0.1 * size * cam.focal[0] / np.maximum(z, 1e-9)
        inside = (z > 0) & (uv[:, 0] > margin) & (uv[:, 1] > margin)
        inside &= (uv[:, 0] < cam.width - margin) & (uv[:, 1] < cam.height - margin)
        d = pts - view.center
        dist = np.linalg.norm(d, axis=1)
        hits = tracer.cast(np.broadcast_to(view.center, d.shape).copy(), d / dist[:, None])
        clear = hits.t >= dist - 0.01 * size
        count += (inside & clear).reshape(len(centres), -1).all(axis=1)
    return count


def _farthest_points(xy: np.ndarray, count: int, min_gap: float, rng: np.random.Generator) -> list[int]:
    """Indices of up to ``count`` points of ``xy`` (N, 2): a random first one, then each the farthest from those
    chosen, none closer than ``min_gap`` to another."""
    if len(xy) == 0:
        return []
    chosen = [int(rng.integers(len(xy)))]
    dist = np.linalg.norm(xy - xy[chosen[0]], axis=1)
    while len(chosen) < count:
        k = int(np.argmax(dist))
        if dist[k] < min_gap:
            break
        chosen.append(k)
        dist = np.minimum(dist, np.linalg.norm(xy - xy[k], axis=1))
    return chosen
