"""What an input folder holds: photos, known cameras, held-out views and ground truth.

INPUT is a folder of photos (directly, or under ``images/``), a COLMAP workspace (``images/`` + ``sparse/`` or
``sparse/N``) or a data_synth scene (``images/``, ``sparse/0`` true cameras, ``sparse/test`` + ``test/`` held-out
views, ``gt/`` truth, ``scene.json``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

from core.errors import FormatError, InputFileError

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")


@dataclass(frozen=True)
class InputSpec:
    """A resolved input folder. Paths are None where the input has no such thing."""

    root: Path
    kind: str  # "photos", "colmap" or "synthetic"
    image_dir: Path
    image_names: tuple[str, ...]
    known_cameras: Path | None = None  # COLMAP model of the photos' cameras
    test_model: Path | None = None  # cameras of the input's own held-out views
    test_photos: Path | None = None
    test_labels: Path | None = None  # per-pixel material ids of the held-out views
    train_labels: Path | None = None
    reference_cloud: Path | None = None  # ground-truth cloud (LiDAR)
    scene_json: Path | None = None
    gsd_m: float | None = None
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    non_collaborative_ids: tuple[int, ...] = ()

    @property
    def has_own_holdout(self) -> bool:
        return self.test_model is not None and self.test_photos is not None


def list_images(folder: Path) -> tuple[str, ...]:
    """Photo file names in ``folder`` (not recursive), sorted; suffixes compared case-insensitively."""
    return tuple(sorted(p.name for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES))


def _existing(path: Path) -> Path | None:
    return path if path.exists() else None


def _largest_model(sparse: Path, model: int | None) -> Path:
    if (sparse / "cameras.bin").is_file() or (sparse / "cameras.txt").is_file():
        return sparse
    candidates = sorted(p for p in sparse.iterdir() if p.is_dir() and p.name.isdigit())
    if model is not None:
        chosen = sparse / str(model)
        if chosen not in candidates:
            raise InputFileError(f"no model {model} here (found: {', '.join(p.name for p in candidates)})", sparse)
        return chosen
    if not candidates:
        raise InputFileError("no COLMAP model here (cameras.bin/.txt or sparse/N/)", sparse)
    return max(candidates, key=lambda p: sum(f.stat().st_size for f in p.glob("images.*")))


def resolve_input(path: str | PathLike[str], model: int | None = None) -> InputSpec:
    """Describe INPUT (see the module docstring); raises :class:`InputFileError` when it holds no photos."""
    root = Path(path)
    if not root.is_dir():
        raise InputFileError("input is not a folder (expected photos, a COLMAP workspace or a data_synth scene)", root)
    image_dir = root / "images" if (root / "images").is_dir() else root
    names = list_images(image_dir)
    if not names:
        raise InputFileError(f"found no photos ({', '.join(IMAGE_SUFFIXES)}) here", image_dir)
    scene_json = root / "scene.json"
    if (root / "sparse" / "0").is_dir() and scene_json.is_file():
        try:
            meta = json.loads(scene_json.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError) as err:
            raise FormatError(f"not valid JSON ({err})", scene_json) from err
        gsd = meta.get("gsd_m")
        return InputSpec(
            root=root,
            kind="synthetic",
            image_dir=image_dir,
            image_names=names,
            known_cameras=root / "sparse" / "0",
            test_model=_existing(root / "sparse" / "test"),
            test_photos=_existing(root / "test"),
            test_labels=_existing(root / "gt" / "labels" / "test"),
            train_labels=_existing(root / "gt" / "labels" / "train"),
            reference_cloud=_existing(root / "gt" / "lidar.ply"),
            scene_json=scene_json,
            gsd_m=float(gsd) if gsd else None,
            origin=tuple(float(v) for v in meta.get("origin", (0.0, 0.0, 0.0))),
            non_collaborative_ids=tuple(
                int(m["id"]) for m in meta.get("materials", []) if not m.get("collaborative", True)
            ),
        )
    if (root / "sparse").is_dir():
        return InputSpec(
            root=root, kind="colmap", image_dir=image_dir, image_names=names,
            known_cameras=_largest_model(root / "sparse", model),
        )  # fmt: skip
    return InputSpec(root=root, kind="photos", image_dir=image_dir, image_names=names)


def select_holdout(names: tuple[str, ...] | list[str], every: int = 8) -> tuple[str, ...]:
    """Every ``every``-th photo in name order, starting with the ``every``-th (none when ``every`` is 0)."""
    if every <= 0:
        return ()
    ordered = sorted(names)
    return tuple(ordered[every - 1 :: every])
