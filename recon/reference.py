"""References for alignment and evaluation: camera centres (``--reference``) and Strecha ``.camera`` files.

Reference camera centres (:func:`read_reference`), the frame the SfM model is aligned to:

- a text file, one image a line: ``NAME X Y Z`` (the format of COLMAP's ``model_aligner --ref_images_path``);
  ``#`` starts a comment, blank lines are ignored, fields are separated by whitespace; a name may contain spaces
  (the last three fields are the coordinates).
- a COLMAP model folder (``cameras/images/points3D`` ``.bin`` or ``.txt``): its camera centres.

Coordinates are given in ``units`` (m, mm, cm, ft) and converted to metres on input: the toolkit works in metres
and prints lengths back in the user's unit (:class:`core.units.Units`). Large coordinates (UTM, national grids)
stay float64.

Strecha et al. ``.camera`` files (fountain-P11), one file per image ``NAME.camera``: K (3 rows), radial
distortion (1 row), R (3 rows), camera centre C (1 row), ``w h``; a world point X projects as
``K·[Rᵀ | −Rᵀ·C]·X`` (R is camera-to-world).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np

from core.cameras import Camera, Cameras, View
from core.errors import DataError, FormatError, InputFileError
from core.units import Units

__all__ = [
    "Reference",
    "ReferenceKind",
    "Units",
    "read_reference",
    "read_reference_centers",
    "read_reference_text",
    "read_strecha_camera",
    "read_strecha_cameras",
    "write_reference_text",
]


class ReferenceKind(str, enum.Enum):
    TEXT = "text"
    MODEL = "model"


@dataclass(frozen=True)
class Reference:
    """Reference camera centres by image name, in metres (float64 (3,) arrays, the reference's frame).

    units: the unit the file was written in (lengths in reports are printed in it).
    """

    path: Path
    kind: ReferenceKind
    units: Units
    centers: Mapping[str, np.ndarray]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(sorted(self.centers))

    def positions(self, names: Sequence[str]) -> np.ndarray:
        """(N, 3) float64 metres for ``names``, in that order (KeyError for a name without a centre)."""
        return np.stack([self.centers[n] for n in names]) if names else np.zeros((0, 3))

    def extent_m(self) -> float:
        """Diagonal of the centres' bounding box, metres (0 for fewer than two centres)."""
        if len(self.centers) < 2:
            return 0.0
        c = self.positions(self.names)
        return float(np.linalg.norm(c.max(axis=0) - c.min(axis=0)))


def _frozen(centers: dict[str, np.ndarray]) -> Mapping[str, np.ndarray]:
    for c in centers.values():
        c.setflags(write=False)
    return MappingProxyType(centers)


def read_reference_text(path: str | Path, units: Units | str = Units.M) -> Reference:
    """Read a ``NAME X Y Z`` file (coordinates in ``units``) → :class:`Reference` in metres.

    Raises InputFileError (missing/unreadable), FormatError naming the line (too few fields, not a number,
    NaN/inf, a name given twice) or when the file holds no position.
    """
    path, units = Path(path), Units.parse(units)
    if not path.is_file():
        raise InputFileError("reference file does not exist", path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as err:
        raise InputFileError(f"cannot read the reference file ({err})", path) from err
    centers: dict[str, np.ndarray] = {}
    lines: dict[str, int] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.rsplit(maxsplit=3)
        if len(fields) != 4:
            raise FormatError(f"line {number}: expected 'NAME X Y Z', got {raw.strip()!r}", path)
        name = fields[0]
        got = " ".join(fields[1:])
        try:
            xyz = np.array([float(v) for v in fields[1:]], dtype=np.float64)
        except ValueError:
            raise FormatError(f"line {number}: coordinates must be numbers, got {got!r}", path) from None
        if not np.isfinite(xyz).all():
            raise FormatError(f"line {number}: coordinates must be finite, got {got!r}", path)
        if name in centers:
            raise FormatError(f"line {number}: image {name!r} is listed twice (first on line {lines[name]})", path)
        centers[name], lines[name] = units.to_metres(xyz), number
    if not centers:
        raise FormatError("reference file holds no 'NAME X Y Z' line", path)
    return Reference(path, ReferenceKind.TEXT, units, _frozen(centers))


def read_reference(path: str | Path, units: Units | str = Units.M) -> Reference:
    """A reference text file or a COLMAP model folder → camera centres in metres (see the module docstring)."""
    from core.io.colmap import read_model

    path, units = Path(path), Units.parse(units)
    if path.is_dir():
        cameras, _ = read_model(path)
        if len(cameras) == 0:
            raise FormatError("COLMAP model has no registered image", path)
        centers = {v.name: units.to_metres(np.asarray(v.center, dtype=np.float64)) for v in cameras}
        if not all(np.isfinite(c).all() for c in centers.values()):
            raise DataError("COLMAP model has NaN or infinite camera poses", path)
        return Reference(path, ReferenceKind.MODEL, units, _frozen(centers))
    return read_reference_text(path, units)


def write_reference_text(path: str | Path, centers: Mapping[str, np.ndarray], units: Units | str = Units.M) -> None:
    """Write centres given in metres as a ``NAME X Y Z`` file in ``units`` (17 significant digits), atomically."""
    from core.io.atomic import write_text_atomic

    units = Units.parse(units)
    rows = [f"# image name, camera centre X Y Z in {units.value}"]
    for name in sorted(centers):
        xyz = units.from_metres(np.asarray(centers[name], dtype=np.float64))
        if any(not math.isfinite(float(v)) for v in xyz):
            raise DataError(f"camera centre of {name!r} is not finite", path)
        rows.append(f"{name} " + " ".join(repr(float(v)) for v in xyz))
    write_text_atomic(path, "\n".join(rows) + "\n")


def read_strecha_camera(path: str | Path, image_id: int = 1, camera_id: int = 1) -> tuple[Camera, View]:
    """One ``.camera`` file → (PINHOLE Camera, View named after the file without ``.camera``)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError("camera file does not exist", path)
    rows = [line.split() for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    try:
        K = np.array(rows[0:3], dtype=np.float64)
        R = np.array(rows[4:7], dtype=np.float64)
        C = np.array(rows[7], dtype=np.float64)
        w, h = (int(float(v)) for v in rows[8][:2])
    except (ValueError, IndexError) as err:
        raise FormatError(f"not a Strecha .camera file ({err})", path) from err
    if K.shape != (3, 3) or R.shape != (3, 3) or C.shape != (3,):
        raise FormatError("not a Strecha .camera file (expected K 3x3, R 3x3, C 3)", path)
    cam = Camera.pinhole(K[0, 0], K[1, 1], K[0, 2], K[1, 2], w, h, camera_id)
    Rcw = R.T  # world-to-camera
    view = View.from_matrix(image_id, path.name.removesuffix(".camera"), camera_id, np.c_[Rcw, -Rcw @ C])
    return cam, view


def read_strecha_cameras(folder: str | Path) -> Cameras:
    """All ``*.camera`` files of a folder, one camera per image, ids in name order."""
    folder = Path(folder)
    files = sorted(folder.glob("*.camera"))
    if not files:
        raise InputFileError("no .camera files here", folder)
    cams, views = {}, {}
    for i, f in enumerate(files, start=1):
        cam, view = read_strecha_camera(f, i, i)
        cams[i], views[i] = cam, view
    return Cameras(cams, views)


def read_reference_centers(path: str | Path, units: str = "m") -> dict[str, np.ndarray]:
    """Camera centres by image name in metres (float64 (3,)), from a text file or a COLMAP model folder.

    As :func:`read_reference`, and at least 3 centres are required (a similarity needs them): FormatError otherwise.
    """
    ref = read_reference(path, units)
    if len(ref.centers) < 3:
        raise FormatError(f"needs at least 3 camera centres to align, found {len(ref.centers)}", ref.path)
    return {name: np.array(c) for name, c in ref.centers.items()}
