"""``hybridsplat measure`` end to end on a small COLMAP model with a georeferenced sidecar (in-process)."""

from __future__ import annotations

import csv
import json

import numpy as np
from test_measure_triangulate import distorted_camera, exact_picks, ring_views

from core.cameras import Cameras
from core.io.colmap import write_model
from core.io.origin import write_origin
from hybridsplat.cli import main

ORIGIN = np.array([500000.0, 5000000.0, 300.0])
TRUTH = np.array([[0.02, -0.03, 0.05], [-0.1, 0.08, 0.0]])


def _project(tmp_path, crs="EPSG:32632"):
    cam = distorted_camera()
    views = ring_views(3)
    write_model(tmp_path / "proj" / "sparse", Cameras({1: cam}, {v.image_id: v for v in views}))
    write_origin(tmp_path / "proj" / "export" / "merged.ply", ORIGIN, crs=crs)
    points = [
        {
            "id": f"P{i}",
            "picks": [
                {"image": p.image, "u": float(p.pixel[0]), "v": float(p.pixel[1])} for p in exact_picks(cam, views, t)
            ],
        }
        for i, t in enumerate(TRUTH)
    ]
    picks = tmp_path / "picks.json"
    picks.write_text(json.dumps({"sigma_px": 0.5, "points": points, "distances": [["P0", "P1"]]}))
    return tmp_path / "proj", picks


def _run(argv) -> int:
    try:
        main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    return 0


def test_measure_cli_prints_and_writes_csv_and_geojson(tmp_path, capsys) -> None:
    project, picks = _project(tmp_path)
    assert _run(["measure", str(picks), "--project", str(project)]) == 0
    out = capsys.readouterr().out
    assert "P0" in out and "distance P0 – P1" in out and "EPSG:32632" in out
    rows = list(csv.DictReader((project / "export" / "measurements.csv").open()))
    world = np.array([[float(r[k]) for k in "xyz"] for r in rows])
    np.testing.assert_allclose(world - ORIGIN, TRUTH, atol=1e-8)
    dist = list(csv.DictReader((project / "export" / "measurements_distances.csv").open()))
    assert abs(float(dist[0]["length"]) - np.linalg.norm(TRUTH[1] - TRUTH[0])) < 1e-8
    gj = json.loads((project / "export" / "measurements.geojson").read_text())
    assert gj["features"][0]["geometry"]["coordinates"][0] > 8.9  # zone 32 near 9° E


def test_measure_cli_without_crs_and_with_a_bad_point(tmp_path, capsys) -> None:
    project, picks = _project(tmp_path, crs=None)
    payload = json.loads(picks.read_text())
    payload["points"].append({"id": "bad", "picks": payload["points"][0]["picks"][:1]})
    picks.write_text(json.dumps(payload))
    assert _run(["measure", str(picks), "--project", str(project)]) == 2
    err = capsys.readouterr().err
    assert "point 'bad'" in err and "at least 2 images" in err and str(picks) in err
    assert _run(["measure", str(picks), "--project", str(project), "--keep-going", "--out", str(tmp_path / "o")]) == 1
    captured = capsys.readouterr()
    assert "point 'bad'" in captured.err and "GeoJSON not written" in captured.out
    assert (tmp_path / "o" / "measurements.csv").is_file() and not (tmp_path / "o" / "measurements.geojson").exists()
