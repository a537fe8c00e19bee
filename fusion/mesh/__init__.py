"""Meshes with a triangle budget from merged Gaussian sets (screened Poisson, trimming, quadric decimation, export).

Entry point: :func:`fusion.mesh.pipeline.mesh_from_gaussians`; files: :func:`fusion.mesh.export.write_mesh`; options:
:mod:`fusion.mesh.options`. The names are imported lazily (:func:`core.lazy.lazy_exports`): importing the package or
its options does not load numba, scipy or open3d. The decimation function is ``fusion.mesh.decimate.decimate`` (the
package's attribute ``decimate`` is that submodule).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from core.lazy import lazy_exports

if TYPE_CHECKING:
    from fusion.mesh.export import read_mesh, write_mesh
    from fusion.mesh.options import (
        DecimateOptions,
        Decimator,
        MeshOptions,
        MeshSource,
        NormalFallback,
        OrientedPointOptions,
        PoissonOptions,
        SnapshotOptions,
    )
    from fusion.mesh.oriented_points import oriented_points_from_gaussians
    from fusion.mesh.pipeline import MeshResult, mesh_from_gaussians
    from fusion.mesh.poisson import poisson_reconstruct, trim_mesh
    from fusion.mesh.quality import MeshQuality, mesh_quality
    from fusion.mesh.transparent import snapshot_union
    from fusion.mesh.types import MeshWarning, OrientedPoints, TriangleMesh

#: name -> submodule that defines it
_EXPORTS: dict[str, str] = {
    "DecimateOptions": "options",
    "Decimator": "options",
    "MeshOptions": "options",
    "MeshQuality": "quality",
    "MeshResult": "pipeline",
    "MeshSource": "options",
    "MeshWarning": "types",
    "NormalFallback": "options",
    "OrientedPointOptions": "options",
    "OrientedPoints": "types",
    "PoissonOptions": "options",
    "SnapshotOptions": "options",
    "TriangleMesh": "types",
    "mesh_from_gaussians": "pipeline",
    "mesh_quality": "quality",
    "oriented_points_from_gaussians": "oriented_points",
    "poisson_reconstruct": "poisson",
    "read_mesh": "export",
    "snapshot_union": "transparent",
    "trim_mesh": "poisson",
    "write_mesh": "export",
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
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
    "mesh_from_gaussians",
    "mesh_quality",
    "oriented_points_from_gaussians",
    "poisson_reconstruct",
    "read_mesh",
    "snapshot_union",
    "trim_mesh",
    "write_mesh",
]
