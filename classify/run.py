"""Classification and masks of a reconstructed project, as plain functions over files (the stages call these).

Nothing here knows the project layout: callers pass the paths (``hybridsplat.stages.classify`` / ``masks``).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from os import PathLike
from pathlib import Path

import numpy as np

from classify.classes import ClassSet, load_classes
from classify.fallback import FALLBACK_FEATURES, fallback_predict
from classify.features import VIEW_GROUPS, FeatureOptions, FeatureTable, compute_features, views_from_workspace
from classify.masks import MaskOptions, PhotoMask, SeenInView, region_masks
from classify.model import ClassifierModel, Prediction, load_model, predict
from core.errors import DataError, InputFileError
from core.pointcloud import PointCloud

DEFAULT_MODEL = Path(__file__).with_name("models") / "default.skops"


def resolve_model_path(model: str) -> Path | None:
    """The file of a model option: ``default`` → the shipped model, ``none`` → None, else the path given."""
    if model == "none":
        return None
    return DEFAULT_MODEL if model == "default" else Path(model)


@dataclass
class ClassifiedCloud:
    """The classified dense cloud: ``cloud``, ``prediction``, the feature ``spacing`` (m), the ``classes``, what
    classified it (``model``: a path, or ``fallback``), the wall time (``seconds``), the feature names and the
    model's feature importances (name → mean decrease in impurity; None for the fallback)."""

    cloud: PointCloud
    prediction: Prediction
    spacing: float
    classes: ClassSet
    model: str
    seconds: float
    feature_names: tuple[str, ...]
    importances: dict[str, float] | None = None

    def report(self) -> dict[str, object]:
        p = self.prediction
        per_class = {c.name: int(np.count_nonzero(p.classification == c.code)) for c in self.classes.classes}
        return {
            "points": len(self.cloud),
            "needs_splats": int(np.count_nonzero(p.needs_splats)),
            "per_class": per_class,
            "model": self.model,
            "spacing_m": self.spacing,
            "seconds": self.seconds,
            "features": list(self.feature_names),
            "classes": self.classes.to_dict(),
            "importances": self.importances,
        }


def classify_cloud(
    cloud: PointCloud,
    model: ClassifierModel | None,
    dense_dir: str | PathLike[str] | None,
    classes: ClassSet | None = None,
    threshold: float | None = None,
) -> tuple[Prediction, FeatureTable]:
    """Features + prediction of a cloud; ``model`` None uses the fallback (multi-view features + scale 0).

    dense_dir: the dense workspace with the photos and depth maps (needed for multi-view features).
    """
    opts = feature_options_for(model)
    views = views_from_workspace(dense_dir) if needs_views(opts) and dense_dir is not None else None
    table = compute_features(cloud, opts, views)
    return predict_table(model, table, classes or load_classes(), threshold), table


def feature_options_for(model: ClassifierModel | None) -> FeatureOptions:
    """The features a model reads (its own options and names), or the fallback's (``model`` None)."""
    if model is None:
        return FeatureOptions(names=FALLBACK_FEATURES)
    return replace(model.feature_options, names=tuple(model.feature_names))


def needs_views(options: FeatureOptions) -> bool:
    """Whether any selected feature needs the photos, cameras and depth maps (a view-based group)."""
    selected = set(options.selected())
    return any(n in selected for n in FeatureOptions(groups=VIEW_GROUPS).selected())


def predict_table(
    model: ClassifierModel | None, table: FeatureTable, classes: ClassSet, threshold: float | None = None
) -> Prediction:
    """The prediction of a feature table: the model's (``threshold`` None: the model's own, else 0.5), or the
    fallback rules' (``model`` None)."""
    if model is None:
        return fallback_predict(table, classes)
    t = threshold if threshold is not None else float(model.info.get("threshold", 0.5))  # type: ignore[arg-type]
    return predict(model, table.select(tuple(model.feature_names)), threshold=t)


def load_classifier(model: str) -> tuple[ClassifierModel | None, ClassSet, str, dict[str, float] | None]:
    """The model of a model option (:func:`resolve_model_path`; a missing shipped default → None, the fallback),
    its classes, its name as the report records it (a path, or ``fallback``) and its feature importances."""
    path = resolve_model_path(model)
    loaded = None
    if path is not None:
        if not path.is_file() and model != "default":
            raise InputFileError("classifier model does not exist", path)
        loaded = load_model(path) if path.is_file() else None
    classes = loaded.classes if loaded is not None else load_classes()
    importances = None
    if loaded is not None:
        values = getattr(loaded.forest, "feature_importances_", None)
        if values is not None:
            importances = {n: float(v) for n, v in zip(loaded.feature_names, values, strict=True)}
    return loaded, classes, (str(path) if loaded is not None else "fallback"), importances


def classify_dense(dense_dir: str | PathLike[str], model: str = "default", threshold: float | None = None):
    """Classify ``dense_dir/fused.ply`` (+ .vis) with the model option (see :func:`resolve_model_path`).

    A missing shipped default model falls back to the no-model rules (recorded as ``fallback``).
    """
    from recon.workspace import read_fused

    t0 = time.perf_counter()
    cloud = read_fused(dense_dir)
    loaded, classes, name, importances = load_classifier(model)
    pred, table = classify_cloud(cloud, loaded, dense_dir, classes, threshold)
    seconds = time.perf_counter() - t0
    return ClassifiedCloud(cloud, pred, table.spacing, classes, name, seconds, table.names, importances)


def write_classify_figures(
    result: ClassifiedCloud, classes_png: str | PathLike[str], importances_png: str | PathLike[str] | None
) -> list[Path]:
    """The report's figures of a classification: the cloud coloured by class (``classes_png``) and, when the
    model has them and a path is given, the feature importances (``importances_png``); written atomically.
    Returns the files written."""
    from classify.figures import classified_cloud_png
    from classify.figures import importances_png as imp_png
    from core.io.atomic import write_bytes_atomic

    written = [Path(classes_png)]
    png = classified_cloud_png(result.cloud.positions, result.prediction.classification, result.classes)
    write_bytes_atomic(classes_png, png)
    if importances_png is not None and result.importances:
        names = list(result.importances)
        write_bytes_atomic(importances_png, imp_png(names, [result.importances[n] for n in names]))
        written.append(Path(importances_png))
    return written


def write_masks_figure(
    path: str | PathLike[str],
    masks: dict[str, np.ndarray],
    coverage: dict[str, float],
    photo: Callable[[str], np.ndarray],
    count: int = 4,
) -> Path | None:
    """Up to ``count`` photos with their masks overlaid (the photos with the largest coverage, evenly picked among
    the non-empty ones), written atomically as a PNG to ``path``; None (nothing written) when every mask is empty.

    masks: image name → (H, W) bool. coverage: image name → share of the photo. photo: name → (H, W, 3) uint8."""
    from classify.figures import masks_png
    from core.io.atomic import write_bytes_atomic

    names = [n for n in sorted(masks, key=lambda n: -coverage[n]) if coverage[n] > 0]
    if not names:
        return None
    pick = names if len(names) <= count else [names[i] for i in np.linspace(0, len(names) - 1, count).astype(int)]
    panels = [(n, photo(n), masks[n], coverage[n]) for n in pick]
    write_bytes_atomic(path, masks_png(panels))
    return Path(path)


def write_classified(path: str | PathLike[str], result: ClassifiedCloud) -> Path:
    """classify/points.ply: the cloud with ``classification`` (uint8), ``probability`` (float32) and
    ``needs_splats`` (uint8) fields, written atomically (with the origin sidecar when needed)."""
    from core.io.ply import write_ply

    c = result.cloud
    fields = dict(c.fields)
    fields["classification"] = result.prediction.classification.astype(np.uint8)
    fields["probability"] = result.prediction.probability.astype(np.float32)
    fields["needs_splats"] = result.prediction.needs_splats.astype(np.uint8)
    out = PointCloud(c.positions, c.origin, c.colors, c.normals, fields)
    return write_ply(path, out)


def _cloud_downscale(cameras, dense_dir: Path | None) -> float:
    """How many times smaller than the photos the dense workspace's (undistorted, MVS-sized) images are: the ratio
    of the largest image sides; 1 without a dense workspace model."""
    if dense_dir is None:
        return 1.0
    from core.io.colmap import read_model
    from recon.workspace import DenseWorkspace

    sparse = DenseWorkspace(Path(dense_dir)).sparse
    if not sparse.is_dir():
        return 1.0
    dense, _ = read_model(sparse)
    photo_side = max(max(c.width, c.height) for c in cameras.cameras.values())
    dense_side = max(max(c.width, c.height) for c in dense.cameras.values())
    return max(1.0, photo_side / dense_side)


def _read_only(array: np.ndarray) -> np.ndarray:
    """``array`` flagged read-only: a shared cached photo that a caller modified would corrupt the others' input."""
    array.setflags(write=False)
    return array


def project_masks(
    points_ply: str | PathLike[str],
    report_json: str | PathLike[str],
    sparse_dir: str | PathLike[str],
    mask_path: Callable[[str], Path],
    options: MaskOptions = MaskOptions(),
    user_mask_dir: Path | None = None,
    held_out: set[str] | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    figure: Path | None = None,
    image_dir: Path | None = None,
    dense_dir: Path | None = None,
) -> dict[str, object]:
    """Write one mask PNG per registered, not held-out photo (``mask_path(name)``); return the record.

    points_ply: classify/points.ply (``needs_splats`` field). report_json: its report (the point spacing).
    user_mask_dir: ``NAME.png`` (or ``NAME``) white = needs splats, optional per photo.
    image_dir: the photos (at the cameras' resolution): holes are explained only by points seen in each photo
    (fused by it, or of its colour, see :class:`classify.masks.SeenInView`); figure: where to write a few photos
    with their masks overlaid (the record's ``figure`` says whether one was written). dense_dir: the dense
    workspace whose ``fused.ply.vis`` says which photos fused each point (same order as ``points_ply``).
    """
    from core.io.colmap import read_model
    from core.io.images import read_image
    from core.io.json_io import read_json
    from core.io.ply import read_ply

    cloud = read_ply(points_ply)
    if "needs_splats" not in cloud.fields:
        raise DataError("classified cloud has no 'needs_splats' field (run the classify stage)", Path(points_ply))
    spacing = float(read_json(report_json)["spacing_m"])
    cameras, _ = read_model(sparse_dir)
    names = [v.name for v in cameras if v.name not in (held_out or set())]
    user = _read_user_masks(user_mask_dir, names)
    # Local positions of the cloud in the model's frame (the sparse model shares the cloud's origin).
    seen = None
    if options.holes and options.explained_by == "seen" and (dense_dir is not None or image_dir is not None):
        seen = _seen_in_view(cloud, dense_dir, image_dir)
    masks = region_masks(
        cameras, cloud.positions, cloud.fields["needs_splats"] > 0, spacing, options, user, names, seen,
        cloud_downscale=_cloud_downscale(cameras, dense_dir),
    )  # fmt: skip
    photos = _write_mask_pngs(masks, mask_path, progress)
    empty = sum(p["empty"] for p in photos)
    drawn = None
    if figure is not None and image_dir is not None:
        drawn = write_masks_figure(
            figure,
            {pm.name: pm.mask for pm in masks},
            {pm.name: pm.coverage for pm in masks},
            lambda name: read_image(Path(image_dir) / name),
        )
    return {
        "photos": len(photos),
        "empty": empty,
        "mean_coverage": float(np.mean([p["coverage"] for p in photos])) if photos else 0.0,
        "training_needed": empty < len(photos),
        "held_out_skipped": sorted(held_out or ()),
        "figure": drawn is not None,
        "per_photo": photos,
    }


def _read_user_masks(user_mask_dir: Path | None, names: list[str]) -> dict[str, np.ndarray]:
    """Image name → (H, W) uint8 user mask, for the photos ``names`` that have ``NAME.png``, ``NAME`` or
    ``STEM.png`` in ``user_mask_dir`` (first found, in that order); empty without a folder."""
    from core.io.images import read_image

    user: dict[str, np.ndarray] = {}
    if user_mask_dir is not None:
        if not Path(user_mask_dir).is_dir():
            raise InputFileError("splat-mask folder does not exist", user_mask_dir)
        for n in names:
            folder = Path(user_mask_dir)
            for cand in (folder / f"{n}.png", folder / n, folder / f"{Path(n).stem}.png"):
                if cand.is_file():
                    user[n] = read_image(cand, grayscale=True)
                    break
    return user


def _seen_in_view(cloud: PointCloud, dense_dir: Path | None, image_dir: Path | None) -> SeenInView:
    """What tells which points each photo sees: the fused cloud's visibility (from ``dense_dir``) and the points'
    colours against the photos (from ``image_dir``), whichever is given."""
    from core.io.images import read_image

    visibility = None
    if dense_dir is not None:
        from recon.workspace import read_fused

        visibility = read_fused(dense_dir).visibility
        if visibility is not None and len(visibility) != len(cloud):
            raise DataError(f"fused.ply.vis lists {len(visibility)} points, the classified cloud {len(cloud)}")
    folder = Path(image_dir) if image_dir is not None else None
    photo = None
    if folder is not None:
        # Each photo is read by the colour test, GrabCut and the parallax test of itself and of its neighbours
        # (classify.masks.at_infinity): views come in image-id order, whose neighbours are mostly the same
        # few photos, so a handful of decoded photos in memory saves most reads (see
        # docs/experiments/2026-11-27-domain-defaults.md).
        photo = functools.lru_cache(maxsize=8)(lambda name: _read_only(read_image(folder / name)))
    return SeenInView(visibility, cloud.colors, photo)


def _write_mask_pngs(
    masks: list[PhotoMask], mask_path: Callable[[str], Path], progress: Callable[[str, int, int], None] | None
) -> list[dict[str, object]]:
    """Write each mask as a 0/255 PNG at ``mask_path(name)``; return the per-photo records, in ``masks`` order."""
    from core.io.images import write_image

    photos = []
    for i, pm in enumerate(masks):
        path = mask_path(pm.name)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_image(path, (pm.mask * 255).astype(np.uint8))
        photos.append(
            {
                "name": pm.name,
                "coverage": pm.coverage,
                "points": pm.points_px,
                "holes": pm.holes_px,
                "user": pm.user_px,
                "empty": pm.empty,
                "train_margin_px": pm.train_margin_px,
            }  # fmt: skip
        )
        if progress is not None:
            progress("masks", i + 1, len(masks))
    return photos
