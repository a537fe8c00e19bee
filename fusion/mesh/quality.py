"""Topology and geometry checks of a triangle mesh: watertight, edge-manifold, boundary edges, degenerate triangles.

Computed from the edge–triangle incidence directly (each undirected edge counted over the triangles using it):
an edge used once is a boundary edge, twice is interior, more is non-manifold. Watertight = no boundary and no
non-manifold edge. Written by hand (a few numpy lines) so the counts are exact and independent of the library that
built the mesh; tests compare them with open3d's ``is_watertight`` / ``get_non_manifold_edges``.
"""

from __future__ import annotations

from dataclasses import dataclass

from fusion.mesh.graph import edge_use_counts, triangle_components
from fusion.mesh.types import TriangleMesh


@dataclass(frozen=True)
class MeshQuality:
    """Counts of one mesh (see the module docstring); ``degenerate`` triangles repeat a vertex or have zero area."""

    vertices: int
    triangles: int
    edges: int
    boundary_edges: int
    non_manifold_edges: int
    degenerate_triangles: int
    pieces: int
    area_m2: float

    @property
    def edge_manifold(self) -> bool:
        return self.non_manifold_edges == 0

    @property
    def watertight(self) -> bool:
        return self.non_manifold_edges == 0 and self.boundary_edges == 0 and self.triangles > 0

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["edge_manifold"] = self.edge_manifold
        out["watertight"] = self.watertight
        return out


def mesh_quality(mesh: TriangleMesh) -> MeshQuality:
    """The counts of :class:`MeshQuality` for ``mesh``."""
    t = mesh.triangles
    if len(t) == 0:
        return MeshQuality(len(mesh.vertices), 0, 0, 0, 0, 0, 0, 0.0)
    edges, counts = edge_use_counts(t)
    areas = mesh.triangle_areas()
    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 0] == t[:, 2])
    pieces = int(triangle_components(t, len(mesh.vertices)).max() + 1)
    return MeshQuality(
        vertices=len(mesh.vertices),
        triangles=len(t),
        edges=len(edges),
        boundary_edges=int((counts == 1).sum()),
        non_manifold_edges=int((counts > 2).sum()),
        degenerate_triangles=int((repeated | (areas <= 0)).sum()),
        pieces=pieces,
        area_m2=float(areas.sum()),
    )
