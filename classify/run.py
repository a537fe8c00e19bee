"""Classification and masks of a reconstructed project, as plain functions over files (the stages call these).

Nothing here knows the project layout: callers pass the paths (``hybridsplat.stages.classify`` / ``masks``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from os import PathLike
from pathlib import Path

import numpy as np

from classify.classes import ClassSet, load_classes
from classify.fallback import FALLBACK_FEATURES, fallback_predict
from classify.features import FeatureGroup, FeatureOptions, FeatureTable, compute_features, views_from_workspace
from classify.masks import MaskOptions, region_masks
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
    classified it (``model``: a path, or ``fallback``) and the wall time (``seconds``)."""

    cloud: PointCloud
    prediction: Prediction
    spacing: float
    classes: ClassSet
    model: str
    seconds: float
    feature_names: tuple[str, ...]

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
    if model is None:
        opts = FeatureOptions(names=FALLBACK_FEATURES)
    else:
        opts = replace(model.feature_options, names=tuple(model.feature_names))
    selected = set(opts.selected())
    needs_views = any(n in selected for n in FeatureOptions(groups=(FeatureGroup.MULTIVIEW,)).selected())
    views = views_from_workspace(dense_dir) if needs_views and dense_dir is not None else None
    table = compute_features(cloud, opts, views)
    if model is None:
        return fallback_predict(table, classes or load_classes()), table
    t = threshold if threshold is not None else float(model.info.get("threshold", 0.5))  # type: ignore[arg-type]
    return predict(model, table.select(tuple(model.feature_names)), threshold=t), table


def classify_dense(dense_dir: str | PathLike[str], model: str = "default", threshold: float | None = None):
    """Classify ``dense_dir/fused.ply`` (+ .vis) with the model option (see :func:`resolve_model_path`).

    A missing shipped default model falls back to the no-model rules (recorded as ``fallback``).
    """
    from recon.workspace import read_fused

    t0 = time.perf_counter()
    cloud = read_fused(dense_dir)
    path = resolve_model_path(model)
    loaded = None
    if path is not None:
        if not path.is_file() and model != "default":
            raise InputFileError("classifier model does not exist", path)
        loaded = load_model(path) if path.is_file() else None
    classes = loaded.classes if loaded is not None else load_classes()
    pred, table = classify_cloud(cloud, loaded, dense_dir, classes, threshold)
    name = str(path) if loaded is not None else "fallback"
    return ClassifiedCloud(cloud, pred, table.spacing, classes, name, time.perf_counter() - t0, table.names)


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


def project_masks(
    points_ply: str | PathLike[str],
    report_json: str | PathLike[str],
    sparse_dir: str | PathLike[str],
    mask_path: Callable[[str], Path],
    options: MaskOptions = MaskOptions(),
    user_mask_dir: Path | None = None,
    held_out: set[str] | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, object]:
    """Write one mask PNG per registered, not held-out photo (``mask_path(name)``); return the record.

    points_ply: classify/points.ply (``needs_splats`` field). report_json: its report (the point spacing).
    user_mask_dir: ``NAME.png`` (or ``NAME``) white = needs splats, optional per photo.
    """
    from core.io.colmap import read_model
    from core.io.images import read_image, write_image
    from core.io.json_io import read_json
    from core.io.ply import read_ply

    cloud = read_ply(points_ply)
    if "needs_splats" not in cloud.fields:
        raise DataError("classified cloud has no 'needs_splats' field (run the classify stage)", Path(points_ply))
    spacing = float(read_json(report_json)["spacing_m"])
    cameras, _ = read_model(sparse_dir)
    names = [v.name for v in cameras if v.name not in (held_out or set())]
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
    # Local positions of the cloud in the model's frame (the sparse model shares the cloud's origin).
    masks = region_masks(cameras, cloud.positions, cloud.fields["needs_splats"] > 0, spacing, options, user, names)
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
            }  # fmt: skip
        )
        if progress is not None:
            progress("masks", i + 1, len(masks))
    empty = sum(p["empty"] for p in photos)
    return {
        "photos": len(photos),
        "empty": empty,
        "mean_coverage": float(np.mean([p["coverage"] for p in photos])) if photos else 0.0,
        "training_needed": empty < len(photos),
        "held_out_skipped": sorted(held_out or ()),
        "per_photo": photos,
    }
