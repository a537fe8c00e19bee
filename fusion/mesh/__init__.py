"""Meshes with a triangle budget from merged Gaussian sets (screened Poisson, trimming, quadric decimation, export).

Entry point: :func:`fusion.mesh.pipeline.mesh_from_gaussians`; files: :func:`fusion.mesh.export.write_mesh`.
"""

from fusion.mesh.decimate import DecimateOptions, Decimator, decimate
from fusion.mesh.export import read_mesh, write_mesh
from fusion.mesh.oriented_points import NormalFallback, OrientedPointOptions, oriented_points_from_gaussians
from fusion.mesh.pipeline import MeshOptions, MeshResult, MeshSource, mesh_from_gaussians
from fusion.mesh.poisson import PoissonOptions, poisson_reconstruct, trim_mesh
from fusion.mesh.quality import MeshQuality, mesh_quality
from fusion.mesh.transparent import SnapshotOptions, snapshot_union
from fusion.mesh.types import MeshWarning, OrientedPoints, TriangleMesh

__all__ = [
    "DecimateOptions",
    "Decimator",
    "MeshOptions",
    "MeshQuality",
    "MeshResult",
    "MeshSource",
    "MeshWarning",
    "NormalFallback",
    "OrientedPointOptions",
    "OrientedPoints",
    "PoissonOptions",
    "SnapshotOptions",
    "TriangleMesh",
    "decimate",
    "mesh_from_gaussians",
    "mesh_quality",
    "oriented_points_from_gaussians",
    "poisson_reconstruct",
    "read_mesh",
    "snapshot_union",
    "trim_mesh",
    "write_mesh",
]
