"""Training from reconstructed projects and their labels (what ``hybridsplat classify train`` does), and the recipe
of the shipped default model: data_synth scenes, one fold per scene (``scripts/train_default_classifier.py``,
scored by ``bench/bench_classify.py``).

Nothing here knows the project layout: callers pass the dense workspace folders (``ProjectLayout(p).dense``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from os import PathLike
from pathlib import Path

import numpy as np

from classify.classes import UNLABELLED, ClassSet, load_classes
from classify.features import FeatureOptions, FeatureTable, compute_features, views_from_workspace
from classify.labels import labels_from_field, labels_from_masks, scene_point_truth, transfer_labels
from classify.model import (
    ClassifierModel,
    ClassScores,
    ForestOptions,
    TrainingReport,
    save_model,
    scores,
    spatial_groups,
    train,
)
from classify.synthetic import SceneData, stack_scenes
from core.errors import ConfigError, DataError, InputFileError
from core.pointcloud import PointCloud

# -- the default model's training scenes ----------------------------------------------------------------------
FULL_SIZE: tuple[str, ...] = ("--views", "24", "--test-views", "2", "--width", "320", "--height", "240")
"""``hybridsplat synth`` size arguments of the full-size training scenes (24 views at 320×240, 2 held out)."""
SMALL_SIZE: tuple[str, ...] = ("--views", "16", "--test-views", "2", "--width", "288", "--height", "216")
"""Size arguments of the smaller scenes: 16 requested views (the rigs make 18–20) at 288×216, so that the model
sees two sampling densities."""


@dataclass(frozen=True)
class SynthTrainingScene:
    """One data_synth training scene: ``preset``, ``seed`` and the ``hybridsplat synth`` size arguments."""

    preset: str
    seed: int
    synth_args: tuple[str, ...]

    @property
    def name(self) -> str:
        """The scene's folder in a training data folder: ``<preset>_s<seed>``."""
        return f"{self.preset}_s{self.seed}"

    def to_dict(self) -> dict[str, object]:
        """As recorded in a model's ``info["scenes"]``."""
        return {"preset": self.preset, "seed": self.seed, "synth_args": list(self.synth_args)}


DEFAULT_TRAINING_SCENES: tuple[SynthTrainingScene, ...] = tuple(
    SynthTrainingScene(preset, seed, FULL_SIZE if seed % 2 == 0 else SMALL_SIZE)
    for seed in range(48)
    for preset in ("random-object", "random-aerial")
)
"""The scenes the shipped model ``classify/models/default.skops`` is trained on, in order: procedural layouts
(``data_synth`` presets ``random-object`` and ``random-aerial``) of seeds 0–47, the even seeds at
:data:`FULL_SIZE`, the odd ones at :data:`SMALL_SIZE`. No scored scene shares a layout with them: the hand-built
layouts (``demo``, ``tabletop``, ``aerial``) are scored only, and procedural seeds 100–199 are reserved for
scoring (issue 30: generalisation is measured on layouts, not seeds)."""

SCENE_FOLDS = 6
"""Folds the default model's training scenes are dealt to for its out-of-fold threshold (each scene held out
whole): 96 scenes in 6 fits instead of 96."""

DEFAULT_FOREST = ForestOptions(class_weight=None)
"""The forest of the shipped model's recipe: :class:`classify.model.ForestOptions` with unweighted classes (32
trees, depth ≤ 14, leaves ≥ 5, one smoothing pass, seed 0). Chosen with the band kept in training and today's three
feature groups by the mean out-of-fold F1 (band left out) over the 96 training scenes alone, among 16 recipes
(``bench/bench_classify.py --part choose``; docs/experiments/2026-11-29-classify-fair-choice.md); no scored scene
was loaded to choose it."""


def train_on_scenes(
    datas: list[SceneData],
    classes: ClassSet,
    options: FeatureOptions = FeatureOptions(),
    forest: ForestOptions = ForestOptions(),
    info: dict[str, object] | None = None,
    by_scene: bool = True,
    ignore_ambiguous: bool = False,
    scene_folds: int | None = None,
) -> tuple[ClassifierModel, TrainingReport]:
    """A forest on the features ``options.selected()`` of several reconstructed scenes with their truth labels.

    by_scene: with at least two scenes, one fold per scene (``forest.folds`` is set to their number): the
    threshold and the report come from each scene predicted by a forest that never saw it, as a user's new
    project will be. Otherwise (or with one scene) folds of spatial blocks (:func:`classify.synthetic.stack_scenes`).
    ignore_ambiguous: leave the truth's ignore band (points within τ of both kinds of surface) out of the forest's
    training rows and the threshold choice. scene_folds: with ``by_scene``, deal the scenes to this many folds
    (each scene still predicted by a forest that never saw it; fewer fits with many scenes); None: one per scene.
    """
    by_scene = by_scene and len(datas) >= 2
    table, codes, groups = stack_scenes(datas, options.selected(), by_scene, ignore_ambiguous)
    if by_scene:
        folds = len(datas) if scene_folds is None else max(2, min(int(scene_folds), len(datas)))
        forest = replace(forest, folds=folds)
    return train(
        table, codes, classes, options, forest, info=info, groups=groups, groups_are_projects=True if by_scene else None
    )


def scene_scores_out_of_fold(datas: list[SceneData], report: TrainingReport, threshold: float) -> list[ClassScores]:
    """Needs-splats scores of each scene of a :func:`train_on_scenes` run (``by_scene``), from its out-of-fold
    probabilities (each scene predicted by a forest that never saw it) at ``threshold``, the truth's ignore band
    left out (the issue-30 score): the figure a recipe is chosen by without looking at a scored scene.

    datas: the scenes in the order they were trained on; report: that run's report."""
    p = report.out_of_fold_needs
    if p is None:
        raise ConfigError("the training run has no out-of-fold probabilities (it needs two scenes or more)")
    sizes = [len(d.truth.codes) for d in datas]
    if sum(sizes) != len(p):
        raise DataError(f"{len(p)} out-of-fold rows for {sum(sizes)} points of {len(datas)} scenes")
    out = []
    for d, p_scene in zip(datas, np.split(p, np.cumsum(sizes)[:-1]), strict=True):
        ok = d.truth.scored
        out.append(scores(d.truth.needs_splats[ok], p_scene[ok] >= threshold, "needs_splats"))
    return out


# -- training from the user's projects --------------------------------------------------------------------------
def _check_label_sources(
    dense_dirs: list[Path], scenes: list[Path] | None, labels_file: Path | None, label_masks: Path | None
) -> None:
    """ConfigError unless exactly one label source is given, and one that fits the number of projects."""
    sources = sum(x is not None and x != [] for x in (scenes or None, labels_file, label_masks))
    if sources != 1:
        raise ConfigError("give exactly one label source: --scene (per project), --labels-file or --label-masks")
    if scenes and len(scenes) != len(dense_dirs):
        raise ConfigError(f"{len(scenes)} scenes for {len(dense_dirs)} projects: give one --scene per project")
    if (labels_file is not None or label_masks is not None) and len(dense_dirs) != 1:
        raise ConfigError("--labels-file and --label-masks label a single project")


def _labels_from_cloud_file(
    labels_file: Path, field: str, las_codes: bool, classes: ClassSet, cloud: PointCloud, max_distance: float
) -> np.ndarray:
    """(N,) uint8 class codes of ``cloud``'s points from the labelled cloud ``labels_file`` (nearest labelled point
    within ``max_distance`` metres; UNLABELLED beyond)."""
    from core.io import read_point_cloud

    labelled = read_point_cloud(labels_file)
    if field not in labelled.fields:
        raise DataError(f"no field {field!r} (fields: {', '.join(labelled.fields) or 'none'})", labels_file)
    codes = labels_from_field(labelled.fields[field], classes, las_codes)
    return transfer_labels(labelled.with_origin(cloud.origin).positions, codes, cloud.positions, max_distance)


def _labels_from_mask_folder(label_masks: Path, dense: Path, cloud: PointCloud) -> np.ndarray:
    """(N,) uint8 class codes of ``cloud``'s points voted by the label images ``NAME.png`` (or ``NAME``, or
    ``STEM.png``) in ``label_masks`` of the dense workspace's photos."""
    from core.io.colmap import read_model
    from core.io.images import read_image
    from recon.workspace import DenseWorkspace

    if not label_masks.is_dir():
        raise InputFileError("label-mask folder does not exist", label_masks)
    cams, _ = read_model(DenseWorkspace(Path(dense)).sparse)
    masks = {}
    for v in cams:
        stem = Path(v.name).stem
        for cand in (label_masks / f"{v.name}.png", label_masks / v.name, label_masks / f"{stem}.png"):
            if cand.is_file():
                masks[v.name] = read_image(cand, grayscale=True)
                break
    if not masks:
        raise InputFileError("no label image matches a photo of the project (NAME.png)", label_masks)
    return labels_from_masks(cloud.positions, cams, masks, cloud.visibility)


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
    from recon.workspace import read_fused

    _check_label_sources(dense_dirs, scenes, labels_file, label_masks)
    classes = load_classes(classes_toml)
    options = FeatureOptions(names=feature_names, geometric=FeatureOptions().geometric)
    options.selected()  # an unknown or removed feature name is refused before any cloud is read
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
            dist = max_distance if max_distance > 0 else 2.0 * table.spacing
            y = _labels_from_cloud_file(labels_file, field, las_codes, classes, cloud, dist)
        else:
            assert label_masks is not None  # exactly one source (checked above)
            y = _labels_from_mask_folder(label_masks, dense, cloud)
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
