"""The neighbouring tiles' splats frozen as context in a tile's training (issue 34).

A tile trains its splats on photos that also see its overlap, which the neighbouring tile owns. Trained alone, each
tile fills the overlap with splats of its own that the stitch then drops; the splats it keeps near its core's
border were fitted beside content that is not in the stitched product. With context on, the tiles train in two
phases of a checkerboard (:func:`training_phases`): the first half trains alone; before a tile of the second half
trains, :func:`write_neighbour_splats` gives it the cleaned splats of its finished neighbours that lie in its bounds
and in their own cores (what the stitch will keep), frozen beside its MVS Gaussians. Diagonal neighbours train in
the same phase: they share only a corner of overlap. Two phases keep half the tiles training at once; a schedule
where every tile saw every neighbour would train the tiles of a 2 × 2 grid one after another.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence

from hybridsplat.layout import ProjectLayout
from recon.tiling import TilePlan


def training_phases(plan: TilePlan, tiles: Sequence[int]) -> list[list[int]]:
    """``tiles`` (plan indices) in the order they train: the checkerboard's even squares ((row + column) even),
    then the odd ones, each in plan order; a phase without tiles is left out."""
    phases: list[list[int]] = [[], []]
    for t in tiles:
        tile = plan.tiles[t]
        phases[(tile.row + tile.column) % 2].append(t)
    return [p for p in phases if p]


def write_neighbour_splats(parent: ProjectLayout, plan: TilePlan, tile: int, finished: Collection[int]) -> int:
    """Write tile ``tile``'s ``splats/neighbours.ply``: the cleaned splats of the ``finished`` tiles that lie in
    its bounds (core + overlap) and in their own tile's core; returns how many (0: the file is removed)."""
    from core.gaussians import GaussianSet
    from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply

    target = ProjectLayout(parent.tile_project(plan.tiles[tile].name)).neighbour_splats
    parts = []
    for other in sorted(finished):
        path = ProjectLayout(parent.tile_project(plan.tiles[other].name)).cleaned_splats
        if other == tile or not path.is_file():
            continue
        splats = read_gaussian_ply(path)
        keep = (plan.owner(splats.means) == other) & plan.in_bounds(splats.means, tile)
        if keep.any():
            parts.append(splats.subset(keep))
    if not parts:
        target.unlink(missing_ok=True)
        return 0
    neighbours = GaussianSet.concatenate(parts)
    write_gaussian_ply(target, neighbours)
    return len(neighbours)
