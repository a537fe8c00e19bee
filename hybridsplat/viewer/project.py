"""The files of a project that the viewer and ``hybridsplat measure`` read, and where measurements go.

Paths follow DESIGN.md's project-folder contract. ``hybridsplat/layout.py`` (``ProjectLayout``) is to be the only
code spelling them; until it is on this branch, this one place does, and is to be replaced by the layout's
attributes (``sparse``, ``merged_ply``, ``fused_ply``, ``mesh_path(ext)``, ``export_dir``).
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path

from core.errors import InputFileError


@dataclass(frozen=True)
class ProjectFiles:
    """Inputs of the viewer / measurement in one project folder (any may be missing but ``sparse``).

    sparse: COLMAP model (local frame). merged: merged 3DGS PLY (its ``.origin.json`` sidecar gives origin, unit,
    CRS). fused: the MVS dense cloud. mesh: the exported mesh. test_sparse: held-out cameras, when the project
    keeps them. measurements_csv / distances_csv / geojson: where measurements are written.
    """

    root: Path
    sparse: Path
    merged: Path
    fused: Path
    mesh: Path
    measurements_csv: Path
    distances_csv: Path
    geojson: Path
    picks_json: Path

    @classmethod
    def of(cls, project: str | PathLike[str]) -> ProjectFiles:
        root = Path(project)
        if not root.is_dir():
            raise InputFileError("project folder does not exist" if not root.exists() else "is not a folder", root)
        export = root / "export"
        return cls(
            root=root,
            sparse=root / "sparse",
            merged=export / "merged.ply",
            fused=root / "dense" / "fused.ply",
            mesh=export / "mesh.ply",
            measurements_csv=export / "measurements.csv",
            distances_csv=export / "measurements_distances.csv",
            geojson=export / "measurements.geojson",
            picks_json=export / "picks.json",
        )
