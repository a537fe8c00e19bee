"""GCP and marks files (core.io.control): round trips, units, and bad input named by file and line."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import DataError, FormatError, InputFileError
from core.io.control import (
    ControlPoint,
    Mark,
    Role,
    merge_marks,
    read_gcp_csv,
    read_marks_csv,
    write_gcp_csv,
    write_marks_csv,
)


def test_gcp_round_trip_keeps_float64_georeferenced_coordinates(tmp_path):
    pts = [
        ControlPoint("A", np.array([500012.3141592653, 5000043.2100000001, 300.052]), Role.CONTROL, 0.005, 0.008),
        ControlPoint("B", np.array([500051.0, 4999987.113, 299.9]), Role.CHECK),
    ]
    write_gcp_csv(tmp_path / "g.csv", pts, units="ft", crs="EPSG:32632")
    back = read_gcp_csv(tmp_path / "g.csv")
    assert back.crs == "EPSG:32632" and back.units.value == "ft"
    assert [p.id for p in back.points] == ["A", "B"] and [p.role for p in back.points] == [Role.CONTROL, Role.CHECK]
    assert back.points[0].xyz_m == pytest.approx(pts[0].xyz_m, abs=1e-9)  # through feet and back, float64
    assert back.points[0].sigma_z_m == pytest.approx(0.008) and back.points[1].sigma_xy_m is None


def test_gcp_units_and_optional_sigma_columns(tmp_path):
    path = tmp_path / "g.csv"
    path.write_text("ID,x,y,z,role\n# a comment\n\nP1,1000,2000,300,check\n")
    got = read_gcp_csv(path, units="mm")
    assert got.points[0].xyz_m == pytest.approx([1.0, 2.0, 0.3]) and got.points[0].line == 4


@pytest.mark.parametrize(
    ("text", "error", "words"),
    [
        ("id,X,Y,Z\nA,1,2,3\n", FormatError, "line 1: the header lacks column(s) role"),
        ("id,X,Y,Z,role\nA,1,x,3,control\n", FormatError, "line 2: Y must be a number"),
        ("id,X,Y,Z,role\nA,1,2,nan,control\n", FormatError, "line 2: Z must be finite"),
        ("id,X,Y,Z,role\nA,1,2,3,gcp\n", FormatError, "line 2: role must be control | check"),
        ("id,X,Y,Z,role\nA,1,2,3,control\nA,1,2,3,check\n", DataError, "line 3: point 'A' is listed twice"),
        ("id,X,Y,Z,sigma_xy,sigma_z,role\nA,1,2,3,-1,,check\n", DataError, "line 2: sigma must be >= 0"),
        ("id,X,Y,Z,role\n", FormatError, "holds no point"),
        ("id,X,Y,Z,role\nA,1,2\n", FormatError, "line 2: expected 5 fields"),
    ],
)
def test_bad_gcp_files_name_the_line(tmp_path, text, error, words):
    path = tmp_path / "g.csv"
    path.write_text(text)
    with pytest.raises(error, match=None) as info:
        read_gcp_csv(path)
    assert words in str(info.value) and str(path) in str(info.value)


def test_gcp_crs_that_disagrees_with_the_run_is_refused(tmp_path):
    path = tmp_path / "g.csv"
    path.write_text("# crs: EPSG:32633\nid,X,Y,Z,role\nA,1,2,3,check\n")
    with pytest.raises(DataError, match="line 1: the file's CRS EPSG:32633 disagrees with the run's CRS EPSG:32632"):
        read_gcp_csv(path, crs="EPSG:32632")
    assert read_gcp_csv(path, crs="epsg:32633").crs == "EPSG:32633"


def test_missing_gcp_file(tmp_path):
    with pytest.raises(InputFileError, match="GCP file does not exist"):
        read_gcp_csv(tmp_path / "none.csv")


def test_marks_round_trip_and_manual_marks_override_detected_ones(tmp_path):
    marks = [Mark("a.png", "P1", np.array([10.25, 20.5])), Mark("b.png", "P1", np.array([1.0, 2.0]))]
    write_marks_csv(tmp_path / "m.csv", marks)
    back = read_marks_csv(tmp_path / "m.csv")
    assert [(m.image, m.point_id) for m in back] == [("a.png", "P1"), ("b.png", "P1")]
    assert back[0].uv == pytest.approx([10.25, 20.5]) and back[0].line == 2 and back[0].source == "manual"
    detected = [Mark("a.png", "P1", np.array([11.0, 21.0]), "detected"), Mark("c.png", "P2", np.zeros(2), "detected")]
    merged = merge_marks(detected, back)
    assert [(m.image, m.point_id, m.source) for m in merged] == [
        ("a.png", "P1", "manual"),
        ("b.png", "P1", "manual"),
        ("c.png", "P2", "detected"),
    ]


def test_a_point_marked_twice_in_one_photo_is_refused(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("image,point_id,u,v\na.png,P1,1,2\na.png,P1,3,4\n")
    with pytest.raises(DataError, match="line 3: point 'P1' is marked twice in a.png"):
        read_marks_csv(path)
