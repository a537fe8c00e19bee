"""Data types of :mod:`fusion.mesh`: oriented points (the input of surface reconstruction) and triangle meshes.

Both hold float64 coordinates relative to a float64 local ``origin`` (world = origin + local), like
:class:`core.pointcloud.PointCloud` and :class:`core.gaussians.GaussianSet`, so georeferenced scenes keep millimetres;
anything handed to open3d or fast-simplification is local.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.errors import DataError


class MeshWarning(UserWarning):
    """Meshing could not do exactly what its options ask (e.g. a budget above the raw triangle count)."""


@dataclass
class OrientedPoints:
    """Points with unit normals, the input of screened Poisson reconstruction.

    positions: (N, 3) float64, metres, relative to ``origin``.
    normals: (N, 3) float64 unit vectors pointing out of the surface (towards the side the cameras saw).
    colors: (N, 3) float32 RGB in [0, 1] (SH DC of the Gaussian each point was drawn from).
    source: (N,) uint8, :class:`fusion.convert.Source` code of that Gaussian (1 MVS, 2 splat, 0 unknown).
    gaussian_index: (N,) int64, index of that Gaussian in the set the points were drawn from (-1: none).
    origin: (3,) float64 world coordinates of the local origin.
    footprint: (N,) float64 metres, radius of the surface the point's Gaussian covers (its sampled ellipse's long
        semi-axis; 0: unknown, the default), used by support trimming (:func:`fusion.mesh.poisson.trim_mesh`).
    """

    positions: np.ndarray
    normals: np.ndarray
    colors: np.ndarray
    source: np.ndarray
    gaussian_index: np.ndarray
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    footprint: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.positions = np.ascontiguousarray(np.asarray(self.positions, dtype=np.float64).reshape(-1, 3))
        n = len(self.positions)
        self.normals = np.asarray(self.normals, dtype=np.float64).reshape(-1, 3)
        self.colors = np.asarray(self.colors, dtype=np.float32).reshape(-1, 3)
        self.source = np.asarray(self.source, dtype=np.uint8).reshape(-1)
        self.gaussian_index = np.asarray(self.gaussian_index, dtype=np.int64).reshape(-1)
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        if self.footprint is None:
            self.footprint = np.zeros(n)
        self.footprint = np.asarray(self.footprint, dtype=np.float64).reshape(-1)
        for name in ("normals", "colors", "source", "gaussian_index", "footprint"):
            if len(getattr(self, name)) != n:
                raise DataError(f"oriented points: {name} has {len(getattr(self, name))} rows for {n} points")

    def __len__(self) -> int:
        return len(self.positions)

    def subset(self, index: np.ndarray | slice) -> OrientedPoints:
        return OrientedPoints(
            self.positions[index],
            self.normals[index],
            self.colors[index],
            self.source[index],
            self.gaussian_index[index],
            self.origin.copy(),
            self.footprint[index],
        )

    def with_origin(self, origin: np.ndarray) -> OrientedPoints:
        """The same points relative to another origin (float64)."""
        origin = np.asarray(origin, dtype=np.float64).reshape(3)
        out = self.subset(slice(None))
        out.positions = self.positions + (self.origin - origin)
        out.origin = origin
        return out

    @staticmethod
    def concatenate(parts: list[OrientedPoints]) -> OrientedPoints:
        """One set from several, in the first part's origin (``gaussian_index`` kept as is: per-part indices)."""
        if not parts:
            raise DataError("cannot concatenate an empty list of oriented point sets")
        origin = parts[0].origin
        moved = [p.with_origin(origin) for p in parts]
        return OrientedPoints(
            np.concatenate([p.positions for p in moved]),
            np.concatenate([p.normals for p in moved]),
            np.concatenate([p.colors for p in moved]),
            np.concatenate([p.source for p in moved]),
            np.concatenate([p.gaussian_index for p in moved]),
            origin,
            np.concatenate([p.footprint for p in moved]),
        )


@dataclass
class TriangleMesh:
    """A triangle mesh.

    vertices: (V, 3) float64, metres, relative to ``origin``.
    triangles: (T, 3) int64 vertex indices, counter-clockwise seen from outside (normals point outwards).
    origin: (3,) float64 world coordinates of the local origin.
    vertex_colors: (V, 3) float32 RGB in [0, 1], or None.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    vertex_colors: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3))
        self.triangles = np.ascontiguousarray(np.asarray(self.triangles, dtype=np.int64).reshape(-1, 3))
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        if self.vertex_colors is not None:
            self.vertex_colors = np.asarray(self.vertex_colors, dtype=np.float32).reshape(-1, 3)
            if len(self.vertex_colors) != len(self.vertices):
                raise DataError(f"mesh: {len(self.vertex_colors)} vertex colours for {len(self.vertices)} vertices")
        if len(self.triangles) and (self.triangles.min() < 0 or self.triangles.max() >= len(self.vertices)):
            raise DataError(f"mesh: triangle indices outside 0..{len(self.vertices) - 1}")

    @property
    def num_triangles(self) -> int:
        return len(self.triangles)

    @property
    def world_vertices(self) -> np.ndarray:
        """(V, 3) float64 world coordinates."""
        return self.vertices + self.origin

    def triangle_areas(self) -> np.ndarray:
        """(T,) float64 areas in square metres."""
        v = self.vertices[self.triangles]
        return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)

    def sample_surface(self, n: int, seed: int = 0) -> np.ndarray:
        """(n, 3) float64 points uniform over the surface (local frame): triangles drawn by area, then uniform
        barycentric coordinates. :class:`DataError` for a mesh without area."""
        areas = self.triangle_areas()
        total = float(areas.sum())
        if not total > 0:
            raise DataError(f"cannot sample a mesh without area ({self.num_triangles} triangles)")
        rng = np.random.default_rng(seed)
        tri = rng.choice(len(areas), size=int(n), p=areas / total)
        a, b = rng.random(int(n)), rng.random(int(n))
        flip = a + b > 1
        a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
        t = self.vertices[self.triangles[tri]]
        return t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])

    def compact(self) -> TriangleMesh:
        """The mesh without vertices that no triangle uses (indices renumbered, colours follow)."""
        used = np.zeros(len(self.vertices), dtype=bool)
        used[self.triangles.reshape(-1)] = True
        remap = np.cumsum(used) - 1
        colors = self.vertex_colors[used] if self.vertex_colors is not None else None
        return TriangleMesh(self.vertices[used], remap[self.triangles], self.origin.copy(), colors)


def as_choice(enum_type: type, value: object, name: str):  # -> the enum member
    """``enum_type(value)``, or a :class:`ConfigError` naming the option and its allowed values."""
    from core.errors import ConfigError

    try:
        return enum_type(value)
    except ValueError:
        allowed = ", ".join(repr(m.value) for m in enum_type)
        raise ConfigError(f"{name} must be one of {allowed}, got {value!r}") from None
