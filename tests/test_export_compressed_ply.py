"""PlayCanvas compressed PLY export (fusion.compressed_ply_format, fusion.export, ``--out X.compressed.ply``).

Truth is the Gaussian set we wrote: each decoded value must lie within half a quantisation step of its chunk's range
(bounds derived from the bit counts and the chunk bounds stored in the file, read with plyfile alone), and a
deliberately broken (truncating) quantiser must exceed them. The header is checked as text against what the
PlayCanvas engine's parser demands. When node and ``@playcanvas/splat-transform`` are installed
(``scripts/check_splat_transform.sh``; nothing is downloaded here), splat-transform reads our file with our values.
"""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import plyfile
import pytest
from npm_readers import splat_transform

from core.errors import DataError, FormatError
from core.gaussians import SH_C0, GaussianSet
from core.io.gaussian_ply import write_gaussian_ply
from core.io.origin import read_origin, sidecar_path
from fusion import compressed_ply_format as cpf
from fusion.compressed_ply_format import CHUNK_SIZE, morton_order, read_compressed_ply, write_compressed_ply
from fusion.export import ExportOptions, export_compressed_ply, export_gaussians

GEO_ORIGIN = np.array([500000.0, 4000000.0, 100.0])
BITS_11_10_11 = np.array([11, 10, 11])
ALPHA_BOUND = 0.5 / 255
ROT_STORED_BOUND = math.sqrt(2) / 2 / 1023  # half of a 10-bit step over [−1/√2, 1/√2]
SH_CENTRE_BOUND = 1 / 64  # half a bucket of 8/256 (splat-transform decodes bucket centres)
SH_BOUND = 1 / 32  # a whole bucket: the end buckets, and the engine's decoding b · 8/255 − 4
SLACK = 1e-9  # float64 decoding of float32 bounds


def _largest_bound(e: float) -> float:
    """The reconstructed largest component when the three stored ones err by ≤ e (see test_export_spz)."""
    d = 3 * e * (1 + e)
    return d / (0.5 + math.sqrt(0.25 - d))


def _random_set(n: int = 2000, degree: int = 3, origin=(0.0, 0.0, 0.0), seed: int = 0, extent: float = 20.0):
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1
    return GaussianSet(
        means=rng.uniform(-extent, extent, (n, 3)),
        log_scales=rng.uniform(-9, 2, (n, 3)),
        quats=rng.normal(size=(n, 4)),
        logit_opacities=rng.uniform(-6, 8, n),
        sh_dc=rng.uniform(-2, 2, (n, 3)),
        sh_rest=np.clip(rng.normal(size=(n, k, 3)), -3.99, 3.99),
        origin=np.asarray(origin, float),
    )


def _chunk_table(path: Path) -> np.ndarray:
    """(M, 18) float32 chunk bounds read with plyfile alone."""
    el = plyfile.PlyData.read(str(path))["chunk"]
    return np.stack([np.asarray(el.data[p.name]) for p in el.properties], axis=1)


def _step_bounds(lo: np.ndarray, hi: np.ndarray, bits: np.ndarray) -> np.ndarray:
    """Half a quantisation step of each splat's chunk range: (hi − lo) / (2 (2^bits − 1))."""
    return (hi.astype(np.float64) - lo.astype(np.float64)) / (2 * (2.0**bits - 1))


def _errors_and_bounds(gs: GaussianSet, path: Path, order: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per-value errors of our reader against the (reordered) truth, and their bounds from the file's chunks."""
    g = gs.subset(order)
    d = read_compressed_ply(path)
    c = _chunk_table(path)[np.arange(len(g)) // CHUNK_SIZE]
    colors = 0.5 + SH_C0 * g.sh_dc.astype(np.float64)
    alpha = 1 / (1 + np.exp(-g.logit_opacities.astype(np.float64)))
    return {
        "position": (np.abs(d.positions - g.means), _step_bounds(c[:, 0:3], c[:, 3:6], BITS_11_10_11) + SLACK),
        "log_scale": (np.abs(d.log_scales - g.log_scales), _step_bounds(c[:, 6:9], c[:, 9:12], BITS_11_10_11) + SLACK),
        "color": (np.abs((0.5 + SH_C0 * d.sh_dc) - colors), _step_bounds(c[:, 12:15], c[:, 15:18], 8) + SLACK),
        "alpha": (np.abs(d.alphas - alpha), np.full(len(g), ALPHA_BOUND + SLACK)),
    }


# -- header --------------------------------------------------------------------------------------------------------
def test_header_is_what_the_playcanvas_parser_demands(tmp_path):
    gs = _random_set(n=600, degree=2)
    layout = write_compressed_ply(tmp_path / "g.compressed.ply", gs)
    raw = (tmp_path / "g.compressed.ply").read_bytes()
    header = raw[: raw.index(b"end_header\n") + len(b"end_header\n")].decode("ascii").splitlines()
    assert header[:2] == ["ply", "format binary_little_endian 1.0"]
    body = [line for line in header if not line.startswith("comment")]
    expected = (
        ["ply", "format binary_little_endian 1.0", "element chunk 3"]
        + [f"property float {p}" for p in cpf.CHUNK_PROPERTIES]
        + ["element vertex 600"]
        + [f"property uint {p}" for p in ("packed_position", "packed_rotation", "packed_scale", "packed_color")]
        + ["element sh 600"]
        + [f"property uchar f_rest_{i}" for i in range(24)]
        + ["end_header"]
    )
    assert body == expected
    assert len(raw) == len("\n".join(header)) + 1 + 3 * 18 * 4 + 600 * 16 + 600 * 24
    assert (layout.num_splats, layout.num_chunks, layout.sh_degree) == (600, 3, 2)
    assert sorted(layout.order.tolist()) == list(range(600))


@pytest.mark.parametrize(("degree", "columns"), [(0, None), (1, 9), (3, 45)])
def test_count_and_sh_degree(tmp_path, degree, columns):
    gs = _random_set(n=257, degree=degree)
    write_compressed_ply(tmp_path / "g.compressed.ply", gs)
    ply = plyfile.PlyData.read(str(tmp_path / "g.compressed.ply"))
    names = [e.name for e in ply.elements]
    assert names == (["chunk", "vertex"] if columns is None else ["chunk", "vertex", "sh"])
    assert len(ply["chunk"].data) == 2 and len(ply["vertex"].data) == 257  # ceil(257 / 256)
    if columns:
        assert len(ply["sh"].properties) == columns
    d = read_compressed_ply(tmp_path / "g.compressed.ply")
    assert len(d) == 257 and d.sh_degree == degree


# -- precision -----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("sort", [True, False])
def test_round_trip_within_chunk_quantisation_bounds(tmp_path, sort):
    gs = _random_set(n=10000)
    layout = write_compressed_ply(tmp_path / "g.compressed.ply", gs, sort=sort)
    for key, (err, bound) in _errors_and_bounds(gs, tmp_path / "g.compressed.ply", layout.order).items():
        bound = bound.reshape(len(err), -1)
        assert (err.reshape(len(err), -1) <= bound).all(), (key, float((err.reshape(len(err), -1) / bound).max()))
        assert (err.reshape(len(err), -1) / bound).max() > 0.5, key  # tight: some value sits near half a step
    # chunk bounds contain every splat (float32, rounded outwards)
    c = _chunk_table(tmp_path / "g.compressed.ply")[np.arange(len(gs)) // CHUNK_SIZE]
    g = gs.subset(layout.order)
    assert (g.means >= c[:, 0:3]).all() and (g.means <= c[:, 3:6]).all()


def test_morton_order_makes_chunks_compact(tmp_path):
    gs = _random_set(n=10000, extent=20.0)
    sorted_layout = write_compressed_ply(tmp_path / "s.compressed.ply", gs)
    write_compressed_ply(tmp_path / "u.compressed.ply", gs, sort=False)
    volume = {}
    for name in ("s", "u"):
        c = _chunk_table(tmp_path / f"{name}.compressed.ply").astype(np.float64)
        volume[name] = float(np.median((c[:, 3:6] - c[:, 0:3]).prod(axis=1)))
    assert volume["u"] > 0.9 * 40.0**3  # input order: every chunk spans the scene (a 40 m cube)
    assert volume["s"] < volume["u"] / 8  # Morton order: 40 chunks, boxes ~1/16 of the scene (measured)
    np.testing.assert_array_equal(sorted_layout.order, morton_order(gs.means))


def test_rotations_within_the_smallest_three_bounds(tmp_path):
    gs = _random_set(n=10000)
    layout = write_compressed_ply(tmp_path / "g.compressed.ply", gs)
    d = read_compressed_ply(tmp_path / "g.compressed.ply")
    q = gs.subset(layout.order).unit_quats.astype(np.float64)
    largest = np.argmax(np.abs(q), axis=1)
    rows = np.arange(len(q))
    q = q * np.where(q[rows, largest] < 0, -1.0, 1.0)[:, None]  # the file makes the largest positive
    stored = np.ones_like(q, bool)
    stored[rows, largest] = False
    err = np.abs(d.quats - q)
    assert err[stored].max() <= ROT_STORED_BOUND + 1e-7  # float32 unit quaternions
    assert err[~stored].max() <= _largest_bound(ROT_STORED_BOUND) + 1e-7
    assert err[stored].max() > 0.9 * ROT_STORED_BOUND
    idx = np.asarray(plyfile.PlyData.read(str(tmp_path / "g.compressed.ply"))["vertex"].data["packed_rotation"]) >> 30
    np.testing.assert_array_equal(idx, largest)  # bits 31-30: index of the largest, in file order w, x, y, z


def test_sh_within_bucket_bounds_for_both_playcanvas_decodings(tmp_path):
    gs = _random_set(n=5000, degree=3)
    layout = write_compressed_ply(tmp_path / "g.compressed.ply", gs)
    truth = gs.subset(layout.order).sh_rest.astype(np.float64)  # type: ignore[union-attr]
    d = read_compressed_ply(tmp_path / "g.compressed.ply")
    err = np.abs(d.sh_rest - truth)
    interior = np.abs(truth) < 4 - 1 / 32
    assert err[interior].max() <= SH_CENTRE_BOUND + SLACK and err.max() <= SH_BOUND + SLACK
    sh = plyfile.PlyData.read(str(tmp_path / "g.compressed.ply"))["sh"].data
    b = np.stack([np.asarray(sh[f"f_rest_{i}"]) for i in range(45)], axis=1).astype(np.float64)
    engine = (b * (8 / 255) - 4).reshape(len(b), 3, 15).transpose(0, 2, 1)  # gsplat-compressed-data.js
    assert np.abs(engine - truth).max() <= SH_BOUND + SLACK


def test_a_truncating_quantiser_exceeds_the_bounds(tmp_path, monkeypatch):
    """Negative control: ``floor(t · (2^b − 1))`` instead of rounding errs by up to a whole step."""
    gs = _random_set(n=10000)
    top = {b: (1 << b) - 1 for b in (8, 10, 11)}
    monkeypatch.setattr(cpf, "_unorm", lambda t, bits: np.clip(np.floor(t * top[bits]), 0, top[bits]).astype(np.uint32))
    layout = write_compressed_ply(tmp_path / "broken.compressed.ply", gs)
    monkeypatch.undo()
    for key, (err, bound) in _errors_and_bounds(gs, tmp_path / "broken.compressed.ply", layout.order).items():
        assert (err.reshape(len(err), -1) > bound.reshape(len(err), -1)).any(), key


def test_degenerate_chunks_and_clipped_scales(tmp_path):
    gs = _random_set(n=300, degree=1)
    gs.means[:] = [1.25, -2.5, 3.0]  # one point, no extent: every chunk box is a point
    gs.log_scales[:5, 1] = 25.0  # beyond the ±20 PlayCanvas clamps to
    with pytest.warns(UserWarning, match="5 of 900 log-scale"):
        write_compressed_ply(tmp_path / "d.compressed.ply", gs)
    d = read_compressed_ply(tmp_path / "d.compressed.ply")
    np.testing.assert_array_equal(d.positions, np.tile([1.25, -2.5, 3.0], (300, 1)))
    assert (d.log_scales[:, 1] <= 20.0 + 1e-6).all() and np.isclose(d.log_scales[:, 1].max(), 20.0)


# -- sidecar, dispatch ---------------------------------------------------------------------------------------------
def test_georeferenced_export_keeps_the_origin_in_the_sidecar(tmp_path):
    gs = _random_set(n=3000, origin=GEO_ORIGIN)
    out = tmp_path / "geo.compressed.ply"
    report = export_compressed_ply(out, gs, ExportOptions(min_opacity=0))
    assert report.format == "compressed-ply" and report.num_written == 3000 and report.origin == tuple(GEO_ORIGIN)
    assert sidecar_path(out) == tmp_path / "geo.compressed.origin.json"
    side = json.loads(sidecar_path(out).read_text())
    assert side["origin"] == GEO_ORIGIN.tolist() and side["units"] == "m"
    d = read_compressed_ply(out)
    np.testing.assert_array_equal(d.origin, GEO_ORIGIN)
    c = _chunk_table(out)
    assert np.abs(c[:, :6]).max() <= 20.0 + 1e-5  # local coordinates in the payload, not UTM
    back = d.to_gaussians()
    g = gs.subset(write_compressed_ply(tmp_path / "again.compressed.ply", gs).order)
    chunk = c[np.arange(len(g)) // CHUNK_SIZE]
    bound = _step_bounds(chunk[:, 0:3], chunk[:, 3:6], BITS_11_10_11) + 1e-9
    assert (np.abs(back.world_means - g.world_means) <= bound).all()  # float64 world = origin + decoded local
    export_compressed_ply(out, _random_set(n=10), ExportOptions(min_opacity=0))
    assert not sidecar_path(out).exists()  # a stale sidecar goes when the origin is zero


def test_dispatch_compressed_before_plain_ply(tmp_path):
    gs = _random_set(n=100)
    assert export_gaussians(tmp_path / "A.Compressed.PLY", gs).format == "compressed-ply"
    assert export_gaussians(tmp_path / "a.ply", gs).format == "3dgs-ply"
    assert export_gaussians(tmp_path / "compressed.ply", gs).format == "3dgs-ply"  # the name, not a suffix
    with pytest.raises(FormatError, match=r"\.compressed\.ply, \.splat, \.spz"):
        export_gaussians(tmp_path / "a.obj", gs)


# -- bad input -----------------------------------------------------------------------------------------------------
def test_empty_set_is_refused_and_writes_nothing(tmp_path):
    with pytest.raises(DataError, match=r"e\.compressed\.ply.*no Gaussians"):
        write_compressed_ply(tmp_path / "e.compressed.ply", _random_set(n=0))
    with pytest.raises(DataError, match="nothing to export"):
        export_compressed_ply(tmp_path / "e.compressed.ply", _random_set(n=5), ExportOptions(min_opacity=0.999999))
    assert not list(tmp_path.iterdir())


def test_nan_input_is_refused_with_the_file_named(tmp_path):
    gs = _random_set(n=20, origin=GEO_ORIGIN)
    gs.log_scales[4, 2] = np.nan
    with pytest.raises(DataError, match=r"n\.compressed\.ply.*1 Gaussians have NaN or infinite log_scales"):
        export_compressed_ply(tmp_path / "n.compressed.ply", gs, ExportOptions(min_opacity=0))
    assert not list(tmp_path.iterdir())


def test_reader_refuses_a_plain_3dgs_ply(tmp_path):
    write_gaussian_ply(tmp_path / "plain.ply", _random_set(n=10))
    with pytest.raises(FormatError, match="not a compressed PLY"):
        read_compressed_ply(tmp_path / "plain.ply")


# -- the command line ----------------------------------------------------------------------------------------------
def _cli(argv: list) -> int:
    from hybridsplat.cli import main

    try:
        main([str(a) for a in argv])
    except SystemExit as ex:
        return int(ex.code or 0)
    return 0


def test_cli_export_writes_compressed_ply_even_with_points(tmp_path):
    gs = _random_set(n=1500, origin=GEO_ORIGIN)
    write_gaussian_ply(tmp_path / "in.ply", gs)
    out = tmp_path / "X.compressed.ply"
    argv = [
        "export",
        tmp_path / "in.ply",
        "--out",
        out,
        "--out",
        tmp_path / "pts.ply",
        "--points",
        "--min-opacity",
        "0",
    ]
    assert _cli(argv) == 0
    np.testing.assert_array_equal(read_origin(out), GEO_ORIGIN)
    assert (tmp_path / "X.compressed.origin.json").is_file()
    d = read_compressed_ply(out)  # --points applies to plain .ply outputs only
    assert len(d) == 1500 and d.sh_degree == 3
    local = gs.means.astype(np.float32).astype(np.float64)  # what the 3DGS PLY holds
    truth = local[morton_order(local)] + GEO_ORIGIN
    chunk = _chunk_table(out)[np.arange(len(d)) // CHUNK_SIZE]
    bound = _step_bounds(chunk[:, 0:3], chunk[:, 3:6], BITS_11_10_11) + 1e-9
    assert (np.abs(d.positions + d.origin - truth) <= bound).all()
    assert "packed_position" not in plyfile.PlyData.read(str(tmp_path / "pts.ply"))["vertex"].data.dtype.names


# -- an independent reader (optional: node + splat-transform) ------------------------------------------------------
def _splat_transform() -> str:
    return splat_transform()


def test_splat_transform_reads_our_compressed_ply_with_our_values(tmp_path):
    st = _splat_transform()
    gs = _random_set(n=3000, degree=3)
    layout = write_compressed_ply(tmp_path / "g.compressed.ply", gs)
    proc = subprocess.run(
        [st, "-w", str(tmp_path / "g.compressed.ply"), str(tmp_path / "g.csv")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    header = (tmp_path / "g.csv").read_text().splitlines()[0].split(",")
    table = np.loadtxt(tmp_path / "g.csv", delimiter=",", skiprows=1, ndmin=2)
    col = {name: table[:, i] for i, name in enumerate(header)}
    assert len(table) == len(gs)
    errors = _errors_and_bounds(gs, tmp_path / "g.compressed.ply", layout.order)
    g = gs.subset(layout.order)
    theirs = {
        "position": np.c_[col["x"], col["y"], col["z"]] - g.means,
        "log_scale": np.c_[col["scale_0"], col["scale_1"], col["scale_2"]] - g.log_scales,
        "color": SH_C0 * (np.c_[col["f_dc_0"], col["f_dc_1"], col["f_dc_2"]] - g.sh_dc),
        "alpha": 1 / (1 + np.exp(-col["opacity"])) - 1 / (1 + np.exp(-g.logit_opacities.astype(np.float64))),
    }
    for key, diff in theirs.items():
        _, bound = errors[key]
        assert (np.abs(diff).reshape(len(g), -1) <= bound.reshape(len(g), -1) + 1e-5).all(), key  # CSV: float32
    d = read_compressed_ply(tmp_path / "g.compressed.ply")
    rot = np.c_[col["rot_0"], col["rot_1"], col["rot_2"], col["rot_3"]]
    np.testing.assert_allclose(rot, d.quats, atol=1e-6)
    rest = np.stack([col[f"f_rest_{i}"] for i in range(45)], axis=1).reshape(len(g), 3, 15).transpose(0, 2, 1)
    np.testing.assert_allclose(rest, d.sh_rest, atol=1e-6)
