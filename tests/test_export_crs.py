"""The input's CRS goes with every export (issue 33): each output's origin sidecar names it, a LAS output carries it
as WKT, and an input without one gives outputs without one."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.gaussians import GaussianSet
from core.io.gaussian_ply import write_gaussian_ply
from core.io.origin import read_crs, sidecar_path, write_origin

UTM = "EPSG:32633"
OUTPUTS = ("g.ply", "g.splat", "g.spz", "g.compressed.ply", "g.las")


def _georeferenced(path, crs: str | None):
    rng = np.random.default_rng(0)
    n = 300
    origin = np.array([500_000.0, 4_000_000.0, 100.0])
    gs = GaussianSet(rng.uniform(-5, 5, (n, 3)), np.full((n, 3), -3.0), np.tile([1.0, 0, 0, 0], (n, 1)),
                     np.full(n, 2.0), rng.normal(size=(n, 3)), origin=origin)  # fmt: skip
    write_gaussian_ply(path, gs)
    write_origin(path, gs.origin, crs)
    return gs


@pytest.mark.parametrize("crs", [UTM, None])
def test_every_output_keeps_the_input_crs(tmp_path, crs):
    import laspy

    from hybridsplat.cli import main

    source = tmp_path / "in.ply"
    gs = _georeferenced(source, crs)
    out = tmp_path / "out"
    out.mkdir()
    main(["export", str(source), *(a for name in OUTPUTS for a in ("--out", str(out / name)))])
    for name in OUTPUTS:
        path = out / name
        if path.suffix == ".las":
            parsed = laspy.read(path).header.parse_crs()
            assert (parsed.to_epsg() if parsed is not None else None) == (32633 if crs else None), name
            continue
        side = json.loads(sidecar_path(path).read_text())
        assert side["origin"] == gs.origin.tolist() and side["crs"] == crs, name
        assert read_crs(path) == crs


def test_a_crs_that_is_not_a_string_is_refused(tmp_path):
    from core.errors import FormatError

    path = tmp_path / "in.ply"
    _georeferenced(path, UTM)
    sidecar_path(path).write_text(json.dumps({"origin": [0, 0, 0], "units": "m", "crs": 32633}))
    with pytest.raises(FormatError, match="crs"):
        read_crs(path)


def test_a_tileset_export_is_placed_on_the_earth_by_the_input_crs(tmp_path):
    import pyproj

    from fusion.gltf_splats import read_splat_glb
    from hybridsplat.cli import main

    source = tmp_path / "in.ply"
    gs = _georeferenced(source, UTM)
    out = tmp_path / "tiles" / "tileset.json"
    out.parent.mkdir()
    main(["export", str(source), "--out", str(out)])
    tileset = json.loads(out.read_text())
    assert tileset["asset"]["version"] == "1.1"
    transform = np.asarray(tileset["root"]["transform"], np.float64).reshape(4, 4).T  # column-major
    ecef = pyproj.Transformer.from_crs(UTM, "EPSG:4978", always_xy=True).transform(*gs.origin)
    np.testing.assert_allclose(transform[:3, 3], ecef, atol=0.5)  # the local frame sits at the origin, on the earth
    glbs = sorted(out.parent.rglob("*.glb"))
    assert glbs and sum(len(read_splat_glb(p).to_gaussians()) for p in glbs) == len(gs)


def test_tileset_export_compresses_with_spz_by_default_and_on_request_not(tmp_path):
    """``--gltf-compression``: spz (default, KHR_gaussian_splatting_compression_spz_2: what CesiumJS draws) or none
    (float32 attributes); anything else exits non-zero and writes nothing."""
    from fusion.gltf_splats import SPZ_EXTENSION, read_splat_glb
    from hybridsplat.cli import main

    def cli(*argv) -> int:
        try:
            main([str(a) for a in argv])
        except SystemExit as ex:
            return int(ex.code or 0)
        return 0

    source = tmp_path / "in.ply"
    gs = _georeferenced(source, UTM)
    for flag, expected in ((None, "spz"), ("none", "none"), ("SPZ", "spz")):
        out = tmp_path / (flag or "default") / "tileset.json"
        extra = [] if flag is None else ["--gltf-compression", flag]
        assert cli("export", source, "--out", out, *extra) == 0
        required = json.loads(out.read_text())["extensions"]["3DTILES_content_gltf"].get("extensionsRequired", [])
        assert (SPZ_EXTENSION in required) == (expected == "spz")
        prims = [read_splat_glb(p) for p in sorted(out.parent.rglob("*.glb"))]
        assert {p.compression for p in prims} == {expected} and sum(len(p) for p in prims) == len(gs)
        decoded = np.concatenate([p.positions for p in prims]).astype(np.float64)
        # SPZ: ±5 m fits 20 fractional bits, ±0.48 µm; both: float32 storage of ≤ 5 m (±0.24 µm) and this ENU
        # frame, built here from pyproj's geodetic origin, against the writer's (≤ 0.5 µm apart): 1 µm in all
        bound = (2.0**-21 if expected == "spz" else 0.0) + 1e-6
        assert np.abs(np.sort(decoded, axis=0) - np.sort(_enu(gs), axis=0)).max() < bound
    bad = tmp_path / "bad" / "tileset.json"
    assert cli("export", source, "--out", bad, "--gltf-compression", "draco") != 0
    assert not bad.exists()


def _enu(gs) -> np.ndarray:
    """Topocentric ENU offsets (metres) of the set's splats at its origin, through pyproj (exact placement)."""
    import pyproj

    to_ecef = pyproj.Transformer.from_crs(UTM, "EPSG:4978", always_xy=True)
    to_geo = pyproj.Transformer.from_crs(UTM, "EPSG:4979", always_xy=True)
    lon, lat, _h = (np.radians(v) if i < 2 else v for i, v in enumerate(to_geo.transform(*gs.origin)))
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    up = np.cross(east, north)
    world = gs.origin + gs.means
    ecef = np.c_[to_ecef.transform(*world.T)] - np.array(to_ecef.transform(*gs.origin))
    return ecef @ np.c_[east, north, up]
