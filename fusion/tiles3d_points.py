"""The survey points and a triangle mesh beside the splats of a 3D Tiles tileset (:mod:`fusion.tiles3d`).

:func:`fusion.tiles3d.write_splat_tileset` takes, besides the Gaussians, optional ``points`` (a
:class:`core.pointcloud.PointCloud`, or a point-cloud file read with its origin sidecar, e.g. export/merged_points.ply)
and an optional ``mesh`` (a ``.glb`` written by :func:`fusion.mesh.export.write_mesh`, e.g. export/mesh.glb, read with
its ``mesh.origin.json`` sidecar). Each becomes one more subtree of the root, beside the splat layers::

    survey_points/r.glb, survey_points/r01.glb, …   glTF 2.0 POINTS primitives (POSITION float32, COLOR_0 RGBA8)
    survey_points/tileset.json                      the points alone (when ``layer_tilesets``), same transform
    mesh/mesh.glb                                   one TRIANGLES primitive (POSITION, COLOR_0 RGBA8, uint32 indices)
    mesh/tileset.json                               the mesh alone (when ``layer_tilesets``), same transform

Frame: positions are converted exactly as the splat means are (:meth:`fusion.tiles3d.TileFrame.positions`: ``exact``
placement through pyproj per point and per vertex, ``grid`` and no CRS as local offsets), after re-expressing them in
float64 about the splats' origin (a different origin of the points or of the mesh is therefore exact). The GLB node
matrix is the same z-up → y-up turn as the splat tiles' (:data:`fusion.gltf_splats.Z_UP_TO_Y_UP`), so POSITION values
are tile-frame coordinates. Points are tiled by the splats' k-d builder (at most ``max_splats_per_tile`` per leaf,
boxes enclosing the float32 positions, half-sizes ≥ 1 mm); the mesh is one tile (no levels of detail). Materials are
``KHR_materials_unlit`` (colours as measured: photographs already hold the light).

Layers: metadata groups "survey points" and "mesh" (``layer`` class, ``kind`` ``points`` / ``mesh``; they have no
``source`` code, the splat layers' ``kind`` is ``splats``). CesiumJS decides per tileset, not per content, whether
its glTF contents are splats (``GaussianSplat3DTileContent.tilesetRequiresGaussianSplattingExt``: the splat extensions
required by ``3DTILES_content_gltf``, the SPZ default here), so it may not draw the points and the mesh of the
combined tileset (not checked in CesiumJS): load ``survey_points/tileset.json`` and ``mesh/tileset.json``, which
require no splat extension, as separate tilesets there. loaders.gl reads the combined tileset as it is (tested).

A points/mesh file without a CRS in its sidecar (or without a sidecar: origin zero) is taken to be in the splats'
CRS. Bad input: an empty or non-finite point set, a mesh that is not a GLB, a points/mesh file whose sidecar names
another CRS (or one while the splats have none), or points/vertices farther than :data:`MAX_LAYER_DISTANCE_M` from
the splats' origin (a missing or wrong origin sidecar) raise :class:`DataError` / :class:`ConfigError` naming the
file.
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import ConfigError, DataError, FormatError, InputFileError
from core.io.atomic import remove_output, write_bytes_atomic
from core.io.json_io import write_json_atomic
from core.pointcloud import PointCloud
from fusion.gltf_splats import Z_UP_TO_Y_UP, generator
from fusion.tiles3d import (
    LayerRecord,
    TileFrame,
    TileNode,
    TileRecord,
    build_tree,
    leaf_nodes,
    remove_stale_tiles,
    tile_box,
    tile_json,
)

POINTS_LAYER, POINTS_FOLDER = "survey points", "survey_points"
MESH_LAYER, MESH_FOLDER, MESH_TILE = "mesh", "mesh", "mesh"
KINDS = {POINTS_LAYER: "points", MESH_LAYER: "mesh"}
"""``kind`` metadata of the non-splat layers (splat layers: ``splats``)."""

MAX_LAYER_DISTANCE_M = 100_000.0
"""Farthest a point or mesh vertex may lie from the splats' origin (metres): beyond, its origin sidecar is missing
or belongs to other data (a UTM mesh without its sidecar lies ~5 000 km away)."""

UNLIT = "KHR_materials_unlit"
_FLOAT, _UBYTE, _UINT = 5126, 5121, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_POINTS, _TRIANGLES = 0, 4


@dataclass
class ExtraLayer:
    """A non-splat layer ready to write: metadata name, folder, k-d tree (leaf paths name the files; boxes in the
    tile frame), GLB bytes per leaf path, count (points or mesh vertices)."""

    name: str
    folder: str
    tree: TileNode
    files: dict[str, bytes]
    count: int


def _source_path(item: Any) -> Path | None:
    return Path(item) if isinstance(item, (str, PathLike)) else None


def _check_crs(path: Path, crs: str | None) -> None:
    """Refuse a file whose origin sidecar names a CRS other than the tileset's."""
    from core.io.origin import read_crs

    theirs = read_crs(path)
    if theirs is None:
        return
    if crs is None:
        raise ConfigError(f"its origin sidecar names CRS {theirs!r}, but the tileset has no CRS", path)
    import pyproj

    try:
        same = pyproj.CRS.from_user_input(theirs) == pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError:
        same = theirs == crs
    if not same:
        raise ConfigError(f"its origin sidecar names CRS {theirs!r}, the splats are in {crs!r}: reproject first", path)


def _local(world_offsets: np.ndarray, own_origin: np.ndarray, origin: np.ndarray, name: Any) -> np.ndarray:
    """(N, 3) float64 offsets about the splats' ``origin`` of offsets about ``own_origin``; checks finiteness and
    distance."""
    if not (np.isfinite(world_offsets).all() and np.isfinite(own_origin).all()):
        raise DataError("positions or origin hold NaN or infinite values", name)
    local = world_offsets + (own_origin - origin)
    far = float(np.abs(local).max())
    if far > MAX_LAYER_DISTANCE_M:
        raise DataError(
            f"lies up to {far / 1000:.1f} km from the splats' origin {origin.tolist()} (its own origin "
            f"{own_origin.tolist()}): a missing or wrong origin sidecar? (limit {MAX_LAYER_DISTANCE_M / 1000:.0f} km)",
            name,
        )
    return local


def points_layer(
    points: PointCloud | str | PathLike[str],
    origin: np.ndarray,
    crs: str | None,
    frame: TileFrame,
    max_n: int,
    out: Path,
) -> ExtraLayer:
    """The survey points as k-d tiled POINTS GLBs in the tile frame (``origin``: the splats' world origin)."""
    path = _source_path(points)
    if path is not None:
        from core.io import read_point_cloud

        if not path.is_file():
            raise InputFileError("survey points file does not exist", path)
        _check_crs(path, crs)
        points = read_point_cloud(path)
    if not isinstance(points, PointCloud):
        raise ConfigError(f"points must be a PointCloud or a point-cloud file, got {type(points).__name__}", out)
    name = path or out
    if len(points) == 0:
        raise DataError("the survey points are empty: nothing to tile", name)
    local = _local(points.positions, points.origin, origin, name)
    pos = frame.positions(local).astype(np.float32)
    colors = None if points.colors is None else np.c_[points.colors, np.full(len(points), 255, np.uint8)]
    tree = build_tree(pos.astype(np.float64), np.zeros_like(pos, np.float64), np.arange(len(pos)), max_n)
    files = {}
    for leaf in leaf_nodes(tree):
        index = leaf.index if leaf.index is not None else np.zeros(0, np.int64)
        files[leaf.path] = encode_glb(
            pos[index],
            None if colors is None else colors[index],
            None,
            f"{POINTS_FOLDER}/{leaf.path}",
            {"layer": POINTS_LAYER, "tile": leaf.path},
        )
    return ExtraLayer(POINTS_LAYER, POINTS_FOLDER, tree, files, len(points))


def mesh_layer(mesh: str | PathLike[str], origin: np.ndarray, crs: str | None, frame: TileFrame) -> ExtraLayer:
    """The mesh (a GLB with its origin sidecar) as one TRIANGLES GLB in the tile frame."""
    from fusion.mesh.export import read_mesh

    path = Path(mesh)
    if path.suffix.lower() != ".glb":
        raise ConfigError(f"the tileset's mesh must be a .glb (export/mesh.glb), got {path.suffix!r}", path)
    if not path.is_file():
        raise InputFileError("mesh file does not exist", path)
    with path.open("rb") as fh:
        if fh.read(4) != b"glTF":
            raise DataError("not a GLB file (no 'glTF' magic)", path)
    _check_crs(path, crs)
    try:
        triangle_mesh = read_mesh(path)
    except (DataError, ConfigError, FormatError, InputFileError):
        raise
    except Exception as err:  # trimesh's own errors on a malformed GLB
        raise DataError(f"cannot read the mesh ({type(err).__name__}: {err})", path) from None
    if triangle_mesh.num_triangles == 0:
        raise DataError("the mesh has no triangles", path)
    local = _local(np.asarray(triangle_mesh.vertices, np.float64), triangle_mesh.origin, origin, path)
    pos = frame.positions(local).astype(np.float32)
    colors = None
    if triangle_mesh.vertex_colors is not None:
        rgb = np.clip(np.rint(np.asarray(triangle_mesh.vertex_colors, np.float64) * 255.0), 0, 255).astype(np.uint8)
        colors = np.c_[rgb, np.full(len(rgb), 255, np.uint8)]
    faces = np.asarray(triangle_mesh.triangles, np.uint32)
    data = encode_glb(pos, colors, faces, MESH_FOLDER, {"layer": MESH_LAYER, "source_file": path.name})
    f64 = pos.astype(np.float64)
    tree = TileNode(MESH_TILE, f64.min(axis=0), f64.max(axis=0), index=np.arange(len(pos)))
    return ExtraLayer(MESH_LAYER, MESH_FOLDER, tree, {MESH_TILE: data}, len(pos))


def encode_glb(
    positions: np.ndarray,
    colors: np.ndarray | None,
    triangles: np.ndarray | None,
    name: str,
    extras: dict[str, Any],
) -> bytes:
    """A GLB of one unlit primitive: ``positions`` (N, 3) float32 in the tile frame (z-up; the node turns it y-up),
    ``colors`` (N, 4) uint8 RGBA or None, ``triangles`` (M, 3) vertex indices (TRIANGLES) or None (POINTS)."""
    import pygltflib as gl

    columns: list[tuple[str | None, np.ndarray, str, int, int]] = [
        ("POSITION", np.ascontiguousarray(positions, "<f4"), "VEC3", _FLOAT, _ARRAY_BUFFER)
    ]
    if colors is not None:
        columns.append(("COLOR_0", np.ascontiguousarray(colors, "<u1"), "VEC4", _UBYTE, _ARRAY_BUFFER))
    if triangles is not None:
        columns.append(
            (None, np.ascontiguousarray(triangles, "<u4").reshape(-1), "SCALAR", _UINT, _ELEMENT_ARRAY_BUFFER)
        )
    blob, accessors, views, attributes = bytearray(), [], [], {}
    for semantic, values, kind, component, target in columns:
        data = values.tobytes()
        views.append(gl.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        acc = gl.Accessor(bufferView=len(views) - 1, componentType=component, count=len(values), type=kind)
        if semantic == "COLOR_0":
            acc.normalized = True
        if semantic == "POSITION":  # glTF requires the exact bounds of POSITION
            acc.min = [float(v) for v in values.min(axis=0)]
            acc.max = [float(v) for v in values.max(axis=0)]
        accessors.append(acc)
        if semantic is not None:
            attributes[semantic] = len(accessors) - 1
        blob += data + b"\0" * (-len(data) % 4)
    primitive = gl.Primitive(attributes=gl.Attributes(**attributes), mode=_POINTS, material=0)
    if triangles is not None:
        primitive.mode, primitive.indices = _TRIANGLES, len(accessors) - 1
    material = gl.Material(
        pbrMetallicRoughness=gl.PbrMetallicRoughness(metallicFactor=0.0, roughnessFactor=1.0),
        doubleSided=True,
        extensions={UNLIT: {}},
    )
    doc = gl.GLTF2(
        asset=gl.Asset(version="2.0", generator=generator(), extras=extras),
        extensionsUsed=[UNLIT],
        scene=0,
        scenes=[gl.Scene(nodes=[0])],
        nodes=[gl.Node(name=name, mesh=0, matrix=list(Z_UP_TO_Y_UP))],
        meshes=[gl.Mesh(name=name, primitives=[primitive])],
        materials=[material],
        accessors=accessors,
        bufferViews=views,
        buffers=[gl.Buffer(byteLength=len(blob))],
    )
    doc.set_binary_blob(bytes(blob))
    return b"".join(doc.save_to_bytes())


def write_extra_layers(
    layers: list[ExtraLayer],
    folder: Path,
    first_group: int,
    layer_tileset: Any,
) -> tuple[list[TileRecord], list[LayerRecord], list[tuple[str, int | None, dict[str, Any]]]]:
    """Write each layer's GLBs (and, through ``layer_tileset(name, subtree) -> relative path or None``, its own
    tileset); returns tile and layer records and the root's subtrees (name, None, tile). Inside the caller's
    transaction; stale files of layers not written now are removed."""
    tiles: list[TileRecord] = []
    records: list[LayerRecord] = []
    subtrees: list[tuple[str, int | None, dict[str, Any]]] = []
    for group, layer in enumerate(layers, start=first_group):
        written: dict[str, int] = {}
        for leaf in leaf_nodes(layer.tree):
            data = layer.files[leaf.path]
            write_bytes_atomic(folder / layer.folder / f"{leaf.path}.glb", data)
            written[f"{leaf.path}.glb"] = len(data)
            count = len(leaf.index)  # type: ignore[arg-type]
            uri = f"{layer.folder}/{leaf.path}.glb"
            tiles.append(TileRecord(uri, layer.name, count, len(data), tuple(tile_box(leaf.lo, leaf.hi))))
        subtrees.append((layer.name, None, tile_json(layer.tree, f"{layer.folder}/", group)))
        own = layer_tileset(layer.name, tile_json(layer.tree, "", 0))
        if layer.folder == POINTS_FOLDER:
            remove_stale_tiles(folder / layer.folder, set(written), keep_tileset=own is not None)
        elif own is None and (folder / layer.folder / "tileset.json").is_file():
            remove_output(folder / layer.folder / "tileset.json")
        kind = KINDS[layer.name]
        records.append(LayerRecord(layer.name, None, layer.count, len(written), sum(written.values()), own, kind))
    present = {layer.folder for layer in layers}
    if POINTS_FOLDER not in present:
        remove_stale_tiles(folder / POINTS_FOLDER, set(), keep_tileset=False)
    if MESH_FOLDER not in present:
        for stale in (folder / MESH_FOLDER / f"{MESH_TILE}.glb", folder / MESH_FOLDER / "tileset.json"):
            if stale.is_file():
                remove_output(stale)
    return tiles, records, subtrees


def layer_tileset_writer(folder: Path, tileset_json: Any, enabled: bool) -> Any:
    """``layer_tileset(name, subtree)`` for :func:`write_extra_layers`: writes ``<folder>/tileset.json`` of one
    non-splat layer (``tileset_json(layers, gltf, note)``, glTF extensions: unlit only; ``note``: the content's
    description for ``asset.extras.glTF``) and returns its relative path."""

    def write(name: str, subtree: dict[str, Any]) -> str | None:
        if not enabled:
            return None
        points = name == POINTS_LAYER
        relative = f"{POINTS_FOLDER if points else MESH_FOLDER}/tileset.json"
        note = f"glTF 2.0 {'POINTS' if points else 'TRIANGLES'} ({UNLIT}), see fusion/tiles3d_points.py"
        write_json_atomic(folder / relative, tileset_json([(name, None, subtree)], {"extensionsUsed": [UNLIT]}, note))
        return relative

    return write
