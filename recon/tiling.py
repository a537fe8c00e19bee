"""Spatial tiles for large surveys: plan them from the sparse model, assign photos, stitch by core ownership.

The first building block of tiled runs (a later runner makes one sub-project per tile and runs its stages as Ray
tasks). Everything here is a pure function of arrays and :class:`core.cameras.Cameras`, plus the plan file's reader
and writer, which take the path from the caller (``hybridsplat.layout.ProjectLayout`` will name it).

Frames
------
All positions are in the project's *local* frame (float64 metres, the sparse model's frame; a georeferenced
project's large offset stays in its origin). Tiles are rectangles in a *plan frame*: ``(u, v)`` in a horizontal
plane and ``h`` up, ``(u, v, h) = (positions - frame.origin) @ frame.axes.T``.

- ``up="z"`` (default): ``u = x``, ``v = y``, ``h = z`` exactly (no arithmetic: positions are used as they are), as
  in data_synth's scenes and georeferenced projects.
- ``up="pca"`` (object scans and façades, whose model is not z-up): ``h`` is the least axis of the camera centres
  (their PCA; the sparse points' when fewer than 3 cameras or the centres are collinear), pointing from the sparse
  points' median towards the cameras (towards local +z when the cameras surround the points); ``u`` is the main
  axis of the sparse points projected on that plane, ``v = h × u``. A façade campaign is then tiled along the
  façade, an orbit around an object on its ground.

Grid and ownership
------------------
The survey region is the sparse points' robust extent in ``(u, v)`` (the ``extent_quantile`` and
``1 - extent_quantile`` quantiles, default 0.5 % and 99.5 %). It is cut into ``columns`` (along u) × ``rows`` (along
v) equal *cores*: ``u_edges`` / ``v_edges`` hold the shared edges. Core ``[u_edges[c], u_edges[c+1]) × [v_edges[r],
v_edges[r+1])`` is half-open, and the outer sides of the border tiles are open (to ±∞): every position of the plane
has exactly one owner tile (:meth:`TilePlan.owner`), points beyond the robust extent included. Tile index =
``row * columns + column``.

Each tile's *bounds* are its core grown by the overlap margin ``overlap_m`` on every side; a tile's sparse points
are those inside its bounds (outer sides open as for the core). Default margin (``overlap_m=None``):
``max(overlap_share × the shorter core side, overlap_spacings × the sparse points' median horizontal spacing)``,
i.e. 10 % of the tile and at least 5 point spacings.

``auto`` grid: ``n = max(1, ceil(photos / photos_per_tile), ceil(points / points_per_tile))`` tiles are needed
(defaults 200 photos and 200 000 sparse points per tile); among ``columns = 1..n`` with ``rows = ceil(n / columns)``
the grid minimising ``columns·rows × max(a, 1/a)`` (``a`` the core's aspect ratio) wins, ties to fewer tiles, then
to more columns. A 100 m × 60 m region needing 4 tiles gets 2×2; needing 5, 3×2.

Photos
------
A photo belongs to a tile when it sees the tile's core (the finite core rectangle, clipped to the region): at least
``min_points_seen`` sparse points inside the core are seen by it (the points' track visibility when the cloud
carries it, else their projection in front of the camera and inside the image), or (``use_footprint``) its
footprint overlaps the core. The footprint is the image frustum (rays through the image border, distortion
included, up to ``far_m``) intersected with the height slab of the sparse points (the same quantiles of ``h``),
projected onto the plan: the convex hull of the ray segments' ends inside the slab. Occlusion is not modelled.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum
from os import PathLike
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from core.cameras import Camera, Cameras, View
from core.constraints import Choice, Constrained, Constraints, Interval, NoneOr
from core.errors import ConfigError, DataError, FormatError
from core.io.json_io import read_json_object, write_json_atomic
from core.options import enum_choice

PLAN_FORMAT = "hybridsplat-tile-plan"
PLAN_VERSION = 1


class UpAxis(StrEnum):
    """How the plan frame is chosen: the local z axis, or the PCA plane of the camera centres."""

    Z = "z"
    PCA = "pca"


@dataclass(frozen=True)
class TileGrid:
    """``--tiles``: ``columns`` (along u) × ``rows`` (along v), or both None for ``auto``."""

    columns: int | None = None
    rows: int | None = None

    @property
    def auto(self) -> bool:
        return self.columns is None


def parse_tiles(text: str) -> TileGrid | None:
    """``"off"`` -> None, ``"auto"`` -> ``TileGrid()``, ``"NxM"`` -> N columns (along x/u) × M rows (along y/v)."""
    value = str(text).strip().lower()
    if value == "off":
        return None
    if value == "auto":
        return TileGrid()
    match = re.fullmatch(r"(\d+)\s*[x×]\s*(\d+)", value)
    if match is None or int(match[1]) < 1 or int(match[2]) < 1:
        raise ConfigError(f"--tiles must be auto, off or NxM with N, M ≥ 1 (e.g. 3x2), got {text!r}")
    return TileGrid(int(match[1]), int(match[2]))


@dataclass(frozen=True, kw_only=True)
class TileOptions(Constrained):
    """Options of :func:`plan_tiles` (units: metres, counts). See the module docstring for each rule."""

    grid: TileGrid = field(default_factory=TileGrid)
    photos_per_tile: int = 200
    points_per_tile: int = 200_000
    overlap_m: float | None = None
    overlap_share: float = 0.1
    overlap_spacings: float = 5.0
    extent_quantile: float = 0.005
    up: UpAxis = UpAxis.Z
    min_points_seen: int = 20
    use_footprint: bool = True
    far_m: float | None = None  # footprint ray length; None: 4 × (region diagonal + height range)

    constraints: ClassVar[Constraints] = {
        "photos_per_tile": Interval(int, 1, None),
        "points_per_tile": Interval(int, 1, None),
        "overlap_m": NoneOr(Interval(float, 0, None)),
        "extent_quantile": Interval(float, 0, 0.5, closed="left"),
        "up": Choice(UpAxis),
        "min_points_seen": Interval(int, 1, None),
    }


@dataclass(frozen=True, eq=False)
class PlanFrame:
    """The plan frame: ``(u, v, h) = (positions - origin) @ axes.T``; ``axes`` rows are u, v, h (orthonormal)."""

    up: UpAxis
    origin: np.ndarray  # (3,) float64, local metres
    axes: np.ndarray  # (3, 3) float64

    def to_plan(self, positions: np.ndarray) -> np.ndarray:
        """(N, 3) float64 local positions -> (N, 3) plan coordinates; the identity (no arithmetic) for ``up="z"``."""
        p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        if self.up is UpAxis.Z:
            return p
        return (p - self.origin) @ self.axes.T


@dataclass(frozen=True)
class Rect:
    """An axis-aligned rectangle of the plan, metres: ``[u0, u1] × [v0, v1]``."""

    u0: float
    u1: float
    v0: float
    v1: float

    def grown(self, margin: float) -> Rect:
        return Rect(self.u0 - margin, self.u1 + margin, self.v0 - margin, self.v1 + margin)


@dataclass(frozen=True)
class Tile:
    """One tile: grid position, core, bounds (core + overlap), the photos that see its core, its sparse point count."""

    index: int
    column: int
    row: int
    core: Rect
    bounds: Rect
    photo_ids: tuple[int, ...]
    photo_names: tuple[str, ...]
    n_points: int

    @property
    def name(self) -> str:
        """Folder-safe name of the tile, ``r{row}c{column}`` (e.g. ``r0c2``)."""
        return f"r{self.row}c{self.column}"


@dataclass(frozen=True, eq=False)
class TilePlan:
    """A tile plan: frame, region, shared core edges, overlap margin, tiles (row-major), the counts it came from."""

    frame: PlanFrame
    region: Rect
    height_range: tuple[float, float]
    u_edges: np.ndarray  # (columns + 1,) float64, strictly increasing; ends = region
    v_edges: np.ndarray  # (rows + 1,) float64
    overlap_m: float
    tiles: tuple[Tile, ...]
    auto: bool
    n_photos: int
    n_points: int

    @property
    def columns(self) -> int:
        return len(self.u_edges) - 1

    @property
    def rows(self) -> int:
        return len(self.v_edges) - 1

    def owner(self, positions: np.ndarray) -> np.ndarray:
        """(N,) int64 index of the tile whose (half-open, outer sides open) core holds each local position (N, 3)."""
        uvh = self.frame.to_plan(positions)
        col = np.searchsorted(self.u_edges[1:-1], uvh[:, 0], side="right")
        row = np.searchsorted(self.v_edges[1:-1], uvh[:, 1], side="right")
        return (row * self.columns + col).astype(np.int64)

    def in_bounds(self, positions: np.ndarray, tile: int) -> np.ndarray:
        """(N,) bool: positions (N, 3) inside tile ``tile``'s bounds (core + overlap; the outer sides open)."""
        t = self.tiles[tile]
        uvh = self.frame.to_plan(positions)
        lo_u = -np.inf if t.column == 0 else t.bounds.u0
        hi_u = np.inf if t.column == self.columns - 1 else t.bounds.u1
        lo_v = -np.inf if t.row == 0 else t.bounds.v0
        hi_v = np.inf if t.row == self.rows - 1 else t.bounds.v1
        u, v = uvh[:, 0], uvh[:, 1]
        return (u >= lo_u) & (u <= hi_u) & (v >= lo_v) & (v <= hi_v)


# -- planning -----------------------------------------------------------------------------------------------------


def plan_frame(cameras: Cameras, positions: np.ndarray, up: UpAxis | str = UpAxis.Z) -> PlanFrame:
    """The plan frame for ``up`` (see the module docstring); positions (N, 3) float64 local sparse points."""
    up = enum_choice(UpAxis, up, "tiles up axis")
    if up is UpAxis.Z:
        return PlanFrame(up, np.zeros(3), np.eye(3))
    centres = np.array([view.center for view in cameras], dtype=np.float64).reshape(-1, 3)
    basis = centres if len(centres) >= 3 else positions
    origin = basis.mean(axis=0)
    _, sing, vt = np.linalg.svd(basis - origin, full_matrices=False)
    if len(sing) < 2 or sing[1] <= 1e-9 * max(sing[0], 1e-300):
        basis, origin = positions, positions.mean(axis=0)
        _, sing, vt = np.linalg.svd(basis - origin, full_matrices=False)
    normal = vt[2] if len(vt) > 2 else np.cross(vt[0], vt[1])
    towards = (centres.mean(axis=0) - np.median(positions, axis=0)) if len(centres) else np.zeros(3)
    spread = float(np.linalg.norm(centres - centres.mean(axis=0), axis=1).mean()) if len(centres) else 0.0
    side = float(towards @ normal)
    if abs(side) <= 0.1 * spread:  # cameras around the points: orient towards local +z
        side = float(normal[2])
    normal = normal if side >= 0 else -normal
    u_axis = _main_axis_in_plane(positions, normal, fallback=vt[0])
    return PlanFrame(up, origin, np.stack([u_axis, np.cross(normal, u_axis), normal]))


def _main_axis_in_plane(positions: np.ndarray, normal: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Unit main axis of the points projected on the plane of ``normal`` (``fallback`` projected if degenerate)."""
    flat = positions - np.outer(positions @ normal, normal)
    axis = fallback
    if len(flat) >= 2:
        _, sing, vt = np.linalg.svd(flat - flat.mean(axis=0), full_matrices=False)
        axis = vt[0] if sing[0] > 0 else fallback
    axis = axis - (axis @ normal) * normal
    norm = np.linalg.norm(axis)
    if norm < 1e-9:  # fallback along the normal: any axis in the plane
        axis = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
        norm = np.linalg.norm(axis)
    return axis / norm


def auto_grid(n_photos: int, n_points: int, width: float, height: float, options: TileOptions) -> tuple[int, int]:
    """(columns, rows) of the ``auto`` rule (module docstring) for a region ``width`` × ``height`` metres."""
    need = max(1, math.ceil(n_photos / options.photos_per_tile), math.ceil(n_points / options.points_per_tile))

    def key(columns: int) -> tuple[float, int, int]:
        rows = math.ceil(need / columns)
        aspect = (width / columns) / (height / rows) if width > 0 and height > 0 else 1.0
        return round(columns * rows * max(aspect, 1.0 / aspect), 9), columns * rows, -columns

    columns = min(range(1, need + 1), key=key)
    return columns, math.ceil(need / columns)


def _edges(lo: float, hi: float, count: int) -> np.ndarray:
    edges = np.array([lo + (hi - lo) * i / count for i in range(count + 1)], dtype=np.float64)
    edges[0], edges[-1] = lo, hi
    return edges


def _median_spacing(uv: np.ndarray) -> float:
    """Median horizontal nearest-neighbour distance of the points (0 for fewer than 2)."""
    if len(uv) < 2:
        return 0.0
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(uv).query(uv, k=2)
    return float(np.median(dist[:, 1]))


def _region(uvh: np.ndarray, q: float) -> tuple[Rect, tuple[float, float]]:
    lo = np.quantile(uvh, q, axis=0) if q > 0 else uvh.min(axis=0)
    hi = np.quantile(uvh, 1 - q, axis=0) if q > 0 else uvh.max(axis=0)
    return Rect(float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])), (float(lo[2]), float(hi[2]))


def plan_tiles(
    cameras: Cameras, positions: np.ndarray, options: TileOptions, visibility: Sequence | None = None
) -> TilePlan:
    """A :class:`TilePlan` from the sparse model.

    cameras: the registered photos (local frame). positions: (N, 3) float64 sparse points, local metres.
    visibility: per point, the image ids that see it (``PointCloud.visibility``, COLMAP tracks), or None to
    project the points into each photo instead. Raises :class:`DataError` for no points or non-finite positions.
    """
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if len(positions) == 0:
        raise DataError("cannot plan tiles: the sparse model has no points")
    if not np.isfinite(positions).all():
        raise DataError("cannot plan tiles: sparse points with NaN or infinite coordinates")
    frame = plan_frame(cameras, positions, options.up)
    uvh = frame.to_plan(positions)
    region, heights = _region(uvh, options.extent_quantile)
    width, height = region.u1 - region.u0, region.v1 - region.v0
    if options.grid.auto:
        columns, rows = auto_grid(len(cameras), len(positions), width, height, options)
    else:
        columns, rows = int(options.grid.columns), int(options.grid.rows)
    u_edges, v_edges = _edges(region.u0, region.u1, columns), _edges(region.v0, region.v1, rows)
    if not (np.all(np.diff(u_edges) > 0) and np.all(np.diff(v_edges) > 0)):
        raise DataError(f"cannot cut a {width:.3g} m × {height:.3g} m region into {columns}x{rows} tiles")
    overlap = options.overlap_m
    if overlap is None:
        spacing = _median_spacing(uvh[:, :2])
        overlap = max(options.overlap_share * min(width / columns, height / rows), options.overlap_spacings * spacing)
    draft = TilePlan(frame, region, heights, u_edges, v_edges, float(overlap), (), options.grid.auto, 0, 0)
    photos = assign_photos(draft, cameras, positions, options, visibility)
    tiles = []
    for row in range(rows):
        for col in range(columns):
            core = Rect(float(u_edges[col]), float(u_edges[col + 1]), float(v_edges[row]), float(v_edges[row + 1]))
            index = row * columns + col
            ids = tuple(photos[index])
            names = tuple(cameras.views[i].name for i in ids)
            tiles.append(Tile(index, col, row, core, core.grown(draft.overlap_m), ids, names, 0))
    plan = TilePlan(frame, region, heights, u_edges, v_edges, draft.overlap_m, tuple(tiles), options.grid.auto, 0, 0)
    counts = [int(plan.in_bounds(positions, t.index).sum()) for t in plan.tiles]
    tiles = tuple(replace(t, n_points=n) for t, n in zip(plan.tiles, counts, strict=True))
    return replace(plan, tiles=tiles, n_photos=len(cameras), n_points=len(positions))


# -- photos -------------------------------------------------------------------------------------------------------


def _core_tile(plan: TilePlan, positions: np.ndarray) -> np.ndarray:
    """(N,) owner tile of each position inside the region (the finite cores), -1 outside."""
    uvh = plan.frame.to_plan(positions)
    r = plan.region
    inside = (uvh[:, 0] >= r.u0) & (uvh[:, 0] <= r.u1) & (uvh[:, 1] >= r.v0) & (uvh[:, 1] <= r.v1)
    return np.where(inside, plan.owner(positions), -1)


def points_seen_per_tile(
    plan: TilePlan, cameras: Cameras, positions: np.ndarray, visibility: Sequence | None = None
) -> dict[int, np.ndarray]:
    """Per image id, (tiles,) int64 counts of the sparse points in each tile's core that the photo sees.

    With ``visibility`` (per point, image ids) the tracks decide; without, a point is seen when it projects in
    front of the camera and inside the image (occlusion not modelled; each photo projects only the points under a
    conservative plan box of its frustum, the points sorted along ``u`` once).
    """
    n_tiles = plan.columns * plan.rows
    tile = _core_tile(plan, positions)
    counts = {view.image_id: np.zeros(n_tiles, np.int64) for view in cameras}
    if visibility is not None:
        return _tracks_per_tile(tile, visibility, sorted(counts), n_tiles)
    inside = np.flatnonzero(tile >= 0)
    u = plan.frame.to_plan(positions[inside])[:, 0]
    order = inside[np.argsort(u, kind="stable")]
    pts, pts_tile, u_sorted = positions[order], tile[order], np.sort(u, kind="stable")
    corners = _box_corners(pts)
    for view in cameras:
        camera = cameras.cameras[view.camera_id]
        box = _view_box(plan, camera, view, corners)
        if box is None:
            continue
        lo, hi = np.searchsorted(u_sorted, box.u0, "left"), np.searchsorted(u_sorted, box.u1, "right")
        v = plan.frame.to_plan(pts[lo:hi])[:, 1]
        near = lo + np.flatnonzero((v >= box.v0) & (v <= box.v1))
        cam = view.world_to_camera(pts[near])
        front = cam[:, 2] > 0
        pix = camera.project(cam[front])
        ok = (pix[:, 0] >= 0) & (pix[:, 0] < camera.width) & (pix[:, 1] >= 0) & (pix[:, 1] < camera.height)
        counts[view.image_id] = np.bincount(pts_tile[near][front][ok], minlength=n_tiles).astype(np.int64)
    return counts


def _box_corners(points: np.ndarray) -> np.ndarray:
    """(8, 3) corners of the points' axis-aligned bounding box (local frame); (0, 3) for no points."""
    if len(points) == 0:
        return np.zeros((0, 3))
    lo, hi = points.min(axis=0), points.max(axis=0)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _view_box(plan: TilePlan, camera: Camera, view: View, corners: np.ndarray) -> Rect | None:
    """A plan rectangle that holds every point of the box ``corners`` that the photo can see (None: none).

    The frustum up to the deepest box corner is the pyramid of the camera centre and the image border at that depth;
    its plan bounding box, grown by 5 % for the lens distortion between the border samples, bounds what it sees.
    """
    depth = float(view.world_to_camera(corners)[:, 2].max()) if len(corners) else 0.0
    if depth <= 0:
        return None
    rays = camera.unproject(_border_pixels(camera.width, camera.height))  # camera frame, z = 1
    apex = np.concatenate([view.center[None], view.camera_to_world(rays * depth)])
    uv = plan.frame.to_plan(apex)[:, :2]
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    pad = 0.05 * (hi - lo) + 1e-9 * (1.0 + np.abs(uv).max())
    return Rect(float(lo[0] - pad[0]), float(hi[0] + pad[0]), float(lo[1] - pad[1]), float(hi[1] + pad[1]))


def _tracks_per_tile(tile: np.ndarray, visibility: Sequence, image_ids: list[int], n_tiles: int) -> dict:
    """Per image id, (tiles,) counts of the core points whose track holds the image (vectorised over the tracks)."""
    if len(visibility) != len(tile):
        raise DataError(f"visibility has {len(visibility)} tracks for {len(tile)} sparse points")
    tracks = [np.asarray(ids, dtype=np.int64).reshape(-1) for ids in visibility]
    flat = np.concatenate(tracks) if tracks else np.zeros(0, np.int64)
    flat_tile = np.repeat(tile, [len(ids) for ids in tracks])
    known = np.asarray(image_ids, dtype=np.int64)
    if len(known) == 0:
        return {}
    row = np.searchsorted(known, flat).clip(0, len(known) - 1)
    keep = (flat_tile >= 0) & (known[row] == flat)  # tracks may name photos that are not registered: skipped
    table = np.zeros((len(known), n_tiles), np.int64)
    np.add.at(table, (row[keep], flat_tile[keep]), 1)
    return {image_id: table[k] for k, image_id in enumerate(image_ids)}


def _border_pixels(width: int, height: int, per_side: int = 4) -> np.ndarray:
    s = np.linspace(0.0, 1.0, per_side + 1)[:-1]
    top = np.stack([s * width, np.zeros_like(s)], axis=1)
    right = np.stack([np.full_like(s, width), s * height], axis=1)
    bottom = np.stack([(1 - s) * width, np.full_like(s, height)], axis=1)
    left = np.stack([np.zeros_like(s), (1 - s) * height], axis=1)
    return np.concatenate([top, right, bottom, left])


def footprint(plan: TilePlan, cameras: Cameras, view: View, far_m: float) -> np.ndarray:
    """(K, 2) plan-frame convex hull (counter-clockwise) of the photo's frustum inside the height slab; K may be 0."""
    camera = cameras.cameras[view.camera_id]
    rays_cam = camera.unproject(_border_pixels(camera.width, camera.height))
    rays_cam = rays_cam / np.linalg.norm(rays_cam, axis=1, keepdims=True)
    centre = plan.frame.to_plan(view.center[None])[0]
    dirs = plan.frame.to_plan(view.camera_to_world(rays_cam)) - plan.frame.to_plan(view.center[None])
    h_lo, h_hi = plan.height_range
    dh = dirs[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_a, t_b = (h_lo - centre[2]) / dh, (h_hi - centre[2]) / dh
    flat = np.abs(dh) < 1e-12
    in_slab = h_lo <= centre[2] <= h_hi
    t_in = np.where(flat, 0.0 if in_slab else np.inf, np.minimum(t_a, t_b))
    t_out = np.where(flat, np.inf if in_slab else -np.inf, np.maximum(t_a, t_b))
    t_in, t_out = np.maximum(t_in, 0.0), np.minimum(t_out, far_m)
    hit = t_in <= t_out
    ends = np.concatenate([centre + t_in[hit, None] * dirs[hit], centre + t_out[hit, None] * dirs[hit]])
    return convex_hull_2d(ends[:, :2])


def convex_hull_2d(points: np.ndarray) -> np.ndarray:
    """(K, 2) convex hull, counter-clockwise (Andrew's monotone chain); fewer than 3 points are returned as given."""
    pts = np.unique(np.asarray(points, dtype=np.float64).reshape(-1, 2), axis=0)
    if len(pts) < 3:
        return pts

    def half(seq: np.ndarray) -> list[np.ndarray]:
        out: list[np.ndarray] = []
        for p in seq:
            while len(out) >= 2 and _cross(out[-1] - out[-2], p - out[-2]) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def polygon_overlaps_rect(polygon: np.ndarray, rect: Rect) -> bool:
    """Whether a convex polygon (K, 2) and a rectangle share interior area (separating-axis test; touching = no)."""
    if len(polygon) == 0:
        return False
    corners = np.array([[rect.u0, rect.v0], [rect.u1, rect.v0], [rect.u1, rect.v1], [rect.u0, rect.v1]])
    axes = [np.array([1.0, 0.0]), np.array([0.0, 1.0])]
    for a, b in zip(polygon, np.roll(polygon, -1, axis=0), strict=True):
        edge = b - a
        if np.any(edge != 0):
            axes.append(np.array([-edge[1], edge[0]]))
    for axis in axes:
        p, r = polygon @ axis, corners @ axis
        if p.max() <= r.min() or r.max() <= p.min():
            return False
    return True


def assign_photos(
    plan: TilePlan, cameras: Cameras, positions: np.ndarray, options: TileOptions, visibility: Sequence | None = None
) -> list[list[int]]:
    """Per tile (row-major), the sorted image ids of the photos that see its core (module docstring's rule)."""
    n_tiles = plan.columns * plan.rows
    seen = points_seen_per_tile(plan, cameras, positions, visibility)
    r, (h_lo, h_hi) = plan.region, plan.height_range
    far = options.far_m or 4.0 * (math.hypot(r.u1 - r.u0, r.v1 - r.v0) + (h_hi - h_lo))
    cores = [
        Rect(float(plan.u_edges[c]), float(plan.u_edges[c + 1]), float(plan.v_edges[w]), float(plan.v_edges[w + 1]))
        for w in range(plan.rows)
        for c in range(plan.columns)
    ]
    photos: list[list[int]] = [[] for _ in range(n_tiles)]
    for view in sorted(cameras, key=lambda v: v.image_id):
        hull = footprint(plan, cameras, view, far) if options.use_footprint else np.zeros((0, 2))
        for t in range(n_tiles):
            if seen[view.image_id][t] >= options.min_points_seen or polygon_overlaps_rect(hull, cores[t]):
                photos[t].append(view.image_id)
    return photos


# -- stitching ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TilePoints:
    """One tile's points: (K, 3) float64 local positions and per-point arrays (first axis K) carried along."""

    tile: int
    positions: np.ndarray
    arrays: Mapping[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class Stitched:
    """Stitched points: positions (N, 3) float64, arrays, ``tile`` (N,) int64 owner, ``dropped`` per part."""

    positions: np.ndarray
    arrays: dict[str, np.ndarray]
    tile: np.ndarray
    dropped: tuple[int, ...]


def stitch_by_core(plan: TilePlan, parts: Sequence[TilePoints]) -> Stitched:
    """Keep each point only in the tile whose core owns it (:meth:`TilePlan.owner`): no duplicate, no loss.

    Rows are copied as they are (positions bit-identical), tile by tile in the order of ``parts``. Every part must
    carry the same array names; a point that no part's own core holds is not kept (each part's ``dropped`` counts
    the points it gave up to a neighbour or that lay outside its core).
    """
    if not parts:
        raise DataError("nothing to stitch: no tile parts")
    names = set(parts[0].arrays)
    keep_pos, keep_arrays, keep_tile, dropped = [], {n: [] for n in names}, [], []
    for part in parts:
        if set(part.arrays) != names:
            raise DataError(f"tile {part.tile}: arrays {sorted(part.arrays)} differ from {sorted(names)}")
        if not 0 <= part.tile < len(plan.tiles):
            raise DataError(f"tile {part.tile} is not in the plan's {len(plan.tiles)} tiles")
        pos = np.asarray(part.positions, dtype=np.float64).reshape(-1, 3)
        if not np.isfinite(pos).all():
            raise DataError(f"tile {part.tile}: {int((~np.isfinite(pos).all(axis=1)).sum())} points are NaN or inf")
        for n in names:
            if len(part.arrays[n]) != len(pos):
                raise DataError(f"tile {part.tile}: array {n!r} has {len(part.arrays[n])} rows, expected {len(pos)}")
        own = plan.owner(pos) == part.tile
        keep_pos.append(pos[own])
        for n in names:
            keep_arrays[n].append(np.asarray(part.arrays[n])[own])
        keep_tile.append(np.full(int(own.sum()), part.tile, np.int64))
        dropped.append(int(len(pos) - own.sum()))
    return Stitched(
        np.concatenate(keep_pos),
        {n: np.concatenate(v) for n, v in keep_arrays.items()},
        np.concatenate(keep_tile),
        tuple(dropped),
    )


@dataclass(frozen=True)
class SeamCheck:
    """Spacing inside tiles against across core borders, metres; ``ratio`` = across / inside (1 for no seam)."""

    spacing_inside: float
    spacing_across: float
    n_border: int

    @property
    def ratio(self) -> float:
        return self.spacing_across / self.spacing_inside if self.spacing_inside > 0 else math.inf

    def ok(self, tolerance: float = 0.25) -> bool:
        """No seam: the spacing across borders within ``tolerance`` (relative) of the spacing inside."""
        return self.n_border > 0 and abs(self.ratio - 1.0) <= tolerance


def seam_check(
    plan: TilePlan, positions: np.ndarray, tile: np.ndarray | None = None, band_m: float | None = None
) -> SeamCheck:
    """Compare the nearest-neighbour spacing across core borders with the spacing inside the tiles.

    positions: (N, 3) float64 merged local positions. tile: (N,) int, the tile each point came from
    (``Stitched.tile``; default: its owner, :meth:`TilePlan.owner`). Inside spacing: the median 3-D
    nearest-neighbour distance over all points. Across: for the points within ``band_m`` (default: the inside
    spacing, i.e. the first row of points on each side) of a core side their tile shares with a neighbour, the
    median distance to the nearest point of another tile. A gap along a border raises the ratio above 1; points
    kept by two tiles (an overlap merged twice) drop it towards 0.
    """
    from scipy.spatial import cKDTree

    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if len(pos) < 2:
        raise DataError(f"seam check needs at least 2 points, got {len(pos)}")
    dist, _ = cKDTree(pos).query(pos, k=2)
    inside = float(np.median(dist[:, 1]))
    band = inside * (1 + 1e-9) if band_m is None else float(band_m)
    owner = plan.owner(pos) if tile is None else np.asarray(tile, dtype=np.int64).reshape(-1)
    if len(owner) != len(pos):
        raise DataError(f"seam check: {len(owner)} tile labels for {len(pos)} points")
    uv = plan.frame.to_plan(pos)[:, :2]
    across: list[np.ndarray] = []
    for each in plan.tiles:
        mine = owner == each.index
        others = pos[~mine]
        if not mine.any() or len(others) == 0:
            continue
        near = mine & (_border_distance(plan, each, uv) <= band)
        if near.any():
            across.append(cKDTree(others).query(pos[near], k=1)[0])
    values = np.concatenate(across) if across else np.zeros(0)
    return SeamCheck(inside, float(np.median(values)) if len(values) else math.inf, int(len(values)))


def _border_distance(plan: TilePlan, tile: Tile, uv: np.ndarray) -> np.ndarray:
    """(N,) distance in the plan to the nearest side of the tile's core shared with a neighbour (inf: none)."""
    d = np.full(len(uv), np.inf)
    c = tile.core
    if tile.column > 0:
        d = np.minimum(d, np.abs(uv[:, 0] - c.u0))
    if tile.column < plan.columns - 1:
        d = np.minimum(d, np.abs(uv[:, 0] - c.u1))
    if tile.row > 0:
        d = np.minimum(d, np.abs(uv[:, 1] - c.v0))
    if tile.row < plan.rows - 1:
        d = np.minimum(d, np.abs(uv[:, 1] - c.v1))
    return d


# -- the plan file ------------------------------------------------------------------------------------------------


def _rect_json(r: Rect) -> dict[str, list[float]]:
    return {"u": [r.u0, r.u1], "v": [r.v0, r.v1]}


def tile_plan_json(plan: TilePlan) -> dict[str, Any]:
    """The plan as the JSON object :func:`write_tile_plan` writes (floats exact: JSON keeps float64 repr)."""
    return {
        "format": PLAN_FORMAT,
        "version": PLAN_VERSION,
        "frame": {"up": plan.frame.up.value, "origin": plan.frame.origin, "axes": plan.frame.axes},
        "grid": {"columns": plan.columns, "rows": plan.rows, "auto": plan.auto},
        "region": {**_rect_json(plan.region), "height": list(plan.height_range)},
        "u_edges": plan.u_edges,
        "v_edges": plan.v_edges,
        "overlap_m": plan.overlap_m,
        "inputs": {"photos": plan.n_photos, "points": plan.n_points},
        "tiles": [
            {
                "index": t.index,
                "name": t.name,
                "column": t.column,
                "row": t.row,
                "core": _rect_json(t.core),
                "bounds": _rect_json(t.bounds),
                "photos": [{"image_id": i, "name": n} for i, n in zip(t.photo_ids, t.photo_names, strict=True)],
                "n_points": t.n_points,
            }
            for t in plan.tiles
        ],
    }


def write_tile_plan(path: str | PathLike[str], plan: TilePlan) -> Path:
    """Write the plan as JSON atomically (temporary name, then rename). Returns the path."""
    return write_json_atomic(path, tile_plan_json(plan))


class _Reader:
    """Typed access to the plan's JSON with :class:`FormatError` naming the file and the key."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, where: str, problem: str) -> FormatError:
        return FormatError(f"tile plan: {where}: {problem}", self.path)

    def get(self, obj: Any, key: str, kind: type | tuple[type, ...], where: str) -> Any:
        if not isinstance(obj, dict) or key not in obj:
            raise self.fail(where, f"missing {key!r}")
        value = obj[key]
        if isinstance(value, bool) and kind is not bool:
            raise self.fail(f"{where}.{key}", f"expected {_kind_name(kind)}, got a boolean")
        if not isinstance(value, kind):
            raise self.fail(f"{where}.{key}", f"expected {_kind_name(kind)}, got {type(value).__name__}")
        return value

    def floats(self, obj: Any, key: str, where: str, size: int | None = None) -> np.ndarray:
        values = self.get(obj, key, list, where)
        try:
            arr = np.array(values, dtype=np.float64)
        except (TypeError, ValueError):
            raise self.fail(f"{where}.{key}", "expected numbers") from None
        if not np.isfinite(arr).all() or (size is not None and arr.size != size):
            raise self.fail(f"{where}.{key}", f"expected {size or 'some'} finite numbers, got {values!r}"[:200])
        return arr

    def rect(self, obj: Any, key: str, where: str) -> Rect:
        box = self.get(obj, key, dict, where)
        u, v = self.floats(box, "u", f"{where}.{key}", 2), self.floats(box, "v", f"{where}.{key}", 2)
        if not (u[0] <= u[1] and v[0] <= v[1]):
            raise self.fail(f"{where}.{key}", f"empty rectangle u={u.tolist()} v={v.tolist()}")
        return Rect(float(u[0]), float(u[1]), float(v[0]), float(v[1]))


def _kind_name(kind: type | tuple[type, ...]) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    return " or ".join(
        {"dict": "an object", "list": "a list", "str": "text"}.get(k.__name__, k.__name__) for k in kinds
    )


def _read_frame(r: _Reader, data: dict[str, Any]) -> PlanFrame:
    frame = r.get(data, "frame", dict, "plan")
    up = r.get(frame, "up", str, "frame")
    if up not in {m.value for m in UpAxis}:
        raise r.fail("frame.up", f"expected one of {[m.value for m in UpAxis]}, got {up!r}")
    axes = r.floats(frame, "axes", "frame", 9).reshape(3, 3)
    if not np.allclose(axes @ axes.T, np.eye(3), atol=1e-9):
        raise r.fail("frame.axes", "not an orthonormal basis")
    return PlanFrame(UpAxis(up), r.floats(frame, "origin", "frame", 3), axes)


def _read_tile(r: _Reader, item: Any, index: int, plan: TilePlan) -> Tile:
    where = f"tiles[{index}]"
    column, row = r.get(item, "column", int, where), r.get(item, "row", int, where)
    if r.get(item, "index", int, where) != index or (row * plan.columns + column) != index:
        raise r.fail(where, f"index, row and column disagree with the {plan.columns}x{plan.rows} grid")
    core = r.rect(item, "core", where)
    expected = (plan.u_edges[column], plan.u_edges[column + 1], plan.v_edges[row], plan.v_edges[row + 1])
    if (core.u0, core.u1, core.v0, core.v1) != tuple(float(e) for e in expected):
        raise r.fail(f"{where}.core", "does not match the grid's edges")
    photos = r.get(item, "photos", list, where)
    ids = tuple(r.get(p, "image_id", int, f"{where}.photos[{k}]") for k, p in enumerate(photos))
    names = tuple(r.get(p, "name", str, f"{where}.photos[{k}]") for k, p in enumerate(photos))
    n_points = r.get(item, "n_points", int, where)
    if n_points < 0:
        raise r.fail(f"{where}.n_points", f"expected a count ≥ 0, got {n_points}")
    return Tile(index, column, row, core, r.rect(item, "bounds", where), ids, names, n_points)


def read_tile_plan(path: str | PathLike[str]) -> TilePlan:
    """Read and validate a plan written by :func:`write_tile_plan`.

    Raises :class:`~core.errors.InputFileError` (missing) or :class:`FormatError` (bad JSON, wrong format or
    version, missing or mistyped keys, edges not increasing, tiles inconsistent with the grid), naming the file.
    """
    path = Path(path)
    data = read_json_object(path)
    r = _Reader(path)
    if data.get("format") != PLAN_FORMAT or data.get("version") != PLAN_VERSION:
        raise r.fail("plan", f"expected format {PLAN_FORMAT!r} version {PLAN_VERSION}, "
                     f"got {data.get('format')!r} version {data.get('version')!r}")  # fmt: skip
    grid = r.get(data, "grid", dict, "plan")
    columns, rows = r.get(grid, "columns", int, "grid"), r.get(grid, "rows", int, "grid")
    if columns < 1 or rows < 1:
        raise r.fail("grid", f"expected at least 1x1 tiles, got {columns}x{rows}")
    u_edges = r.floats(data, "u_edges", "plan", columns + 1)
    v_edges = r.floats(data, "v_edges", "plan", rows + 1)
    if not (np.all(np.diff(u_edges) > 0) and np.all(np.diff(v_edges) > 0)):
        raise r.fail("plan", "u_edges and v_edges must increase strictly")
    region = r.rect(data, "region", "plan")
    heights = r.floats(r.get(data, "region", dict, "plan"), "height", "region", 2)
    overlap = float(r.get(data, "overlap_m", (int, float), "plan"))
    if not (math.isfinite(overlap) and overlap >= 0):
        raise r.fail("plan.overlap_m", f"expected metres ≥ 0, got {overlap}")
    inputs = r.get(data, "inputs", dict, "plan")
    plan = TilePlan(
        _read_frame(r, data), region, (float(heights[0]), float(heights[1])), u_edges, v_edges, overlap, (),
        bool(r.get(grid, "auto", bool, "grid")), r.get(inputs, "photos", int, "inputs"),
        r.get(inputs, "points", int, "inputs"),
    )  # fmt: skip
    items = r.get(data, "tiles", list, "plan")
    if len(items) != columns * rows:
        raise r.fail("tiles", f"expected {columns * rows} tiles for a {columns}x{rows} grid, got {len(items)}")
    tiles = tuple(_read_tile(r, item, k, plan) for k, item in enumerate(items))
    return replace(plan, tiles=tiles)
