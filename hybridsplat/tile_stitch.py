"""Stitching the tiles' products into the parent project, by core ownership (issue 34).

Every product a tile makes that has positions (the fused cloud, the classified cloud, the trained and the cleaned
splats) is a PLY of one ``vertex`` element whose ``x, y, z`` are in the parent's local frame (the tiles share it).
A row is kept only by the tile whose core holds its position (:meth:`recon.tiling.TilePlan.owner`: half-open cores,
the outer sides open), so the stitched file has no duplicate from an overlap and loses nothing; rows are copied byte
for byte, in tile order. The fused cloud's ``.vis`` is carried along, its positions re-indexed from the tile's
registered photos to the parent's (photo ids are the parent's in every tile, :mod:`recon.tile_models`).

The parent's dense workspace is its own undistortion of every registered photo (what the untiled ``mvs`` stage
makes; evaluation and the background and appearance layers read it) plus each photo's depth and normal maps from the
first tile (in plan order) that computed them, so that the parent's ``masks`` stage reads depth as it would untiled.

Written here, not with :func:`recon.tiling.stitch_by_core`: that one stitches arrays in memory; these are files of
arbitrary fields whose bytes must survive (one structured array per file, no conversion).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import DataError
from recon.tiling import TilePlan


@dataclass(frozen=True)
class StitchCounts:
    """Rows kept in the stitched file and rows each part gave up (to a neighbour's core or outside every core)."""

    kept: int
    dropped: tuple[int, ...]


def _vertex_rows(path: Path) -> np.ndarray:
    import plyfile

    from core.io.ply import load_ply_data

    data: plyfile.PlyData = load_ply_data(path)
    names = [e.name for e in data.elements]
    if names != ["vertex"]:
        raise DataError(f"expected one 'vertex' element to stitch, found {names}", path)
    rows = data["vertex"].data
    for axis in ("x", "y", "z"):
        if axis not in rows.dtype.names:
            raise DataError(f"the vertex element has no {axis!r} property", path)
    return rows


def owned_rows(plan: TilePlan, tile: int, rows: np.ndarray) -> np.ndarray:
    """(N,) bool: the rows (a PLY vertex array with x, y, z in the local frame) whose position tile ``tile``'s
    core holds."""
    positions = np.stack([rows["x"], rows["y"], rows["z"]], axis=1).astype(np.float64)
    return plan.owner(positions) == tile


def stitch_ply(
    plan: TilePlan, parts: Sequence[tuple[int, Path]], out: str | PathLike[str]
) -> tuple[StitchCounts, list[np.ndarray]]:
    """Stitch the PLY files ``parts`` ((tile index, path), in plan order) into ``out`` (written atomically, with
    the first part's origin sidecar). Returns the counts and each part's kept-row mask."""
    import plyfile

    from core.io.atomic import atomic_path

    arrays, masks = [], []
    for tile, path in parts:
        rows = _vertex_rows(Path(path))
        if arrays and rows.dtype != arrays[0].dtype:
            raise DataError(f"its properties {rows.dtype.names} differ from the first tile's", path)
        own = owned_rows(plan, tile, rows)
        arrays.append(rows[own])
        masks.append(own)
    if not arrays:
        raise DataError("nothing to stitch: no tile made this product", Path(out))
    stitched = np.concatenate(arrays)
    with atomic_path(out) as tmp:
        plyfile.PlyData([plyfile.PlyElement.describe(stitched, "vertex")], text=False, byte_order="<").write(str(tmp))
    _copy_sidecar(Path(parts[0][1]), Path(out))
    counts = StitchCounts(len(stitched), tuple(int((~m).sum()) for m in masks))
    return counts, masks


def _copy_sidecar(source: Path, target: Path) -> None:
    from core.io.origin import read_crs, read_origin, remove_origin, sidecar_path, write_origin

    if sidecar_path(source).is_file():
        write_origin(target, read_origin(source), read_crs(source))
    else:
        remove_origin(target)


def stitch_fused(plan: TilePlan, tiles: Sequence[tuple[int, Path]], parent_dense: Path) -> StitchCounts:
    """The parent's ``fused.ply`` and ``fused.ply.vis`` from the tiles' dense workspaces ((tile, dense dir) in plan
    order); ``parent_dense`` already holds the parent's undistorted workspace (its ``sparse/`` orders the .vis)."""
    import pycolmap

    from core.io.colmap_vis import read_vis, write_vis
    from recon.workspace import DenseWorkspace

    parent = DenseWorkspace(parent_dense)
    parent_ids = [int(i) for i in pycolmap.Reconstruction(str(parent.sparse)).reg_image_ids()]
    position_of = {image_id: k for k, image_id in enumerate(parent_ids)}
    parts = [(t, DenseWorkspace(d).fused_ply) for t, d in tiles]
    counts, masks = stitch_ply(plan, parts, parent.fused_ply)
    visibility: list[np.ndarray] = []
    for (tile, dense), own in zip(tiles, masks, strict=True):
        ws = DenseWorkspace(dense)
        tile_ids = np.array([int(i) for i in pycolmap.Reconstruction(str(ws.sparse)).reg_image_ids()], np.int64)
        to_parent = np.array([position_of.get(int(i), -1) for i in tile_ids], np.int64)
        if (to_parent < 0).any():
            raise DataError(f"tile {plan.tiles[tile].name} has photos the parent's dense model lacks", ws.sparse)
        vis = read_vis(ws.fused_vis, len(own))
        visibility += [to_parent[np.asarray(v, np.int64)] for v, keep in zip(vis, own.tolist(), strict=True) if keep]
    write_vis(parent.fused_vis, visibility)
    return counts


def gather_depth_maps(tiles: Sequence[Path], parent_dense: Path) -> int:
    """Each photo's depth and normal maps (and the fusion list) into the parent's ``stereo/``, from the first of the
    tiles' dense workspaces (in plan order) that has them: hard links where the file system allows, else copies.
    Returns the number of photos with maps."""
    from recon.workspace import DenseWorkspace

    parent = DenseWorkspace(parent_dense)
    parent.make_dirs()
    done: set[str] = set()
    fused: list[str] = []
    for dense in tiles:
        ws = DenseWorkspace(dense)
        for name in ws.fused_names() or []:
            if name not in fused:
                fused.append(name)
        for path in sorted((ws.stereo / "depth_maps").glob("*.bin")):
            photo, kind = path.name.split(".")[:-2], path.name.split(".")[-2]
            name = ".".join(photo)
            if name in done or ws.map_kind(name) != kind:
                continue
            _link(path, parent.depth_map(name, kind))
            _link(ws.normal_map(name, kind), parent.normal_map(name, kind))
            done.add(name)
    parent.write_fusion_cfg(sorted(fused))
    return len(done)


def _link(source: Path, target: Path) -> None:
    if target.exists():
        target.unlink()
    try:
        os.link(source, target)
    except OSError:
        shutil.copyfile(source, target)
