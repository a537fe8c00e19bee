"""Mesh files: PLY, OBJ and GLB written through trimesh, atomically, georeferenced like the clouds.

Vertex positions in every file are local (metres, relative to the mesh's float64 origin); a non-zero origin goes to the
``<name>.origin.json`` sidecar (:mod:`core.io.origin`; ``mesh.ply``, ``mesh.obj`` and ``mesh.glb`` share
``mesh.origin.json``), so world = origin + file coordinates, as for the PLY clouds. Colours are 8-bit RGBA per vertex.

glTF is +Y up while survey data is +Z up: the GLB keeps the local Z-up positions in its buffer (so the sidecar still
applies to them) and puts the mesh under a node whose matrix turns Z-up into Y-up (x, y, z) → (x, z, −y), so game
engines and viewers show it upright. The origin is also written into the glTF scene's ``extras`` (``origin``,
``units``), and as a comment in PLY and OBJ headers, for tools that never see the sidecar.
"""

from __future__ import annotations

from enum import Enum
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import ConfigError, DataError
from core.io.atomic import atomic_path
from core.io.origin import remove_origin, write_origin
from fusion.mesh.types import TriangleMesh

Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
"""4×4 node matrix of the GLB: (x, y, z) → (x, z, −y)."""


class MeshFormat(str, Enum):
    PLY = "ply"
    OBJ = "obj"
    GLB = "glb"


def format_of(path: str | PathLike[str]) -> MeshFormat:
    """The mesh format from a file suffix (.ply, .obj, .glb); :class:`ConfigError` otherwise."""
    suffix = Path(path).suffix.lower().lstrip(".")
    try:
        return MeshFormat(suffix)
    except ValueError:
        raise ConfigError(f"unknown mesh format {suffix!r}: use .ply, .obj or .glb", path) from None


def _trimesh(mesh: TriangleMesh):  # -> trimesh.Trimesh
    import trimesh

    colors = None
    if mesh.vertex_colors is not None:
        rgb = np.clip(np.rint(mesh.vertex_colors.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
        colors = np.concatenate([rgb, np.full((len(rgb), 1), 255, np.uint8)], axis=1)
    return trimesh.Trimesh(mesh.vertices, mesh.triangles, vertex_colors=colors, process=False, validate=False)


def write_mesh(path: str | PathLike[str], mesh: TriangleMesh) -> Path:
    """Write ``mesh`` to ``path`` (format from the suffix) atomically, plus the origin sidecar when non-zero."""
    import trimesh

    target = Path(path)
    fmt = format_of(target)
    if mesh.num_triangles == 0:
        raise DataError("refusing to write a mesh without triangles", target)
    if not np.isfinite(mesh.vertices).all():
        raise DataError("mesh vertices hold NaN or infinite values", target)
    tm = _trimesh(mesh)
    origin_text = "origin " + " ".join(repr(float(v)) for v in mesh.origin) + " units m"
    if fmt is MeshFormat.GLB:
        scene = trimesh.Scene()
        scene.add_geometry(tm, node_name="mesh", geom_name="mesh", transform=Z_UP_TO_Y_UP)
        scene.metadata["origin"] = [float(v) for v in mesh.origin]
        scene.metadata["units"] = "m"
        data = scene.export(file_type="glb")
    elif fmt is MeshFormat.PLY:
        data = trimesh.exchange.ply.export_ply(tm, encoding="binary", vertex_normal=False)
        # a comment line right after the "format" line: readers ignore it, the origin stays visible
        magic, fmt_line, rest = data.split(b"\n", 2)
        data = b"\n".join([magic, fmt_line, f"comment {origin_text}".encode("ascii"), rest])
    else:
        text = trimesh.exchange.obj.export_obj(tm, include_normals=False, include_color=True, include_texture=False)
        data = f"# {origin_text}\n{text}".encode()
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)
    if np.any(mesh.origin != 0):
        write_origin(target, mesh.origin)
    else:
        remove_origin(target)
    return target


def read_mesh(path: str | PathLike[str]) -> TriangleMesh:
    """Read a mesh written by :func:`write_mesh` (or any PLY/OBJ/GLB trimesh reads) with its origin sidecar.

    GLB node transforms are applied and the Z-up → Y-up turn undone, so vertices come back in the local Z-up frame.
    """
    import trimesh

    from core.io.origin import read_origin

    p = Path(path)
    fmt = format_of(p)
    if not p.is_file():
        from core.errors import InputFileError

        raise InputFileError("mesh file does not exist", p)
    loaded = trimesh.load(
        str(p), file_type=fmt.value, process=False, force="mesh" if fmt is not MeshFormat.GLB else None
    )
    if isinstance(loaded, trimesh.Scene):
        loaded = loaded.to_mesh() if hasattr(loaded, "to_mesh") else loaded.dump(concatenate=True)
        loaded.apply_transform(np.linalg.inv(Z_UP_TO_Y_UP))
    colors = None
    vc = getattr(loaded.visual, "vertex_colors", None)
    if vc is not None and len(vc) == len(loaded.vertices):
        colors = np.asarray(vc, dtype=np.float64)[:, :3] / 255.0
    return TriangleMesh(np.asarray(loaded.vertices), np.asarray(loaded.faces), read_origin(p), colors)
