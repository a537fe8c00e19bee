"""SPZ export (fusion.spz_format, fusion.export.export_spz, ``hybridsplat export --out X.spz``).

Truth is the Gaussian set we wrote: every decoded value must lie within the bound its quantisation allows, derived
from the bit counts below (the same derivations as the module docstring), and a deliberately broken quantiser must
exceed those bounds. The header is read from the raw gzip bytes, not by our reader. When node and
``@playcanvas/splat-transform`` are installed (``scripts/check_splat_transform.sh`` installs them once; nothing is
downloaded here), Niantic's reference (its WebAssembly build, ``@adobe/spz``, a dependency of splat-transform)
packs the same float32 values a 3DGS PLY holds into bytes identical to ours, and both it and splat-transform read
our file back with our values.
"""

from __future__ import annotations

import gzip
import json
import math
import struct
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest
from npm_readers import splat_transform

from core.errors import DataError, FormatError, InputFileError
from core.gaussians import GaussianSet
from core.io.gaussian_ply import write_gaussian_ply
from core.io.origin import read_origin, sidecar_path
from fusion import spz_format
from fusion.export import ExportOptions, export_gaussians, export_spz
from fusion.spz_format import encode_spz, fixed_point_fits, read_spz, write_spz

GEO_ORIGIN = np.array([500000.0, 4000000.0, 100.0])

# -- bounds, derived from the bit counts ---------------------------------------------------------------------------
FRACTIONAL_BITS = 12
POSITION_BOUND = 2.0 ** -(FRACTIONAL_BITS + 1)  # half a fixed-point step, metres
ALPHA_BOUND = 0.5 / 255  # 8 bits over [0, 1]
COLOR_BOUND = 0.5 / (0.15 * 255)  # f_dc step is 1 / (0.15 · 255)
LOG_SCALE_BOUND = 0.5 / 16  # log σ step 1/16
SH1_BOUND = (2 ** (8 - 5) + 1) / 256  # bucket of 8 codes of 1/128, after rounding to 1/128 first
SH_REST_BOUND = (2 ** (8 - 4) + 1) / 256  # bucket of 16 codes
V2_XYZ_BOUND = 0.5 / 127.5  # x, y, z codes of 1/127.5
V3_STORED_BOUND = math.sqrt(0.5) / 511 / 2  # 9-bit magnitudes over [0, 1/√2]
FLOAT32_SLACK = 1e-6  # the reference quantises float32 values (unit quaternions, products): ~1e-7 noise


def _largest_bound(e: float) -> float:
    """Error of the reconstructed largest component m = √(1 − Σa²) when three components err by ≤ e: |Σa² − Σa'²|
    ≤ √3e · (2‖a‖ + √3e) ≤ 3e(1 + e) as ‖a‖ ≤ √3/2, and m ≥ 1/2, m' ≥ √(1/4 − 3e(1+e))."""
    d = 3 * e * (1 + e)
    return d / (0.5 + math.sqrt(0.25 - d))


def _v2_w_bound(w: np.ndarray) -> np.ndarray:
    """Version 2 rebuilds w ≥ 0 from x, y, z (each ≤ e off): |w'² − w²| ≤ D = √3e(2√(1 − w²) + √3e), so
    |w' − w| ≤ min(√D, D / w) — up to 0.117 as w → 0, the price of the 3-byte rotation."""
    e = V2_XYZ_BOUND
    d = math.sqrt(3) * e * (2 * np.sqrt(np.maximum(0.0, 1 - w**2)) + math.sqrt(3) * e)
    return np.minimum(np.sqrt(d), d / np.maximum(w, 1e-12))


def _random_set(n: int = 2000, degree: int = 3, origin=(0.0, 0.0, 0.0), seed: int = 0, extent: float = 50.0):
    """Values inside SPZ's ranges (log σ in [−10, 5.9], |f_dc| < 3.3, |SH| ≤ 1) so nothing is clipped."""
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1
    return GaussianSet(
        means=rng.uniform(-extent, extent, (n, 3)),
        log_scales=rng.uniform(-9.5, 5.5, (n, 3)),
        quats=rng.normal(size=(n, 4)),
        logit_opacities=rng.uniform(-6, 8, n),
        sh_dc=rng.uniform(-3.2, 3.2, (n, 3)),
        sh_rest=np.clip(rng.normal(size=(n, k, 3)) * 0.4, -1, 1),
        origin=np.asarray(origin, float),
    )


def _raw_header(path: Path) -> tuple[tuple, bytes]:
    payload = gzip.decompress(path.read_bytes())
    return struct.unpack_from("<IIIBBBB", payload), payload


def _aligned(truth_wxyz: np.ndarray, decoded_wxyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit truth and decoded quaternions with the same sign (q and −q are one rotation)."""
    q = truth_wxyz.astype(np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    sign = np.where((q * decoded_wxyz).sum(axis=1) < 0, -1.0, 1.0)[:, None]
    return q, decoded_wxyz * sign


def _errors(gs: GaussianSet, d: spz_format.SpzData) -> dict[str, np.ndarray]:
    alpha = 1 / (1 + np.exp(-gs.logit_opacities.astype(np.float64)))
    return {
        "position": np.abs(d.positions - gs.means),
        "alpha": np.abs(d.alphas - alpha),
        "color": np.abs(d.sh_dc - gs.sh_dc),
        "log_scale": np.abs(d.log_scales - gs.log_scales),
        "sh1": np.abs(d.sh_rest[:, :3] - gs.sh_rest[:, :3]),  # type: ignore[index]
        "sh_rest": np.abs(d.sh_rest[:, 3:] - gs.sh_rest[:, 3:]),  # type: ignore[index]
    }


BOUNDS = {
    "position": POSITION_BOUND,
    "alpha": ALPHA_BOUND + FLOAT32_SLACK,
    "color": COLOR_BOUND + FLOAT32_SLACK,
    "log_scale": LOG_SCALE_BOUND + FLOAT32_SLACK,
    "sh1": SH1_BOUND + FLOAT32_SLACK,
    "sh_rest": SH_REST_BOUND + FLOAT32_SLACK,
}


# -- header, count, degree -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_header_count_degree_and_plane_sizes_from_raw_bytes(tmp_path, degree):
    gs = _random_set(n=300, degree=degree)
    header = write_spz(tmp_path / "g.spz", gs)
    raw = (tmp_path / "g.spz").read_bytes()
    assert raw[:2] == b"\x1f\x8b"  # a gzip stream (versions 1-3)
    (magic, version, n, sh_degree, bits, flags, reserved), payload = _raw_header(tmp_path / "g.spz")
    assert magic == 0x5053474E and payload[:4] == b"NGSP"
    assert (version, n, sh_degree, bits, flags, reserved) == (2, 300, degree, FRACTIONAL_BITS, 0, 0)
    k = (degree + 1) ** 2 - 1
    assert len(payload) == 16 + 300 * (9 + 1 + 3 + 3 + 3 + 3 * k)  # v2: 3 rotation bytes per splat
    assert header == spz_format.SpzHeader(2, 300, degree, FRACTIONAL_BITS, 0)
    d = read_spz(tmp_path / "g.spz")
    assert len(d) == 300 and d.header == header and d.sh_rest.shape == (300, k, 3)


def test_version_3_header_and_rotation_plane(tmp_path):
    gs = _random_set(n=100, degree=1)
    write_spz(tmp_path / "g3.spz", gs, version=3)
    (_, version, n, degree, *_), payload = _raw_header(tmp_path / "g3.spz")
    assert (version, n, degree) == (3, 100, 1)
    assert len(payload) == 16 + 100 * (9 + 1 + 3 + 3 + 4 + 9)  # v3: 4 rotation bytes
    with pytest.raises(FormatError, match="version 4"):
        write_spz(tmp_path / "g4.spz", gs, version=4)


def test_output_is_deterministic(tmp_path):
    gs = _random_set(n=500)
    write_spz(tmp_path / "a.spz", gs)
    write_spz(tmp_path / "b.spz", gs)
    assert (tmp_path / "a.spz").read_bytes() == (tmp_path / "b.spz").read_bytes()


# -- precision -----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("version", [2, 3])
def test_round_trip_within_quantisation_bounds(tmp_path, version):
    gs = _random_set(n=10000)
    write_spz(tmp_path / "g.spz", gs, version=version)
    d = read_spz(tmp_path / "g.spz")
    for key, err in _errors(gs, d).items():
        assert err.max() <= BOUNDS[key], (key, err.max(), BOUNDS[key])
        assert err.max() > 0.5 * BOUNDS[key], (key, err.max())  # the bound is tight, not generous
    q, dq = _aligned(gs.quats, d.quats)
    if version == 2:
        q = q * np.where(q[:, :1] < 0, -1.0, 1.0)  # the writer stores the sign with w ≥ 0
        assert (d.quats[:, 0] >= 0).all()
        xyz_err = np.abs(d.quats[:, 1:] - q[:, 1:])
        assert xyz_err.max() <= V2_XYZ_BOUND + FLOAT32_SLACK
        w_err = np.abs(d.quats[:, 0] - q[:, 0])
        assert (w_err <= _v2_w_bound(q[:, 0]) + FLOAT32_SLACK).all()
    else:
        largest = np.argmax(np.abs(q), axis=1)
        stored = np.ones_like(q, bool)
        stored[np.arange(len(q)), largest] = False
        err = np.abs(dq - q)
        assert err[stored].max() <= V3_STORED_BOUND + FLOAT32_SLACK
        assert err[~stored].max() <= _largest_bound(V3_STORED_BOUND) + FLOAT32_SLACK


def test_a_truncating_quantiser_exceeds_the_bounds(tmp_path, monkeypatch):
    """Negative control: rounding down instead of to the nearest code (as some converters do) doubles the error,
    and the bounds above catch it."""
    gs = _random_set(n=10000)
    monkeypatch.setattr(spz_format, "_round_half_away", lambda x: np.floor(np.asarray(x, np.float64)))
    write_spz(tmp_path / "broken.spz", gs)
    monkeypatch.undo()
    errors = _errors(gs, read_spz(tmp_path / "broken.spz"))
    for key in ("position", "alpha", "color", "log_scale"):
        assert errors[key].max() > BOUNDS[key], key


def test_splats_keep_their_order_and_world_coordinates_in_the_sidecar(tmp_path):
    gs = _random_set(n=3000, origin=GEO_ORIGIN)
    report = export_spz(tmp_path / "geo.spz", gs, ExportOptions(min_opacity=0))
    assert report.format == "spz" and report.num_written == 3000 and report.sh_degree == 3
    side = json.loads(sidecar_path(tmp_path / "geo.spz").read_text())
    assert side["origin"] == GEO_ORIGIN.tolist() and side["units"] == "m"
    d = read_spz(tmp_path / "geo.spz")
    np.testing.assert_array_equal(d.origin, GEO_ORIGIN)
    world = d.positions + d.origin
    assert np.abs(world - gs.world_means).max() <= POSITION_BOUND  # float64 world: the sub-mm step survives
    back = d.to_gaussians()
    np.testing.assert_array_equal(back.origin, GEO_ORIGIN)
    assert np.isfinite(back.logit_opacities).all()
    # re-export without an origin removes a stale sidecar
    export_spz(tmp_path / "geo.spz", _random_set(n=10), ExportOptions(min_opacity=0))
    assert not sidecar_path(tmp_path / "geo.spz").exists()


def test_export_dispatches_spz_and_filters_first(tmp_path):
    gs = _random_set(n=400)
    opts = ExportOptions(min_opacity=0.5, sh_degree=1)
    report = export_gaussians(tmp_path / "F.SPZ", gs, opts)
    keep = gs.opacities >= np.float32(0.5)
    assert report.format == "spz" and report.num_written == int(keep.sum()) and report.dropped_opacity > 0
    d = read_spz(tmp_path / "F.SPZ")
    assert d.header.sh_degree == 1 and len(d) == int(keep.sum())
    assert np.abs(d.positions - gs.means[keep]).max() <= POSITION_BOUND


# -- fixed-point range: never wrapped ------------------------------------------------------------------------------
def test_large_local_extent_gets_fewer_fractional_bits_with_a_warning_never_wraps(tmp_path):
    gs = _random_set(n=200, extent=1.0)
    gs.means[0] = [3000.0, -2500.0, 0.1]  # beyond ±2048 m, the range of 12 fractional bits
    with pytest.warns(UserWarning, match=r"11 fractional bits.*step 0\.488 mm"):
        header = write_spz(tmp_path / "wide.spz", gs)
    assert header.fractional_bits == 11
    d = read_spz(tmp_path / "wide.spz")
    assert np.abs(d.positions - gs.means).max() <= 2.0**-12  # half of the 2^-11 step
    with pytest.raises(FormatError, match=r"wide12\.spz.*24-bit fixed point at 12 fractional bits.*11 fractional"):
        write_spz(tmp_path / "wide12.spz", gs, fractional_bits=12)
    assert not (tmp_path / "wide12.spz").exists()
    gs.means[0] = [9.0e6, 0.0, 0.0]  # beyond what whole metres can hold
    with pytest.raises(FormatError, match=r"huge\.spz.*whole metres"):
        write_spz(tmp_path / "huge.spz", gs)
    assert not (tmp_path / "huge.spz").exists()


def test_values_outside_spz_ranges_are_clipped_with_a_count(tmp_path):
    gs = _random_set(n=50, degree=1)
    gs.log_scales[:2, 0] = 8.0  # σ ≈ 3 km: beyond 379 m
    gs.sh_rest[:3, 0, 0] = 1.5  # type: ignore[index]
    with pytest.warns(UserWarning) as record:
        write_spz(tmp_path / "clip.spz", gs)
    text = " ".join(str(w.message) for w in record)
    assert "2 of 150 log-scale" in text and "3 of 450 SH rest" in text
    d = read_spz(tmp_path / "clip.spz")
    assert np.allclose(d.log_scales[:2, 0], 255 / 16 - 10)


# -- bad input -----------------------------------------------------------------------------------------------------
def test_empty_set_is_refused_and_writes_nothing(tmp_path):
    empty = _random_set(n=0)
    with pytest.raises(DataError, match=r"e\.spz.*no Gaussians"):
        write_spz(tmp_path / "e.spz", empty)
    with pytest.raises(DataError, match="nothing to export"):
        export_spz(tmp_path / "e.spz", _random_set(n=5), ExportOptions(min_opacity=0.999999))
    assert not list(tmp_path.iterdir())


def test_nan_input_is_refused_with_the_file_named(tmp_path):
    gs = _random_set(n=20, origin=GEO_ORIGIN)
    gs.means[7, 1] = np.nan
    with pytest.raises(DataError, match=r"n\.spz.*1 Gaussians have NaN or infinite means \(first: 7\)"):
        export_spz(tmp_path / "n.spz", gs, ExportOptions(min_opacity=0))
    gs = _random_set(n=20)
    gs.sh_rest[3, 0, 0] = np.inf  # type: ignore[index]
    with pytest.raises(DataError, match="sh_rest"):
        encode_spz(gs)
    assert not list(tmp_path.iterdir())


def test_reader_refuses_what_it_cannot_read(tmp_path):
    (tmp_path / "text.spz").write_text("hello")
    with pytest.raises(FormatError, match="not an SPZ file"):
        read_spz(tmp_path / "text.spz")
    (tmp_path / "v4.spz").write_bytes(struct.pack("<II", 0x5053474E, 4) + bytes(24))
    with pytest.raises(FormatError, match="version 4"):
        read_spz(tmp_path / "v4.spz")
    write_spz(tmp_path / "ok.spz", _random_set(n=100))
    payload = gzip.decompress((tmp_path / "ok.spz").read_bytes())
    (tmp_path / "short.spz").write_bytes(gzip.compress(payload[:-10]))
    with pytest.raises(FormatError, match="expected for 100 splats"):
        read_spz(tmp_path / "short.spz")
    (tmp_path / "cut.spz").write_bytes((tmp_path / "ok.spz").read_bytes()[:200])
    with pytest.raises(InputFileError, match=r"cut\.spz.*truncated"):
        read_spz(tmp_path / "cut.spz")


# -- the command line ----------------------------------------------------------------------------------------------
def _cli(argv: list) -> int:
    from hybridsplat.cli import main

    try:
        main([str(a) for a in argv])
    except SystemExit as ex:
        return int(ex.code or 0)
    return 0


def test_cli_export_writes_spz_and_its_sidecar(tmp_path):
    gs = _random_set(n=1500, origin=GEO_ORIGIN)
    write_gaussian_ply(tmp_path / "in.ply", gs)  # float32 local means + in.origin.json
    assert _cli(["export", tmp_path / "in.ply", "--out", tmp_path / "X.spz", "--min-opacity", "0"]) == 0
    np.testing.assert_array_equal(read_origin(tmp_path / "X.spz"), GEO_ORIGIN)
    d = read_spz(tmp_path / "X.spz")
    assert d.header.version == 2 and len(d) == 1500 and d.header.sh_degree == 3
    bits = d.header.fractional_bits  # the finest step the local extent allows, not the reference's fixed 12
    local = gs.means.astype(np.float32).astype(np.float64)
    assert bits > 12 and fixed_point_fits(local, bits) and (bits == 23 or not fixed_point_fits(local, bits + 1))
    world = d.positions + d.origin
    truth = gs.means.astype(np.float32).astype(np.float64) + GEO_ORIGIN  # what the 3DGS PLY holds
    assert np.abs(world - truth).max() <= POSITION_BOUND
    assert _cli(["export", tmp_path / "in.ply", "--out", tmp_path / "Y.spz", "--spz-version", "3"]) == 0
    assert read_spz(tmp_path / "Y.spz").header.version == 3
    assert _cli(["export", tmp_path / "in.ply", "--out", tmp_path / "Z.spz", "--spz-version", "4"]) != 0
    assert not (tmp_path / "Z.spz").exists()


# -- independent readers and the reference writer (optional: node + splat-transform) -----------------------------
_REFERENCE_SCRIPT = r"""
import { readFileSync, writeFileSync } from 'node:fs';
const [spzJs, jobFile] = process.argv.slice(2);
const { default: createSpzModule } = await import('file://' + spzJs);
const spz = await createSpzModule({ print: () => {}, printErr: () => {} });
const job = JSON.parse(readFileSync(jobFile, 'utf8'));
const f32 = (name) => {
  const b = readFileSync(`${job.dir}/${name}.f32`);
  return new Float32Array(b.buffer, b.byteOffset, b.length / 4);
};
const cloud = { numPoints: job.n, shDegree: job.degree, antialiased: false, extensions: [],
  positions: f32('positions'), scales: f32('scales'), rotations: f32('rotations'), alphas: f32('alphas'),
  colors: f32('colors'), sh: f32('sh') };
for (const v of job.versions) {
  const opts = { version: v, from: spz.CoordinateSystem.UNSPECIFIED, sh1Bits: 5, shRestBits: 4 };
  writeFileSync(`${job.dir}/reference_v${v}.spz`, spz.saveSpzToBuffer(cloud, opts));
}
for (const file of job.load) {
  const g = await spz.loadSpzFromBuffer(new Uint8Array(readFileSync(file)), { to: spz.CoordinateSystem.UNSPECIFIED });
  for (const k of ['positions', 'scales', 'rotations', 'alphas', 'colors', 'sh']) {
    writeFileSync(`${file}.${k}.f32`, Buffer.from(new Float32Array(g[k]).buffer));
  }
}
"""


def _splat_transform() -> str:
    return splat_transform()


def _reference_module(st: str) -> Path:
    """Niantic's reference as WebAssembly (``@adobe/spz``), installed with splat-transform."""
    package = Path(st).resolve().parents[1]  # <node_modules>/@playcanvas/splat-transform
    for root in (package / "node_modules", package.parents[1]):
        candidate = root / "@adobe" / "spz" / "dist" / "spz.js"
        if candidate.is_file():
            return candidate
    pytest.skip("@adobe/spz (the SPZ reference, a dependency of splat-transform) not found")


def _ply_arrays(gs: GaussianSet, folder: Path) -> None:
    """The float32 arrays a 3DGS PLY holds, in the reference's GaussianCloud layout (quaternions x, y, z, w; SH
    coefficient-major with the channel innermost, as its PLY loader reorders them)."""
    arrays = {
        "positions": gs.means,
        "scales": gs.log_scales,
        "rotations": gs.quats[:, [1, 2, 3, 0]],
        "alphas": gs.logit_opacities,
        "colors": gs.sh_dc,
        "sh": gs.sh_rest,
    }
    for name, values in arrays.items():
        np.ascontiguousarray(values, "<f4").tofile(folder / f"{name}.f32")


def test_reference_packs_a_ply_into_our_bytes_and_reads_our_file(tmp_path):
    st = _splat_transform()
    module = _reference_module(st)
    gs = _random_set(n=4000)
    gs.means = gs.means.astype(np.float32).astype(np.float64)  # as read from a 3DGS PLY
    for v in (2, 3):
        write_spz(tmp_path / f"ours_v{v}.spz", gs, version=v)
    _ply_arrays(gs, tmp_path)
    job = {
        "dir": str(tmp_path),
        "n": len(gs),
        "degree": 3,
        "versions": [2, 3],
        "load": [str(tmp_path / f"ours_v{v}.spz") for v in (2, 3)],
    }
    (tmp_path / "job.json").write_text(json.dumps(job))
    (tmp_path / "reference.mjs").write_text(_REFERENCE_SCRIPT)
    proc = subprocess.run(
        ["node", str(tmp_path / "reference.mjs"), str(module), str(tmp_path / "job.json")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    for v in (2, 3):  # no axis conversion on either side: the same bytes
        ours = gzip.decompress((tmp_path / f"ours_v{v}.spz").read_bytes())
        theirs = gzip.decompress((tmp_path / f"reference_v{v}.spz").read_bytes())
        assert len(ours) == len(theirs), (v, len(ours), len(theirs))
        differ = np.count_nonzero(np.frombuffer(ours, np.uint8) != np.frombuffer(theirs, np.uint8))
        assert differ == 0, f"version {v}: {differ} of {len(ours)} bytes differ from the reference's"
    n = len(gs)
    for v in (2, 3):  # the reference's reader and ours decode our files alike
        d = read_spz(tmp_path / f"ours_v{v}.spz")

        def loaded(key: str, width: int, v: int = v) -> np.ndarray:
            return np.fromfile(tmp_path / f"ours_v{v}.spz.{key}.f32", "<f4").astype(np.float64).reshape(n, width)

        np.testing.assert_array_equal(loaded("positions", 3), d.positions)
        np.testing.assert_array_equal(loaded("scales", 3), d.log_scales)
        np.testing.assert_allclose(loaded("rotations", 4)[:, [3, 0, 1, 2]], d.quats, atol=1e-4)  # float32 √(1 − s)
        np.testing.assert_allclose(loaded("colors", 3), d.sh_dc, atol=1e-6)
        np.testing.assert_allclose(1 / (1 + np.exp(-loaded("alphas", 1)[:, 0])), d.alphas, atol=1e-6)
        np.testing.assert_array_equal(loaded("sh", 45).reshape(n, 15, 3), d.sh_rest)


def test_splat_transform_reads_our_spz_with_our_values(tmp_path):
    st = _splat_transform()
    gs = _random_set(n=3000)
    for v in (2, 3):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            write_spz(tmp_path / f"g{v}.spz", gs, version=v)
        proc = subprocess.run(
            [st, "-w", str(tmp_path / f"g{v}.spz"), str(tmp_path / f"g{v}.csv")],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 0, proc.stdout + proc.stderr
        header = (tmp_path / f"g{v}.csv").read_text().splitlines()[0].split(",")
        table = np.loadtxt(tmp_path / f"g{v}.csv", delimiter=",", skiprows=1, ndmin=2)
        col = {name: table[:, i] for i, name in enumerate(header)}
        assert len(table) == len(gs)
        xyz = np.c_[col["x"], col["y"], col["z"]]
        assert np.abs(xyz - gs.means).max() <= POSITION_BOUND + 1e-5  # CSV holds float32 decimals
        assert (
            np.abs(np.c_[col["scale_0"], col["scale_1"], col["scale_2"]] - gs.log_scales).max() <= BOUNDS["log_scale"]
        )
        dc = np.c_[col["f_dc_0"], col["f_dc_1"], col["f_dc_2"]]
        assert np.abs(dc - gs.sh_dc).max() <= BOUNDS["color"] + 1e-5
        rest = np.stack([col[f"f_rest_{i}"] for i in range(45)], axis=1).reshape(len(gs), 3, 15).transpose(0, 2, 1)
        assert np.abs(rest[:, :3] - gs.sh_rest[:, :3]).max() <= BOUNDS["sh1"]  # type: ignore[index]
        assert np.abs(rest[:, 3:] - gs.sh_rest[:, 3:]).max() <= BOUNDS["sh_rest"]  # type: ignore[index]
        d = read_spz(tmp_path / f"g{v}.spz")
        rot = np.c_[col["rot_0"], col["rot_1"], col["rot_2"], col["rot_3"]]
        np.testing.assert_allclose(rot, d.quats, atol=1e-6)
