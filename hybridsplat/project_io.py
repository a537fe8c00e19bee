"""Typed reading of what the stages leave in a project folder, over :class:`hybridsplat.layout.ProjectLayout`.

Stages read each other's products here, never through string keys of JSON records or by spelling paths: any
stage's typed result as the manifest recorded it (:func:`stage_result`), the model's origin (the sfm stage's
record), the COLMAP models in world coordinates, the region and training masks with their per-photo record (the
masks stage's), and per-point fields of the classified cloud matched to a set of Gaussians. Every reader names the
file it found wrong in its error.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from core.cameras import Cameras
from core.errors import DataError, FormatError
from core.pointcloud import PointCloud
from hybridsplat.layout import ProjectLayout

if TYPE_CHECKING:
    from hybridsplat.manifest import Manifest
    from hybridsplat.stages.base import Stage

# ------------------------------------------------------------------------------------ every stage: its result


def stage_result(project: ProjectLayout | Manifest, stage: Stage | type[Stage]) -> Any:
    """What ``stage`` (a stage class or instance) recorded in the project's manifest at its last run, as its typed
    ``Result`` (:class:`hybridsplat.stages.base.StageResult`; a record of an earlier version reads with defaults for
    what it lacks); None when the stage has no record or was skipped. ``project``: a project's layout, or its
    :class:`~hybridsplat.manifest.Manifest` already loaded. The one way code reads another stage's counts::

        train = stage_result(layout, TrainStage)
        steps = train.iterations if train is not None else 0
    """
    from hybridsplat.manifest import Manifest

    manifest = project if isinstance(project, Manifest) else Manifest(project.manifest)
    return manifest.result(stage.name, stage.Result)


# ------------------------------------------------------------------------------------------------- sfm: the origin


def model_origin(layout: ProjectLayout, fallback: np.ndarray | None = None) -> np.ndarray:
    """(3,) float64 world coordinates (metres) of the frame the project's COLMAP models are written in.

    COLMAP models hold no origin: the sfm stage records it (a georeferenced block is aligned into a local frame
    around a rounded centroid), and the control stage its control frame's when it adjusted the model
    (:func:`sparse_model`). ``fallback`` (zeros by default) before the sfm stage ran or without a georeference.
    """
    from core.io.json_io import read_json_object

    for record in (layout.record("control"), layout.record("sfm")):
        if not record.is_file() or (record == layout.record("control") and not layout.control_sparse.is_dir()):
            continue
        origin = read_json_object(record).get("origin")
        if origin is not None:
            if not (isinstance(origin, list) and len(origin) == 3):
                raise FormatError(f'"origin" must be three numbers, got {origin!r}', record)
            return np.asarray(origin, np.float64).reshape(3)
        break
    return np.zeros(3) if fallback is None else np.asarray(fallback, np.float64).reshape(3)


def sparse_model(layout: ProjectLayout) -> Path:
    """The sparse model later stages build on: the one held to survey control (``control/sparse``) when the
    control stage made it, else the sfm stage's (``sparse/``); its frame's origin is :func:`model_origin`."""
    return layout.control_sparse if layout.control_sparse.is_dir() else layout.sparse


def read_model_at(path: Path, origin: np.ndarray) -> tuple[Cameras, PointCloud]:
    """A COLMAP model (cameras and points) whose local frame lies at ``origin`` (world = origin + local)."""
    from core.io.colmap import read_model

    cameras, points = read_model(path)
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    return replace(cameras, origin=origin), replace(points, origin=origin)


def read_project_model(layout: ProjectLayout, path: Path) -> tuple[Cameras, PointCloud]:
    """A model of this project (``sparse/`` or the dense workspace's) in world coordinates, see model_origin."""
    return read_model_at(path, model_origin(layout))


def read_training_photos(
    layout: ProjectLayout, held_out: Collection[str] = (), only: Collection[str] | None = None
) -> tuple[Cameras, dict[str, np.ndarray]]:
    """The dense workspace's cameras without the ``held_out`` photos (never trained on) and their undistorted photos
    by name (the whole images a layer is trained on); ``only``: just these photos (a tile's)."""
    from core.io.images import read_image

    cameras = dense_cameras(layout, held_out, only)
    return cameras, {v.name: read_image(layout.dense_workspace.images / v.name) for v in cameras}


def dense_cameras(
    layout: ProjectLayout, held_out: Collection[str] = (), only: Collection[str] | None = None
) -> Cameras:
    """The dense workspace's cameras without the ``held_out`` photos, and with ``only`` just those photos."""
    cameras, _ = read_project_model(layout, layout.dense_workspace.sparse)
    keep = {i: v for i, v in cameras.views.items() if v.name not in held_out and (only is None or v.name in only)}
    return Cameras(cameras.cameras, keep, cameras.origin)


# ------------------------------------------------------------------------------------------------- masks: a record


@dataclass(frozen=True)
class PhotoMaskRecord:
    """What the masks stage recorded of one photo: the share of the image its region mask covers, whether it is
    empty (training skips it), and the extra dilation of its training mask in pixels (``train_margin_px``)."""

    name: str
    coverage: float
    empty: bool
    train_margin_px: int


@dataclass(frozen=True)
class MasksRecord:
    """The masks stage's record (``logs/masks.json``): one :class:`PhotoMaskRecord` per photo with a mask, and
    whether any mask is set (``training_needed``)."""

    photos: tuple[PhotoMaskRecord, ...]
    training_needed: bool
    figure: bool

    @property
    def margins(self) -> dict[str, int]:
        return {p.name: p.train_margin_px for p in self.photos}

    @staticmethod
    def from_dict(data: dict[str, Any], path: Path) -> MasksRecord:
        try:
            photos = tuple(
                PhotoMaskRecord(
                    str(p["name"]),
                    float(p.get("coverage", 0.0)),
                    bool(p.get("empty", False)),
                    int(p.get("train_margin_px", 0)),
                )  # fmt: skip
                for p in data.get("per_photo", [])
            )
            needed = bool(data.get("training_needed", any(not p.empty for p in photos)))
        except (KeyError, TypeError, ValueError) as err:
            raise FormatError(f"not a masks record ({err})", path) from err
        return MasksRecord(photos, needed, bool(data.get("figure", False)))


def read_masks_record(layout: ProjectLayout) -> MasksRecord | None:
    """The masks stage's record, or None before that stage ran."""
    from core.io.json_io import read_json_object

    path = layout.record("masks")
    return MasksRecord.from_dict(read_json_object(path), path) if path.is_file() else None


def has_region_masks(layout: ProjectLayout) -> bool:
    """Whether the masks stage wrote any region mask PNG."""
    return layout.masks_dir.is_dir() and any(layout.masks_dir.glob("*.png"))


def read_region_masks(layout: ProjectLayout, cameras: Cameras, training: bool = False) -> dict[str, np.ndarray]:
    """Region masks (bool, True = needs splats, at each camera's size: resized nearest when the masks stage wrote
    another size) by image name, for the cameras that have one.

    training: the training masks, i.e. each region mask dilated by a disk (OpenCV's ellipse element, as in the
    masks stage) of its photo's ``train_margin_px`` (:class:`PhotoMaskRecord`; 0 without a record)."""
    import cv2

    from core.io.images import read_image

    record = read_masks_record(layout) if training else None
    margins = record.margins if record is not None else {}
    masks = {}
    for view in cameras:
        path = layout.mask_path(view.name)
        if not path.is_file():
            continue
        m = read_image(path, grayscale=True) > 127
        margin = margins.get(view.name, 0)
        if margin > 0 and m.any():
            disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
            m = cv2.dilate(m.astype(np.uint8), disk) > 0
        cam = cameras.camera_of(view)
        if m.shape != (cam.height, cam.width):
            m = cv2.resize(m.astype(np.uint8), (cam.width, cam.height), interpolation=cv2.INTER_NEAREST) > 0
        masks[view.name] = m
    return masks


# ------------------------------------------------------------------------------------ classify: fields per Gaussian


def classified_field_per_gaussian(layout: ProjectLayout, gaussians: Any, field: str) -> np.ndarray:
    """A per-point field of the classified cloud (``needs_splats``, ``classification``, ...), one value per
    Gaussian of ``gaussians`` (a GaussianSet converted from the same cloud: same order, or else matched by the
    nearest position)."""
    from scipy.spatial import cKDTree

    from core.io import read_point_cloud

    cloud = read_point_cloud(layout.classified_points)
    if field not in cloud.fields:
        raise DataError(f"classified cloud has no {field!r} field", layout.classified_points)
    values = np.asarray(cloud.fields[field])
    if len(cloud) == len(gaussians):
        return values
    _, idx = cKDTree(cloud.world_positions).query(gaussians.world_means, k=1, workers=-1)
    return values[idx]


def needs_splats_per_gaussian(layout: ProjectLayout, gaussians: Any) -> np.ndarray:
    """(N,) bool ``needs_splats`` of the classified cloud, one per Gaussian (see classified_field_per_gaussian)."""
    return classified_field_per_gaussian(layout, gaussians, "needs_splats").astype(bool)


def read_needs_splats_class_codes(layout: ProjectLayout) -> dict[str, int]:
    """Class name → code of the classes that need splats, in the class set the classify stage recorded ({} when
    it recorded none)."""
    from classify.classes import ClassSet
    from core.io.json_io import read_json_object

    report = layout.classify_report
    stored = read_json_object(report).get("classes") if report.is_file() else None
    if not stored:
        return {}
    return {c.name: c.code for c in ClassSet.from_dict(stored, report).classes if c.needs_splats}


# ------------------------------------------------------------------------------------- merge: the unrefined product


def unrefined_layers(layout: ProjectLayout, merged: Any) -> Any:
    """``merged`` (export/merged.ply as read, a GaussianSet) with every layer as before the appearance stage: the
    survey rows with export/mvs_gaussians.ply's attributes, the fill rows with splats/cleaned.ply's and the
    background rows with splats/background.ply's, where those files exist (:func:`fusion.appearance.
    with_converted_survey`). What the survey products and the ``merged_unrefined`` control read."""
    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.appearance import with_converted_survey

    fill, background = (read_gaussian_ply(p) if p.is_file() else None
                        for p in (layout.cleaned_splats, layout.background_splats))  # fmt: skip
    converted = read_gaussian_ply(layout.mvs_gaussians)
    return with_converted_survey(merged, converted, layout.merged_ply, fill=fill, background=background)
