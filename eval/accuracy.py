"""The accuracy statement of a controlled survey, after the ASPRS Positional Accuracy Standards for Digital
Geospatial Data, Edition 2 (2023), with the older NSSDA 95 % figures beside it.

Residuals are model minus survey, per check point, in metres, in the control frame (x = easting, y = northing,
z = height). Over the ``n`` check points:

- RMSE_x, RMSE_y, RMSE_z: ``sqrt(mean(d²))`` per axis; the mean errors are reported too (a systematic error);
- RMSE_H1 = sqrt(RMSE_x² + RMSE_y²) and RMSE_V1 = RMSE_z: what the check points measure;
- Edition 2 adds the check points' own survey error: RMSE_H = sqrt(RMSE_H1² + RMSE_H2²) and
  RMSE_V = sqrt(RMSE_V1² + RMSE_V2²), where RMSE_H2 and RMSE_V2 are the survey's horizontal and vertical RMSE
  (here from the GCP file's sigmas: RMSE_H2 = sqrt(mean(2·σ_xy²)) with σ_xy per horizontal axis, RMSE_V2 =
  sqrt(mean(σ_z²)); a check point without sigmas counts as exact, and the statement says so);
- RMSE_3D = sqrt(RMSE_H² + RMSE_V²);
- NSSDA (FGDC 1998) at 95 % confidence: 1.7308 · RMSE_H (valid when RMSE_x ≈ RMSE_y) and 1.96 · RMSE_V (normal
  errors); Edition 2 dropped them, clients still ask;
- the accuracy class met: Edition 2 names a class by its RMSE ("X-cm"); the statement gives the smallest of the
  common class values (:data:`CLASS_VALUES_CM`) at or above RMSE_H and RMSE_V;
- Edition 2 asks for at least 30 check points (:data:`MIN_CHECK_POINTS`); with fewer the statement is informal.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

NSSDA_H95 = 1.7308
NSSDA_V95 = 1.96
MIN_CHECK_POINTS = 30
CLASS_VALUES_CM = (0.5, 1.0, 1.25, 2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 20.0, 25.0, 30.0, 50.0, 100.0, 200.0, 500.0,
                   1000.0)  # fmt: skip
"""Common accuracy class values (cm) the statement rounds up to; beyond the last the class is the RMSE itself."""


@dataclass(frozen=True)
class PointResidual:
    """One surveyed point after the adjustment: ``id``, ``role`` (control | check), ``survey_m`` (3,) its surveyed
    coordinates (local control frame, metres), ``dx, dy, dz`` model minus survey (metres), ``marks`` photos it was
    triangulated from, ``reprojection_px`` RMS reprojection error of its marks (px), the survey's ``sigma_xy_m`` and
    ``sigma_z_m`` (None when not given)."""

    id: str
    role: str
    survey_m: tuple[float, float, float]
    dx: float
    dy: float
    dz: float
    marks: int
    reprojection_px: float
    sigma_xy_m: float | None = None
    sigma_z_m: float | None = None


@dataclass(frozen=True)
class AccuracyStatement:
    """The statement over the check points (metres; see the module docstring for each figure)."""

    check_points: int = 0
    rmse_x: float = math.nan
    rmse_y: float = math.nan
    rmse_z: float = math.nan
    mean_dx: float = math.nan
    mean_dy: float = math.nan
    mean_dz: float = math.nan
    rmse_h_measured: float = math.nan
    rmse_v_measured: float = math.nan
    rmse_h_survey: float = 0.0
    rmse_v_survey: float = 0.0
    survey_sigmas_given: bool = False
    rmse_h: float = math.nan
    rmse_v: float = math.nan
    rmse_3d: float = math.nan
    nssda_h95: float = math.nan
    nssda_v95: float = math.nan
    class_h_cm: float = math.nan
    class_v_cm: float = math.nan
    informal: bool = True
    control_points: int = 0
    control_rmse_3d: float = math.nan
    points: tuple[PointResidual, ...] = field(default=())

    def to_json(self) -> dict[str, object]:
        """JSON-ready dict (NaN as None)."""
        out = asdict(self)
        out["points"] = [asdict(p) for p in self.points]
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in out.items()}


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else math.nan


def accuracy_class_cm(rmse_m: float) -> float:
    """The smallest common class value (cm, :data:`CLASS_VALUES_CM`) at or above ``rmse_m``; beyond them the RMSE
    in cm rounded up to 1 cm; NaN for NaN."""
    if not math.isfinite(rmse_m):
        return math.nan
    cm = rmse_m * 100.0
    for value in CLASS_VALUES_CM:
        if cm <= value + 1e-12:
            return value
    return float(math.ceil(cm))


def accuracy_statement(points: Sequence[PointResidual]) -> AccuracyStatement:
    """The statement (module docstring) over the check points of ``points``; control points are kept in ``points``
    and summarised by their RMSE_3D only (they were held, so they do not measure accuracy)."""
    check = [p for p in points if p.role == "check"]
    control = [p for p in points if p.role == "control"]
    d = np.array([[p.dx, p.dy, p.dz] for p in check], dtype=np.float64).reshape(-1, 3)
    rx, ry, rz = (_rms(d[:, k]) for k in range(3))
    h1, v1 = math.hypot(rx, ry) if check else math.nan, rz
    given = [p for p in check if p.sigma_xy_m is not None or p.sigma_z_m is not None]
    sxy = np.array([p.sigma_xy_m or 0.0 for p in check])
    sz = np.array([p.sigma_z_m or 0.0 for p in check])
    h2 = float(np.sqrt(np.mean(2.0 * sxy**2))) if check else 0.0
    v2 = float(np.sqrt(np.mean(sz**2))) if check else 0.0
    rh, rv = math.hypot(h1, h2), math.hypot(v1, v2)
    dc = np.array([[p.dx, p.dy, p.dz] for p in control], dtype=np.float64).reshape(-1, 3)
    return AccuracyStatement(
        check_points=len(check),
        rmse_x=rx,
        rmse_y=ry,
        rmse_z=rz,
        mean_dx=float(d[:, 0].mean()) if check else math.nan,
        mean_dy=float(d[:, 1].mean()) if check else math.nan,
        mean_dz=float(d[:, 2].mean()) if check else math.nan,
        rmse_h_measured=h1,
        rmse_v_measured=v1,
        rmse_h_survey=h2,
        rmse_v_survey=v2,
        survey_sigmas_given=bool(given),
        rmse_h=rh,
        rmse_v=rv,
        rmse_3d=math.hypot(rh, rv),
        nssda_h95=NSSDA_H95 * rh,
        nssda_v95=NSSDA_V95 * rv,
        class_h_cm=accuracy_class_cm(rh),
        class_v_cm=accuracy_class_cm(rv),
        informal=len(check) < MIN_CHECK_POINTS,
        control_points=len(control),
        control_rmse_3d=_rms(np.linalg.norm(dc, axis=1)) if control else math.nan,
        points=tuple(points),
    )


def statement_from_json(data: dict) -> AccuracyStatement:
    """Inverse of :meth:`AccuracyStatement.to_json` (None back to NaN)."""
    pts = tuple(
        PointResidual(**{**p, "survey_m": tuple(p["survey_m"])}) for p in data.get("points", ())
    )  # fmt: skip
    known = {f for f in AccuracyStatement.__dataclass_fields__ if f != "points"}
    values = {k: (math.nan if v is None and k not in ("survey_sigmas_given", "informal") else v)
              for k, v in data.items() if k in known}  # fmt: skip
    return AccuracyStatement(**values, points=pts)
