"""A tile's COLMAP model: the parent's sparse model restricted to one tile's photos and points (issue 34).

A tiled run (:mod:`hybridsplat.stages.tiles`) gives each tile a project of its own whose ``sparse/`` is written here:
the photos of the tile (:attr:`recon.tiling.Tile.photo_ids`, without the held-out ones, which never take part in
depth estimation or training), their cameras as they are (same ids, poses and intrinsics: the tile lives in the
parent's local frame, so its products stitch back without a transform), and the sparse points that at least two of
those photos see, wherever they lie: MVS takes each photo's depth range and its source photos from them, so a photo
gets the same range and sources as in the untiled run (points inside the tile's bounds only would leave a photo
that looks mostly beyond the tile without a range). Image ids are kept: a tile's ``fused.ply.vis`` maps back to
the parent's photos by id.

pycolmap does the restriction (``deregister_frame``, ``delete_point3D``); a deregistered photo is not written.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

from core.errors import DataError
from recon.tiling import TilePlan


@dataclass(frozen=True)
class TileModelCounts:
    """What a tile's model holds: its photos (registered images) and sparse points."""

    photos: int
    points: int


def write_tile_model(
    parent_sparse: str | PathLike[str],
    out_dir: str | PathLike[str],
    plan: TilePlan,
    tile: int,
    exclude_names: Collection[str] = (),
) -> TileModelCounts:
    """Write tile ``tile``'s model into ``out_dir`` (a COLMAP binary model; the folder is created).

    parent_sparse: the parent project's sparse model, positions in the plan's local frame (metres).
    exclude_names: photo names left out (the held-out photos). Raises :class:`DataError` when the tile keeps no
    photo, or fewer than two (nothing to match depth between).
    """
    import pycolmap

    rec = pycolmap.Reconstruction(str(parent_sparse))
    keep = {int(i) for i in plan.tiles[tile].photo_ids}
    excluded = set(exclude_names)
    for image_id in sorted(int(i) for i in rec.reg_image_ids()):
        if image_id not in keep or rec.image(image_id).name in excluded:
            rec.deregister_frame(rec.image(image_id).frame_id)
    name = plan.tiles[tile].name
    if rec.num_reg_images() < 2:
        raise DataError(f"tile {name} keeps {rec.num_reg_images()} photo(s): at least 2 are needed for depth")
    for pid in sorted(int(i) for i in rec.point3D_ids()):
        if rec.point3D(pid).track.length() < 2:
            rec.delete_point3D(pid)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rec.write(str(out))
    return TileModelCounts(photos=int(rec.num_reg_images()), points=int(rec.num_points3D()))
