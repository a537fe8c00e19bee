"""Measurement exports (CSV, WGS84 GeoJSON), the PICKS.json format and measuring a picks file against a model.

Independent truth: the exact synthetic points; pyproj's own inverse transform (WGS84 → UTM) for the GeoJSON
(round trip to 1e-6 m: PROJ's UTM is accurate to nanometres near the central meridian); and an analytic
fact of UTM: easting 500000 m lies on the zone's central meridian (zone 32: 9° E) at every northing.
"""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest
from test_measure_triangulate import distorted_camera, exact_picks, ring_views

from core.cameras import Cameras
from core.errors import ConfigError, DataError, FormatError
from eval.measure import Measurements, measurements_from, to_geojson, triangulate
from eval.measure.export import distances_csv, points_csv
from eval.measure.picks import ImagePick, PicksFile, PointPicks, parse_picks, read_picks, write_picks
from eval.measure.project import Georeference, measure_picks, read_georeference

UTM_ORIGIN = np.array([500000.0, 5000000.0, 300.0])
TRUTH = np.array([[0.0, 0.0, 0.0], [0.1234, -0.0567, 0.0891], [-0.08, 0.11, 0.02]])


def measured(origin=UTM_ORIGIN, crs="EPSG:32632") -> Measurements:
    cam = distorted_camera()
    views = ring_views(3)
    points = [triangulate(exact_picks(cam, views, t), origin=origin, name=f"P{i}") for i, t in enumerate(TRUTH)]
    return measurements_from(points, [("P0", "P1"), ("P1", "P2")], "m", crs)


def test_csv_holds_world_coordinates_to_float64() -> None:
    m = measured()
    rows = list(csv.DictReader(io.StringIO(points_csv(m))))
    assert [r["id"] for r in rows] == ["P0", "P1", "P2"]
    for row, t in zip(rows, TRUTH, strict=True):
        world = np.array([float(row["x"]), float(row["y"]), float(row["z"])])
        np.testing.assert_allclose(world - UTM_ORIGIN, t, atol=1e-9)
        assert row["unit"] == "m" and row["crs"] == "EPSG:32632"
        assert float(row["sigma_3d"]) > 0 and int(row["n_rays"]) == 3
        assert row["images"] == "0001.png;0002.png;0003.png"
    d = list(csv.DictReader(io.StringIO(distances_csv(m))))
    assert float(d[0]["length"]) == pytest.approx(np.linalg.norm(TRUTH[1] - TRUTH[0]), abs=1e-9)
    assert float(d[0]["sigma"]) > 0


def test_geojson_is_wgs84_and_inverts_with_pyproj() -> None:
    from pyproj import Transformer

    m = measured()
    gj = to_geojson(m)
    assert gj["type"] == "FeatureCollection" and "crs" not in gj  # RFC 7946 §4: no crs member
    points = [f for f in gj["features"] if f["geometry"]["type"] == "Point"]
    lines = [f for f in gj["features"] if f["geometry"]["type"] == "LineString"]
    assert len(points) == 3 and len(lines) == 2
    back = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True)
    for f, t in zip(points, TRUTH, strict=True):
        lon, lat, h = f["geometry"]["coordinates"]
        assert -180 <= lon <= 180 and -90 <= lat <= 90
        e, n = back.transform(lon, lat)
        np.testing.assert_allclose([e, n, h], UTM_ORIGIN + t, atol=1e-6)
    # Easting 500000 is the central meridian of UTM zone 32 (9° E); northing 5e6 m is about 45.1° N.
    lon0, lat0, _ = points[0]["geometry"]["coordinates"]
    assert lon0 == pytest.approx(9.0, abs=1e-12)
    assert 45.0 < lat0 < 45.2
    assert lines[0]["properties"]["length"] == pytest.approx(np.linalg.norm(TRUTH[1]), abs=1e-9)


def test_geojson_needs_a_crs() -> None:
    with pytest.raises(ConfigError, match="CRS"):
        to_geojson(measured(crs=None))
    with pytest.raises(ConfigError, match="unknown CRS"):
        to_geojson(measured(crs="EPSG:999999"))


def test_picks_file_round_trip_and_errors(tmp_path) -> None:
    picks = PicksFile(
        (PointPicks("A", (ImagePick("0001.png", 10.5, 20.25, 0.5), ImagePick("0002.png", 11.0, 21.0, 0.7))),),
        (),
    )
    write_picks(tmp_path / "p.json", picks)
    assert read_picks(tmp_path / "p.json") == picks
    with pytest.raises(FormatError, match="points"):
        parse_picks({"pts": []})
    with pytest.raises(FormatError, match="u must be a number"):
        parse_picks({"points": [{"id": "A", "picks": [{"image": "a", "u": "x", "v": 1}]}]})
    with pytest.raises(FormatError, match="appears twice"):
        parse_picks({"points": [{"id": "A", "picks": []}, {"id": "A", "picks": []}]})
    with pytest.raises(FormatError, match="not among the points"):
        parse_picks({"points": [{"id": "A", "picks": []}], "distances": [["A", "B"]]})
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(FormatError, match="not valid JSON"):
        read_picks(tmp_path / "bad.json")


def test_measure_picks_against_a_camera_model(tmp_path) -> None:
    cam = distorted_camera()
    views = ring_views(4)
    cameras = Cameras({1: cam}, {v.image_id: v for v in views})
    payload = {
        "sigma_px": 0.5,
        "points": [
            {
                "id": f"P{i}",
                "picks": [{"image": p.image, "u": p.pixel[0], "v": p.pixel[1]} for p in exact_picks(cam, views, t)],
            }
            for i, t in enumerate(TRUTH)
        ]
        + [{"id": "lonely", "picks": [{"image": "0001.png", "u": 5.0, "v": 5.0}]}],
        "distances": [["P0", "P2"]],
    }
    georef = Georeference(UTM_ORIGIN, "m", "EPSG:32632")
    with pytest.raises(DataError, match="lonely"):
        measure_picks(parse_picks(payload), cameras, georef)
    errors = []
    m = measure_picks(parse_picks(payload), cameras, georef, on_error=lambda pid, err: errors.append(pid))
    assert errors == ["lonely"]
    np.testing.assert_allclose(np.stack([p.world for p in m.points]) - UTM_ORIGIN, TRUTH, atol=1e-9)
    assert m.distances[0].length == pytest.approx(np.linalg.norm(TRUTH[2] - TRUTH[0]), abs=1e-9)
    payload["points"][0]["picks"][0]["image"] = "missing.png"
    with pytest.raises(DataError, match="missing.png"):
        measure_picks(parse_picks(payload), cameras, georef)


def test_read_georeference_from_sidecar(tmp_path) -> None:
    from core.io.origin import write_origin

    ply = tmp_path / "merged.ply"
    assert read_georeference(ply).crs is None and np.all(read_georeference(ply).origin == 0)
    write_origin(ply, UTM_ORIGIN + 0.123456789, crs="EPSG:32632")
    g = read_georeference(ply)
    assert g.crs == "EPSG:32632" and g.unit == "m"
    assert np.all(g.origin == UTM_ORIGIN + 0.123456789)
    (tmp_path / "merged.origin.json").write_text(json.dumps({"origin": [0, 0, 0], "crs": 5}))
    with pytest.raises(FormatError, match="crs"):
        read_georeference(ply)
