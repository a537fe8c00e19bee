"""What the user hands to ``hybridsplat run INPUT``: resolved once into a typed :class:`InputSpec`.

INPUT is one of (checked in this order)::

    data_synth scene      scene.json + images/ + sparse/0 (true cameras) [+ sparse/test + test/ held-out views,
                          gt/lidar.ply reference cloud, gt/labels/test material labels]
    COLMAP workspace      sparse/ (a model directly, or sparse/N models) [+ images/] [+ dense/]; without images/
                          the undistorted dense/images + dense/sparse are used
    folder of photos      photos directly in INPUT, or in INPUT/images/

Photos are the files with a supported extension (case-insensitive), top level only, sorted by name. Held-out
photos (:func:`select_holdout`, :func:`choose_holdout`) are never used for depth estimation, fusion or training;
they are registered by SfM so that every product can be rendered and evaluated at their poses.
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from core.errors import ConfigError, FormatError, InputFileError
from core.io.scene_description import SCENE_FILE_NAME, SceneDescription, read_scene_description

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
DEFAULT_HOLDOUT_EVERY = 8  # every 8th photo in name order is held out by default


class InputKind(str, enum.Enum):
    PHOTOS = "photos"
    COLMAP = "colmap"
    SYNTH = "synthetic"


@dataclass(frozen=True)
class InputSpec:
    """A resolved INPUT. Paths are None where the input has no such thing; names are file names.

    image_dir / image_names: the photos (sorted names, supported extensions only).
    known_cameras: a COLMAP model of known cameras for these photos (a scene's ``sparse/0``, the selected model
    of a workspace), or None. models: every model a workspace holds (``sparse`` or ``sparse/N``).
    dense_dir: a workspace's ``dense/`` folder, or None.
    test_photos / test_model / test_names: held-out views the input brings (a scene's ``test/`` photos and
    ``sparse/test`` cameras), or None / (). They are never part of ``image_names``.
    reference_cloud / test_labels / train_labels: ground truth (a scene's ``gt/lidar.ply``, ``gt/labels/*``).
    scene_json / description: the scene description and its parsed content, or None.
    origin: float64 world coordinates (metres) of the local frame; gsd_m: metres per pixel, or None.
    non_collaborative_ids: material ids MVS cannot be trusted on (from the scene description).
    """

    root: Path
    kind: InputKind
    image_dir: Path
    image_names: tuple[str, ...]
    known_cameras: Path | None = None
    models: tuple[Path, ...] = ()
    dense_dir: Path | None = None
    test_model: Path | None = None
    test_photos: Path | None = None
    test_names: tuple[str, ...] = ()
    test_labels: Path | None = None
    train_labels: Path | None = None
    reference_cloud: Path | None = None
    scene_json: Path | None = None
    gsd_m: float | None = None
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    non_collaborative_ids: tuple[int, ...] = ()
    crs: str | None = None
    description: SceneDescription | None = None

    @property
    def has_own_holdout(self) -> bool:
        """True when the input brings held-out views (photos and their cameras) of its own."""
        return self.test_model is not None and self.test_photos is not None


@dataclass(frozen=True)
class Holdout:
    """Held-out photos: names, and where they are (``image_dir``) and their cameras (``model``, or None when
    they are photos of the input itself and SfM registers them). source: "input" (the input's own held-out
    views), "every" (every N-th photo) or "none"."""

    names: tuple[str, ...]
    source: str
    image_dir: Path | None = None
    model: Path | None = None


def list_images(folder: Path) -> tuple[str, ...]:
    """Names of the photos directly in ``folder`` (supported extensions, case-insensitive), sorted.

    Raises InputFileError when the folder does not exist or cannot be read.
    """
    if not folder.is_dir():
        raise InputFileError("folder does not exist", folder)
    try:
        entries = list(folder.iterdir())
    except OSError as err:
        raise InputFileError(f"cannot read the folder ({err.strerror or err})", folder) from err
    return tuple(sorted(p.name for p in entries if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()))


def _no_photos(folder: Path, also_images: bool = False) -> InputFileError:
    where = "here nor in its images/ folder" if also_images else "here"
    return InputFileError(
        f"found no photos {where} (supported: {', '.join(IMAGE_SUFFIXES)}, any case; INPUT must be a folder of "
        "photos, a folder holding images/, a COLMAP workspace or a data_synth scene)",
        folder,
    )


def _is_model(folder: Path) -> bool:
    return any((folder / f"cameras.{ext}").is_file() for ext in ("bin", "txt"))


def _num_images(model: Path) -> int:
    """Number of images of a COLMAP model, from the images file's header (binary) or its lines (text)."""
    binary, text = model / "images.bin", model / "images.txt"
    try:
        if binary.is_file():
            with open(binary, "rb") as f:
                head = f.read(8)
            if len(head) != 8:
                raise FormatError("images.bin is truncated", binary)
            return int.from_bytes(head, "little")
        if text.is_file():
            # two lines per image: the pose line, then its 2D points (an empty line when it has none)
            lines = [s for s in text.read_text(encoding="utf-8").splitlines() if not s.startswith("#")]
            while lines and not lines[-1].strip() and len(lines) % 2:
                lines.pop()
            return (len(lines) + 1) // 2
    except OSError as err:
        raise InputFileError(f"cannot read the model ({err.strerror or err})", model) from err
    raise InputFileError("COLMAP model has no images.bin or images.txt", model)


def _workspace_models(sparse: Path) -> tuple[Path, ...]:
    """The models of a workspace's ``sparse/``: the folder itself, or its numbered sub-folders in number order."""
    if _is_model(sparse):
        return (sparse,)
    try:
        subs = [p for p in sparse.iterdir() if p.is_dir() and p.name.isdigit() and _is_model(p)]
    except OSError as err:
        raise InputFileError(f"cannot read the folder ({err.strerror or err})", sparse) from err
    return tuple(sorted(subs, key=lambda p: int(p.name)))


def _pick_model(sparse: Path, models: tuple[Path, ...], model: int | None) -> Path:
    if not models:
        raise InputFileError("no COLMAP model here (expected cameras.bin/.txt in sparse/ or sparse/N/)", sparse)
    if model is not None:
        for m in models:
            if m.name == str(model) or (m == sparse and model == 0):
                return m
        found = ", ".join(m.name for m in models)
        raise InputFileError(f"model {model} does not exist (models here: {found})", sparse)
    # the largest model; ties go to the lowest number (the order COLMAP writes them)
    return max(models, key=lambda m: (_num_images(m), -models.index(m)))


def _resolve_synth(root: Path) -> InputSpec:
    desc = read_scene_description(root / SCENE_FILE_NAME)
    image_dir = root / "images"
    images = list_images(image_dir)
    if not images:
        raise _no_photos(image_dir)
    test_dir, test_model = root / "test", root / "sparse" / "test"
    test_names = list_images(test_dir) if test_dir.is_dir() else ()
    has_test = bool(test_names) and _is_model(test_model)
    lidar, labels = root / "gt" / "lidar.ply", root / "gt" / "labels"
    return InputSpec(
        root=root,
        kind=InputKind.SYNTH,
        image_dir=image_dir,
        image_names=images,
        known_cameras=root / "sparse" / "0",
        models=(root / "sparse" / "0",),
        test_model=test_model if has_test else None,
        test_photos=test_dir if has_test else None,
        test_names=test_names if has_test else (),
        test_labels=labels / "test" if (labels / "test").is_dir() else None,
        train_labels=labels / "train" if (labels / "train").is_dir() else None,
        reference_cloud=lidar if lidar.is_file() else None,
        scene_json=desc.path,
        gsd_m=desc.gsd_m,
        origin=desc.origin,
        non_collaborative_ids=desc.non_collaborative_ids,
        crs=desc.crs,
        description=desc,
    )


def _resolve_colmap(root: Path, model: int | None) -> InputSpec:
    sparse, dense = root / "sparse", root / "dense"
    dense_dir = dense if dense.is_dir() else None
    image_dir = root / "images"
    if sparse.is_dir() and image_dir.is_dir():
        models = _workspace_models(sparse)
        chosen = _pick_model(sparse, models, model)
    elif dense_dir is not None and (dense / "images").is_dir() and _is_model(dense / "sparse"):
        # only the undistorted workspace is there: its pinhole model and images are the input
        image_dir, models = dense / "images", (dense / "sparse",)
        chosen = _pick_model(dense / "sparse", models, model)
    else:
        raise InputFileError("COLMAP workspace without images/ (expected images/ next to sparse/)", root)
    images = list_images(image_dir)
    if not images:
        raise _no_photos(image_dir)
    return InputSpec(
        root=root,
        kind=InputKind.COLMAP,
        image_dir=image_dir,
        image_names=images,
        known_cameras=chosen,
        models=models,
        dense_dir=dense_dir,
    )


def resolve_input(path: str | Path, model: int | None = None) -> InputSpec:
    """Resolve INPUT (a folder of photos, a COLMAP workspace or a data_synth scene) into an :class:`InputSpec`.

    model: which ``sparse/N`` of a COLMAP workspace to use (default: the one with the most images).
    Raises InputFileError (missing/unreadable folder, no photos, no model N), FormatError (bad scene.json),
    ConfigError (``model`` given for an input that has no COLMAP models).
    """
    root = Path(path)
    if not root.exists():
        raise InputFileError("input does not exist", root)
    if not root.is_dir():
        raise InputFileError("input is not a folder (expected a folder of photos, a COLMAP workspace or a scene)", root)
    if (root / SCENE_FILE_NAME).is_file() and (root / "images").is_dir() and _is_model(root / "sparse" / "0"):
        if model not in (None, 0):
            raise ConfigError(f"a data_synth scene has one camera model (sparse/0); got model {model}")
        return _resolve_synth(root)
    if (root / "sparse").is_dir() or (root / "dense" / "sparse").is_dir():
        return _resolve_colmap(root, model)
    if model is not None:
        raise ConfigError(f"model {model} was asked for, but {root} is a folder of photos without COLMAP models")
    images = list_images(root)
    image_dir = root
    if not images and (root / "images").is_dir():
        image_dir = root / "images"
        images = list_images(image_dir)
    if not images:
        raise _no_photos(root, (root / "images").is_dir())
    return InputSpec(root=root, kind=InputKind.PHOTOS, image_dir=image_dir, image_names=images)


def select_holdout(names: Sequence[str], every: int = DEFAULT_HOLDOUT_EVERY) -> tuple[str, ...]:
    """Every ``every``-th photo in name order: the every-th, 2·every-th, ... (1-based), so that the first and
    the last photo of a sequence stay in training and held-out views are interpolated, not extrapolated.

    every = 0: none. Raises ConfigError for every < 0 or every = 1 (nothing would be left to train on).
    """
    if every < 0 or every == 1:
        raise ConfigError(f"holdout must be 0 (none) or N >= 2 (every N-th photo), got {every}")
    if every == 0:
        return ()
    ordered = sorted(names)
    return tuple(ordered[i] for i in range(every - 1, len(ordered), every))


def choose_holdout(spec: InputSpec, every: int | None = None) -> Holdout:
    """The held-out views of a run: ``every`` None = the input's own held-out views when it brings some (a scene's
    ``test/``), otherwise every 8th photo; 0 = none; N = every N-th photo of ``spec.image_names``."""
    if every is None:
        if spec.has_own_holdout:
            return Holdout(spec.test_names, "input", spec.test_photos, spec.test_model)
        every = DEFAULT_HOLDOUT_EVERY
    names = select_holdout(spec.image_names, every)
    return Holdout(names, "every" if names else "none", spec.image_dir if names else None, None)
