"""Triangle meshes with a material id per face, and the primitives the scenes are built from.

Primitives come from ``trimesh.creation`` (boxes, icospheres, cylinders); terrain is a height field.
All coordinates are float64 metres in the scene's local frame (z up).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from core.errors import DataError


@dataclass(frozen=True)
class SceneMesh:
    """The ground-truth surface.

    vertices: (V, 3) float64, metres, local frame.
    faces: (F, 3) int32 vertex indices, counter-clockwise seen from outside (normals point out).
    face_material: (F,) int32 material id per face.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_material: np.ndarray

    def __post_init__(self) -> None:
        v = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        f = np.ascontiguousarray(self.faces, dtype=np.int32).reshape(-1, 3)
        m = np.ascontiguousarray(self.face_material, dtype=np.int32).reshape(-1)
        if len(m) != len(f):
            raise DataError(f"mesh has {len(f)} faces but {len(m)} face materials")
        if len(f) and (f.min() < 0 or f.max() >= len(v)):
            raise DataError("mesh faces index vertices out of range")
        if not np.isfinite(v).all():
            raise DataError("mesh vertices contain NaN or infinite values")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)
        object.__setattr__(self, "face_material", m)

    @property
    def triangles(self) -> np.ndarray:
        """(F, 3, 3) float64 corner coordinates."""
        return self.vertices[self.faces]

    def face_normals(self) -> np.ndarray:
        """(F, 3) float64 unit geometric normals (right-hand rule); degenerate faces get (0, 0, 1)."""
        tri = self.triangles
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        out = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
        out[norm[:, 0] == 0] = (0.0, 0.0, 1.0)
        return out

    def face_areas(self) -> np.ndarray:
        """(F,) float64 triangle areas, m²."""
        tri = self.triangles
        return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)

    def bounds(self) -> np.ndarray:
        """(2, 3) float64 min and max corner."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    def to_trimesh(self) -> trimesh.Trimesh:
        """A trimesh (float64, not merged or processed) for proximity queries."""
        return trimesh.Trimesh(self.vertices, self.faces, process=False)


@dataclass
class MeshBuilder:
    """Collects parts (vertices, faces, one material each) into one :class:`SceneMesh`."""

    _parts: list[tuple[np.ndarray, np.ndarray, int]] = field(default_factory=list)

    def add(self, mesh: trimesh.Trimesh, material_id: int) -> None:
        """Append a part; its faces all get ``material_id``."""
        self._parts.append((np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64), material_id))

    def build(self) -> SceneMesh:
        verts, faces, mats, offset = [], [], [], 0
        for v, f, m in self._parts:
            verts.append(v)
            faces.append(f + offset)
            mats.append(np.full(len(f), m, np.int32))
            offset += len(v)
        return SceneMesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(mats))


def box(
    extents: tuple[float, float, float], center: tuple[float, float, float], yaw_deg: float = 0.0
) -> trimesh.Trimesh:
    """A box of ``extents`` (x, y, z metres) centred at ``center``, rotated by ``yaw_deg`` about z."""
    transform = trimesh.transformations.rotation_matrix(np.radians(yaw_deg), (0, 0, 1))
    transform[:3, 3] = center
    return trimesh.creation.box(extents=extents, transform=transform)


def sphere(radius: float, center: tuple[float, float, float], subdivisions: int = 3) -> trimesh.Trimesh:
    """An icosphere (subdivisions 1 gives a faceted gem, 3-4 a smooth ball)."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.apply_translation(center)
    return mesh


def cylinder(radius: float, height: float, center: tuple[float, float, float], sections: int = 32) -> trimesh.Trimesh:
    """An upright (z) capped cylinder centred at ``center``."""
    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    mesh.apply_translation(center)
    return mesh


def rod(p0: np.ndarray, p1: np.ndarray, radius: float, sections: int = 8) -> trimesh.Trimesh:
    """A thin capped cylinder between two points (wires, lattice members, cables)."""
    return trimesh.creation.cylinder(radius=radius, segment=np.stack([p0, p1]).astype(np.float64), sections=sections)


def polyline_rods(points: np.ndarray, radius: float, sections: int = 6) -> list[trimesh.Trimesh]:
    """Rods along consecutive points (N, 3) (e.g. a sagging cable)."""
    return [rod(points[i], points[i + 1], radius, sections) for i in range(len(points) - 1)]


def heightfield(
    size: tuple[float, float], cells: tuple[int, int], heights: np.ndarray, center: tuple[float, float] = (0.0, 0.0)
) -> trimesh.Trimesh:
    """A terrain surface: ``heights`` (cells_y + 1, cells_x + 1) metres on a regular grid of ``size`` (x, y) metres.

    Faces are oriented upwards.
    """
    nx, ny = cells
    h = np.asarray(heights, dtype=np.float64)
    if h.shape != (ny + 1, nx + 1):
        raise DataError(f"heights must have shape {(ny + 1, nx + 1)}, got {h.shape}")
    xs = np.linspace(-size[0] / 2, size[0] / 2, nx + 1) + center[0]
    ys = np.linspace(-size[1] / 2, size[1] / 2, ny + 1) + center[1]
    gx, gy = np.meshgrid(xs, ys)
    verts = np.stack([gx.ravel(), gy.ravel(), h.ravel()], axis=1)
    idx = np.arange((ny + 1) * (nx + 1)).reshape(ny + 1, nx + 1)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return trimesh.Trimesh(verts, faces, process=False)


def plane(size: tuple[float, float], z: float = 0.0, cells: tuple[int, int] = (1, 1)) -> trimesh.Trimesh:
    """A flat upward-facing rectangle centred at the origin at height ``z``."""
    return heightfield(size, cells, np.full((cells[1] + 1, cells[0] + 1), z))
