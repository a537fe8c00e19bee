"""Survey control files: ground control / check points (``gcp.csv``) and image marks (``marks.csv``).

GCP file, comma-separated with a header row naming the columns (any order, case-insensitive)::

    # units: m            (optional: the unit of X, Y, Z and the sigmas; else the run's --units)
    # crs: EPSG:32632     (optional: the CRS of X, Y, Z; must agree with the run's --crs)
    id,X,Y,Z,sigma_xy,sigma_z,role
    T00,500012.314,5000043.210,300.052,0.005,0.008,control
    T01,500051.002,4999987.113,300.049,,,check

``id`` is any name without commas; ``X, Y, Z`` the surveyed coordinates (easting, northing, height); ``sigma_xy``
and ``sigma_z`` (optional columns, a blank cell = unknown) the survey's standard deviations, horizontal (per axis)
and vertical; ``role`` is ``control`` (held in the adjustment) or ``check`` (only compared afterwards). Lines
starting with ``#`` are comments, blank lines are skipped.

Marks file, comma-separated with a header row::

    image,point_id,u,v
    train_003.png,T00,152.25,88.5

``u, v`` are pixel coordinates in COLMAP's convention (the top-left pixel's centre is (0.5, 0.5)), in the photo as
given (distorted). Coordinates are read in float64 and converted to metres on input (:class:`core.units.Units`).
Every problem is a :class:`~core.errors.FormatError` or :class:`~core.errors.DataError` naming the file and the
line.
"""

from __future__ import annotations

import csv
import enum
import io
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import DataError, FormatError, InputFileError
from core.io.atomic import write_text_atomic
from core.units import Units


class Role(str, enum.Enum):
    """What a surveyed point is for: ``control`` points hold the adjustment, ``check`` points only measure it."""

    CONTROL = "control"
    CHECK = "check"


@dataclass(frozen=True)
class ControlPoint:
    """One surveyed point: ``xyz_m`` (3,) float64 metres in the file's frame, the survey's ``sigma_xy_m`` (per
    horizontal axis) and ``sigma_z_m`` (metres, None when not given), its ``role`` and the file ``line`` it is on."""

    id: str
    xyz_m: np.ndarray
    role: Role
    sigma_xy_m: float | None = None
    sigma_z_m: float | None = None
    line: int = 0


@dataclass(frozen=True)
class ControlPoints:
    """The points of a GCP file (in file order), its unit and its CRS (None when the file names none)."""

    path: Path
    points: tuple[ControlPoint, ...]
    units: Units = Units.M
    crs: str | None = None

    def by_id(self) -> dict[str, ControlPoint]:
        return {p.id: p for p in self.points}

    def with_role(self, role: Role) -> tuple[ControlPoint, ...]:
        return tuple(p for p in self.points if p.role is role)


@dataclass(frozen=True)
class Mark:
    """A point seen in a photo: ``image`` name, ``point_id``, pixel ``uv`` (2,) float64 (COLMAP convention);
    ``source`` is ``detected`` or ``manual``; ``line`` the marks file line (0 for detected marks)."""

    image: str
    point_id: str
    uv: np.ndarray
    source: str = "manual"
    line: int = 0


_GCP_REQUIRED = ("id", "x", "y", "z", "role")
_MARK_COLUMNS = ("image", "point_id", "u", "v")


def _read_text(path: Path, what: str) -> str:
    if not path.is_file():
        raise InputFileError(f"{what} file does not exist", path)
    try:
        return path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as err:
        raise InputFileError(f"cannot read the {what} file ({err})", path) from err


def _rows(text: str) -> tuple[list[tuple[int, list[str]]], dict[str, str]]:
    """Non-blank, non-comment CSV rows with their line numbers, and the ``# key: value`` comments."""
    rows, meta = [], {}
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            key, sep, value = stripped[1:].partition(":")
            if sep:
                meta[key.strip().lower()] = value.strip()
            continue
        rows.append((number, [c.strip() for c in next(csv.reader([line]))]))
    return rows, meta


def _header(rows: list[tuple[int, list[str]]], required: Sequence[str], path: Path) -> dict[str, int]:
    if not rows:
        raise FormatError(f"the file holds no header row ({','.join(required)})", path)
    number, cells = rows[0]
    columns = {c.lower(): i for i, c in enumerate(cells)}
    missing = [c for c in required if c not in columns]
    if missing:
        got = ",".join(cells)
        raise FormatError(f"line {number}: the header lacks column(s) {', '.join(missing)}; got {got}", path)
    return columns


def _number(cell: str, what: str, number: int, path: Path, blank_ok: bool = False) -> float | None:
    if cell == "" and blank_ok:
        return None
    try:
        value = float(cell)
    except ValueError:
        raise FormatError(f"line {number}: {what} must be a number, got {cell!r}", path) from None
    if not math.isfinite(value):
        raise FormatError(f"line {number}: {what} must be finite, got {cell!r}", path)
    return value


def read_gcp_csv(path: str | PathLike[str], units: Units | str = Units.M, crs: str | None = None) -> ControlPoints:
    """Read a GCP file (module docstring) → :class:`ControlPoints` in metres.

    units: the unit of the coordinates unless the file declares its own (``# units: ft``). crs: the run's CRS
    (``--crs``); a file that declares another is refused. Raises InputFileError (missing), FormatError (header,
    numbers, role) and DataError (an id given twice, a negative sigma, a CRS that disagrees), naming the line.
    """
    path = Path(path)
    rows, meta = _rows(_read_text(path, "GCP"))
    file_units = Units.parse(meta["units"]) if "units" in meta else Units.parse(units)
    file_crs = meta.get("crs") or None
    if crs and file_crs and crs.strip().upper() != file_crs.strip().upper():
        line = next(n for n, raw in enumerate(path.read_text(encoding="utf-8-sig").splitlines(), 1) if "crs" in raw)
        raise DataError(f"line {line}: the file's CRS {file_crs} disagrees with the run's CRS {crs}", path)
    columns = _header(rows, _GCP_REQUIRED, path)
    points: list[ControlPoint] = []
    seen: dict[str, int] = {}
    for number, cells in rows[1:]:
        if len(cells) < len(columns):
            raise FormatError(f"line {number}: expected {len(columns)} fields, got {len(cells)}", path)
        pid = cells[columns["id"]]
        if not pid:
            raise FormatError(f"line {number}: the point id is empty", path)
        if pid in seen:
            raise DataError(f"line {number}: point {pid!r} is listed twice (first on line {seen[pid]})", path)
        xyz = np.array([_number(cells[columns[c]], c.upper(), number, path) for c in "xyz"], dtype=np.float64)
        sig = [
            _number(cells[columns[c]], c, number, path, blank_ok=True) if c in columns else None
            for c in ("sigma_xy", "sigma_z")
        ]
        if any(s is not None and s < 0 for s in sig):
            raise DataError(f"line {number}: sigma must be >= 0, got {sig}", path)
        role_text = cells[columns["role"]].lower()
        try:
            role = Role(role_text)
        except ValueError:
            raise FormatError(f"line {number}: role must be control | check, got {role_text!r}", path) from None
        sig_m = [None if s is None else float(file_units.to_metres(s)) for s in sig]
        points.append(ControlPoint(pid, file_units.to_metres(xyz), role, sig_m[0], sig_m[1], number))
        seen[pid] = number
    if not points:
        raise FormatError("the GCP file holds no point", path)
    return ControlPoints(path, tuple(points), file_units, file_crs or crs)


def write_gcp_csv(
    path: str | PathLike[str], points: Iterable[ControlPoint], units: Units | str = Units.M, crs: str | None = None
) -> None:
    """Write points (metres) as a GCP file in ``units`` (declared in a ``# units`` line), atomically."""
    units = Units.parse(units)
    out = io.StringIO()
    out.write(f"# units: {units.value}\n")
    if crs:
        out.write(f"# crs: {crs}\n")
    out.write("id,X,Y,Z,sigma_xy,sigma_z,role\n")
    for p in points:
        xyz = units.from_metres(np.asarray(p.xyz_m, dtype=np.float64))
        sig = ["" if s is None else repr(float(units.from_metres(s))) for s in (p.sigma_xy_m, p.sigma_z_m)]
        out.write(f"{p.id},{float(xyz[0])!r},{float(xyz[1])!r},{float(xyz[2])!r},{sig[0]},{sig[1]},{p.role.value}\n")
    write_text_atomic(path, out.getvalue())


def read_marks_csv(path: str | PathLike[str]) -> tuple[Mark, ...]:
    """Read a marks file (module docstring). A (photo, point) pair given twice is refused (FormatError / DataError
    naming the line)."""
    path = Path(path)
    rows, _ = _rows(_read_text(path, "marks"))
    columns = _header(rows, _MARK_COLUMNS, path)
    marks: list[Mark] = []
    seen: dict[tuple[str, str], int] = {}
    for number, cells in rows[1:]:
        if len(cells) < len(columns):
            raise FormatError(f"line {number}: expected {len(columns)} fields, got {len(cells)}", path)
        image, pid = cells[columns["image"]], cells[columns["point_id"]]
        if not image or not pid:
            raise FormatError(f"line {number}: image and point_id must not be empty", path)
        key = (image, pid)
        if key in seen:
            first = seen[key]
            raise DataError(f"line {number}: point {pid!r} is marked twice in {image} (first on line {first})", path)
        uv = np.array([_number(cells[columns[c]], c, number, path) for c in "uv"], dtype=np.float64)
        marks.append(Mark(image, pid, uv, "manual", number))
        seen[key] = number
    return tuple(marks)


def write_marks_csv(path: str | PathLike[str], marks: Iterable[Mark]) -> None:
    """Write marks (``image,point_id,u,v``, COLMAP pixel convention), atomically."""
    out = io.StringIO()
    out.write("image,point_id,u,v\n")
    for m in marks:
        out.write(f"{m.image},{m.point_id},{float(m.uv[0])!r},{float(m.uv[1])!r}\n")
    write_text_atomic(path, out.getvalue())


def merge_marks(detected: Iterable[Mark], manual: Iterable[Mark]) -> tuple[Mark, ...]:
    """Detected marks with the manual ones over them: a manual mark replaces the detected mark of the same photo and
    point, or adds one. Sorted by (point, image)."""
    out = {(m.image, m.point_id): m for m in detected}
    out.update({(m.image, m.point_id): m for m in manual})
    return tuple(sorted(out.values(), key=lambda m: (m.point_id, m.image)))
