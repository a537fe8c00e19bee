"""The accuracy statement's maths (eval.accuracy) on residuals whose RMSEs are known in closed form."""

from __future__ import annotations

import math

import pytest

from eval.accuracy import (
    MIN_CHECK_POINTS,
    AccuracyStatement,
    PointResidual,
    accuracy_class_cm,
    accuracy_statement,
    statement_from_json,
)


def _point(k: int, role: str, d: tuple[float, float, float], sxy: float | None = None, sz: float | None = None):
    return PointResidual(f"P{k}", role, (float(k), 0.0, 0.0), *d, marks=3, reprojection_px=0.1, sigma_xy_m=sxy,
                         sigma_z_m=sz)  # fmt: skip


def _signs(n: int, dx: float, dy: float, dz: float, **kw) -> list[PointResidual]:
    """``n`` check points with residuals ±dx, ±dy, ±dz (alternating): RMSE_x = dx etc., means 0 for even n."""
    return [_point(k, "check", (dx * (-1) ** k, dy * (-1) ** (k // 2), dz * (-1) ** k), **kw) for k in range(n)]


def test_rmse_per_axis_horizontal_vertical_3d_without_survey_sigma():
    s = accuracy_statement(_signs(4, 0.03, 0.04, 0.05))
    assert s.check_points == 4
    assert (s.rmse_x, s.rmse_y, s.rmse_z) == pytest.approx((0.03, 0.04, 0.05), abs=1e-15)
    assert s.rmse_h_measured == pytest.approx(0.05)  # 3-4-5
    assert s.rmse_h == pytest.approx(0.05) and s.rmse_v == pytest.approx(0.05)
    assert s.rmse_3d == pytest.approx(math.sqrt(0.05**2 + 0.05**2))
    assert (s.mean_dx, s.mean_dy, s.mean_dz) == pytest.approx((0.0, 0.0, 0.0), abs=1e-15)
    assert s.nssda_h95 == pytest.approx(1.7308 * 0.05) and s.nssda_v95 == pytest.approx(1.96 * 0.05)
    assert s.class_h_cm == 5.0 and s.class_v_cm == 5.0
    assert s.informal and not s.survey_sigmas_given


def test_check_point_survey_sigma_is_folded_in_as_edition_2_prescribes():
    s = accuracy_statement(_signs(4, 0.03, 0.04, 0.05, sxy=0.01, sz=0.02))
    h2, v2 = math.sqrt(2) * 0.01, 0.02  # per-axis sigma -> horizontal RMSE sqrt(2)·σ
    assert s.rmse_h_survey == pytest.approx(h2) and s.rmse_v_survey == pytest.approx(v2)
    assert s.rmse_h == pytest.approx(math.sqrt(0.05**2 + h2**2))
    assert s.rmse_v == pytest.approx(math.sqrt(0.05**2 + v2**2))
    assert s.rmse_3d == pytest.approx(math.sqrt(s.rmse_h**2 + s.rmse_v**2))
    assert s.class_h_cm == 7.5 and s.class_v_cm == 7.5  # 5.20 cm and 5.39 cm round up to the 7.5-cm class
    assert s.survey_sigmas_given


def test_control_points_do_not_enter_the_statement_and_thirty_checks_make_it_formal():
    points = _signs(MIN_CHECK_POINTS, 0.01, 0.01, 0.02) + [_point(99, "control", (1.0, 1.0, 1.0))]
    s = accuracy_statement(points)
    assert s.check_points == MIN_CHECK_POINTS and not s.informal
    assert s.rmse_x == pytest.approx(0.01) and s.rmse_z == pytest.approx(0.02)
    assert s.control_points == 1 and s.control_rmse_3d == pytest.approx(math.sqrt(3.0))


def test_mean_error_shows_a_systematic_shift():
    s = accuracy_statement([_point(k, "check", (0.02, -0.01, 0.03)) for k in range(5)])
    assert (s.mean_dx, s.mean_dy, s.mean_dz) == pytest.approx((0.02, -0.01, 0.03))
    assert s.rmse_x == pytest.approx(0.02)


def test_no_check_point_gives_nan_figures_not_an_error():
    s = accuracy_statement([_point(0, "control", (0.0, 0.0, 0.0))])
    assert s.check_points == 0 and math.isnan(s.rmse_h) and s.informal
    assert s.to_json()["rmse_h"] is None


@pytest.mark.parametrize(("rmse_m", "cm"), [(0.004, 0.5), (0.005, 0.5), (0.0051, 1.0), (0.08, 10.0), (12.3, 1230.0)])
def test_accuracy_class_rounds_up_to_the_common_values(rmse_m, cm):
    assert accuracy_class_cm(rmse_m) == cm


def test_statement_json_round_trip():
    s = accuracy_statement(_signs(3, 0.01, 0.02, 0.03, sxy=0.001) + [_point(7, "control", (0.0, 0.0, 0.0))])
    back = statement_from_json(s.to_json())
    assert isinstance(back, AccuracyStatement)
    assert back.rmse_h == pytest.approx(s.rmse_h) and back.points == s.points
