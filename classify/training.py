"""Training from reconstructed projects and their labels (what ``hybridsplat classify train`` does)."""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from classify.classes import UNLABELLED, load_classes
from classify.features import FeatureOptions, FeatureTable, compute_features, views_from_workspace
from classify.labels import labels_from_field, labels_from_masks, scene_point_truth, transfer_labels
from classify.model import ForestOptions, TrainingReport, save_model, spatial_groups, train
from core.errors import ConfigError, DataError, InputFileError


def train_from_projects(
    dense_dirs: list[Path],
    out: str | PathLike[str],
    scenes: list[Path] | None = None,
    labels_file: Path | None = None,
    field: str = "classification",
    las_codes: bool = True,
    label_masks: Path | None = None,
    classes_toml: Path | None = None,
    feature_names: tuple[str, ...] | None = None,
    max_distance: float = 0.0,
    trees: int = 32,
    max_depth: int | None = 14,
    seed: int = 0,
    tau_gsd: float = 3.0,
) -> TrainingReport:
    """Features of each dense workspace's fused cloud, labels from exactly one source, a forest saved to ``out``.

    Sources: ``scenes`` (one data_synth scene per workspace: truth labels), ``labels_file`` (a labelled cloud
    for a single workspace, transferred to the nearest fused points within ``max_distance`` metres, 0 = twice
    the point spacing), or ``label_masks`` (a folder of per-photo label images, for a single workspace).
    """
    from core.io import read_point_cloud
    from core.io.colmap import read_model
    from core.io.images import read_image
    from recon.workspace import read_fused

    sources = sum(x is not None and x != [] for x in (scenes or None, labels_file, label_masks))
    if sources != 1:
        raise ConfigError("give exactly one label source: --scene (per project), --labels-file or --label-masks")
    if scenes and len(scenes) != len(dense_dirs):
        raise ConfigError(f"{len(scenes)} scenes for {len(dense_dirs)} projects: give one --scene per project")
    if (labels_file is not None or label_masks is not None) and len(dense_dirs) != 1:
        raise ConfigError("--labels-file and --label-masks label a single project")
    classes = load_classes(classes_toml)
    options = FeatureOptions(names=feature_names, geometric=FeatureOptions().geometric)
    tables: list[FeatureTable] = []
    labels: list[np.ndarray] = []
    blocks: list[np.ndarray] = []
    for i, dense in enumerate(dense_dirs):
        cloud = read_fused(dense)
        table = compute_features(cloud, options, views_from_workspace(dense))
        if scenes:
            from data_synth import load_scene

            y = scene_point_truth(cloud, load_scene(scenes[i]), classes, tau_gsd).codes
        elif labels_file is not None:
            labelled = read_point_cloud(labels_file)
            if field not in labelled.fields:
                raise DataError(f"no field {field!r} (fields: {', '.join(labelled.fields) or 'none'})", labels_file)
            codes = labels_from_field(labelled.fields[field], classes, las_codes)
            dist = max_distance if max_distance > 0 else 2.0 * table.spacing
            y = transfer_labels(labelled.with_origin(cloud.origin).positions, codes, cloud.positions, dist)
        else:
            assert label_masks is not None
            if not label_masks.is_dir():
                raise InputFileError("label-mask folder does not exist", label_masks)
            cams, _ = read_model(Path(dense) / "sparse")
            masks = {}
            for v in cams:
                stem = Path(v.name).stem
                for cand in (label_masks / f"{v.name}.png", label_masks / v.name, label_masks / f"{stem}.png"):
                    if cand.is_file():
                        masks[v.name] = read_image(cand, grayscale=True)
                        break
            if not masks:
                raise InputFileError("no label image matches a photo of the project (NAME.png)", label_masks)
            y = labels_from_masks(cloud.positions, cams, masks, cloud.visibility)
        tables.append(table)
        labels.append(y)
        # Held-out blocks of 16 point spacings, a separate range per project (see classify.model.train).
        blocks.append(spatial_groups(cloud.positions, 16.0 * table.spacing, i * 10**8))
    table = FeatureTable(tables[0].names, np.concatenate([t.values for t in tables]), tables[0].spacing)
    y = np.concatenate(labels)
    if np.all(y == UNLABELLED):
        raise DataError("no point received a label")
    info = {"projects": [str(d) for d in dense_dirs], "scenes": [str(s) for s in scenes or []], "seed": seed}
    forest = ForestOptions(n_estimators=trees, max_depth=max_depth, seed=seed)
    model, report = train(table, y, classes, options, forest, info=info, groups=np.concatenate(blocks))
    per_class = {c.name: c.f1 for c in report.per_class}
    model.info["report"] = {"needs_splats_f1": report.binary.f1, "per_class_f1": per_class}
    save_model(model, out)
    return report
