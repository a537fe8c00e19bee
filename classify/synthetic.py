"""Training data from a data_synth scene and its reconstruction: features of the fused cloud + truth labels."""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from classify.classes import ClassSet
from classify.features import FeatureOptions, FeatureTable, compute_features, views_from_workspace
from classify.labels import PointTruth, scene_point_truth
from core.io.atomic import atomic_path
from core.pointcloud import PointCloud


@dataclass
class SceneData:
    """One reconstructed synthetic scene: the fused ``cloud``, its feature ``table``, the point ``truth``, the
    ``scene`` (:class:`data_synth.Scene`) and the ``dense`` workspace folder."""

    cloud: PointCloud
    table: FeatureTable
    truth: PointTruth
    scene: object
    dense: Path


def load_scene_data(
    scene_dir: str | PathLike[str],
    dense_dir: str | PathLike[str],
    classes: ClassSet,
    options: FeatureOptions = FeatureOptions(),
    tau_gsd: float = 3.0,
    cache: str | PathLike[str] | None = None,
) -> SceneData:
    """Features and truth of ``dense_dir/fused.ply`` for the scene in ``scene_dir`` (τ = ``tau_gsd`` × GSD).

    cache: an ``.npz`` file to reuse the feature table from (written when absent; it stores the names: a cache that
    holds every selected name is read and narrowed to them, one that lacks some is recomputed and rewritten).
    """
    from data_synth import load_scene
    from recon.workspace import read_fused

    scene = load_scene(scene_dir)
    dense = Path(dense_dir)
    cloud = read_fused(dense)
    names = options.selected()
    table = None
    if cache is not None and Path(cache).is_file():
        data = np.load(cache)
        cached = tuple(str(n) for n in data["names"])
        if set(names) <= set(cached) and len(data["values"]) == len(cloud):
            table = FeatureTable(cached, data["values"], float(data["spacing"])).select(names)
    if table is None:
        table = compute_features(cloud, options, views_from_workspace(dense))
        if cache is not None:
            Path(cache).parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(cache) as tmp, open(tmp, "wb") as f:
                np.savez(f, names=np.array(table.names), values=table.values, spacing=table.spacing)
    if table.neighbours is None:  # not cached: the finest neighbourhood, as compute_features finds it
        from dataclasses import replace

        from classify.features.geometric import level_neighbours

        _, neighbours = level_neighbours(cloud.positions, options.geometric.k, options.geometric)
        table = replace(table, neighbours=neighbours)
    truth = scene_point_truth(cloud, scene, classes, tau_gsd)
    return SceneData(cloud, table, truth, scene, dense)


BLOCK_SPACINGS = 16.0
"""Side of the spatial blocks held out together in training, in point spacings of each scene."""


def stack_scenes(
    datas: list[SceneData], names: tuple[str, ...], by_scene: bool = False, ignore_ambiguous: bool = False
) -> tuple[FeatureTable, np.ndarray, np.ndarray]:
    """The features ``names`` of several scenes as one table (with their neighbours, re-indexed), the truth codes
    (N,) uint8 and the groups (N,) int64 for training: the index of each row's scene (``by_scene``) or its
    spatial block (:func:`classify.model.spatial_groups`, a range per scene). ignore_ambiguous: the points of the
    truth's ignore band (:attr:`classify.labels.PointTruth.ambiguous`) get UNLABELLED, so that neither the forest
    nor the threshold choice sees them."""
    from classify.classes import UNLABELLED
    from classify.model import spatial_groups

    values, codes, blocks, neighbours = [], [], [], []
    offset = 0
    for i, d in enumerate(datas):
        values.append(d.table.select(names).values)
        scene_codes = d.truth.codes
        if ignore_ambiguous:
            scene_codes = np.where(d.truth.ambiguous, np.uint8(UNLABELLED), scene_codes)
        codes.append(scene_codes)
        if by_scene:
            blocks.append(np.full(len(d.table.values), i, dtype=np.int64))
        else:
            blocks.append(spatial_groups(d.cloud.positions, BLOCK_SPACINGS * d.table.spacing, i * 10**8))
        if d.table.neighbours is not None:
            neighbours.append(d.table.neighbours + offset)
        offset += len(d.table.values)
    nb = np.concatenate(neighbours) if len(neighbours) == len(datas) else None
    table = FeatureTable(tuple(names), np.concatenate(values), 0.0, nb)
    return table, np.concatenate(codes), np.concatenate(blocks)
