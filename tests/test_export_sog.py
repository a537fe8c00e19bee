"""PlayCanvas SOG export (fusion.sog_format, fusion.export, ``--out X.sog`` / ``--out DIR/meta.json``).

Truth is the Gaussian set we wrote: each decoded value must lie within the bound its encoding allows, derived from
what the file states (the log-position range and the codebooks of meta.json, read with zipfile and json alone):
positions within half a 16-bit step of the log transform, log-scales / f_dc / SH-palette values within half the
largest gap between codebook entries, α within 1/510, rotations within the smallest-three step. Each bound is
also shown to be tight (some value comes near it). When node and ``@playcanvas/splat-transform`` are installed
(``scripts/check_splat_transform.sh``; nothing is downloaded here), splat-transform reads our ``.sog`` and our
``meta.json`` and converts them to PLY, which must hold our decoded values.
"""

from __future__ import annotations

import io
import json
import math
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import plyfile
import pytest
from npm_readers import splat_transform
from PIL import Image

from core.errors import DataError, FormatError, InputFileError
from core.gaussians import SH_C0, GaussianSet
from core.io.gaussian_ply import write_gaussian_ply
from core.io.origin import read_origin, sidecar_path
from fusion.compressed_ply_format import morton_order
from fusion.export import ExportOptions, export_gaussians, export_sog
from fusion.sog_format import (
    FILE_ORDER,
    kmeans,
    palette_size,
    quantise_codebook,
    read_sog,
    texture_size,
    write_sog,
)

GEO_ORIGIN = np.array([500000.0, 4000000.0, 100.0])
ALPHA_BOUND = 0.5 / 255
ROT_STORED_BOUND = math.sqrt(2) / 510  # half of an 8-bit step over [−1/√2, 1/√2]
SLACK = 1e-6  # float32 codebook entries and float32 quaternions


def _largest_bound(e: float) -> float:
    """The reconstructed largest component when the three stored ones err by ≤ e (see test_export_spz)."""
    d = 3 * e * (1 + e)
    return d / (0.5 + math.sqrt(0.25 - d))


def _random_set(n: int = 4096, degree: int = 3, origin=(0.0, 0.0, 0.0), seed: int = 0, extent: float = 20.0):
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


def _bundle(path: Path) -> tuple[dict, dict[str, np.ndarray]]:
    """meta.json and the decoded images of a .sog, read with zipfile, json and Pillow alone."""
    with zipfile.ZipFile(path) as z:
        meta = json.loads(z.read("meta.json"))
        images = {
            n: np.asarray(Image.open(io.BytesIO(z.read(n))).convert("RGBA")) for n in z.namelist() if n != "meta.json"
        }
    return meta, images


def _half_gap(codebook: list) -> float:
    c = np.asarray(codebook, np.float64)
    return float(np.diff(c).max() / 2)


def _errors_and_bounds(gs: GaussianSet, path: Path, order: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per-value errors of our reader against the (reordered) truth, and their bounds from the file's meta.json."""
    g = gs.subset(order)
    d = read_sog(path)
    meta, _ = _bundle(path)
    step = (np.asarray(meta["means"]["maxs"]) - np.asarray(meta["means"]["mins"])) / 65535
    pos_bound = (np.abs(g.means) + 1) * np.expm1(step / 2) * (1 + 1e-9) + 1e-12
    alpha = 1 / (1 + np.exp(-g.logit_opacities.astype(np.float64)))
    return {
        "position": (np.abs(d.positions - g.means), pos_bound),
        "log_scale": (np.abs(d.log_scales - g.log_scales), np.full((len(g), 3), _half_gap(meta["scales"]["codebook"]))),
        "f_dc": (np.abs(d.sh_dc - g.sh_dc), np.full((len(g), 3), _half_gap(meta["sh0"]["codebook"]))),
        "alpha": (np.abs(d.alphas - alpha), np.full(len(g), ALPHA_BOUND)),
    }


# -- layout --------------------------------------------------------------------------------------------------------
def test_bundle_layout_meta_and_image_sizes(tmp_path):
    gs = _random_set(n=1000, degree=2)
    layout = write_sog(tmp_path / "g.sog", gs)
    with zipfile.ZipFile(tmp_path / "g.sog") as z:
        infos = z.infolist()
    assert [i.filename for i in infos] == [*FILE_ORDER, "meta.json"]  # splat-transform's order, meta.json last
    assert all(i.compress_type == zipfile.ZIP_STORED for i in infos)
    meta, images = _bundle(tmp_path / "g.sog")
    assert meta["version"] == 2 and meta["count"] == 1000
    assert set(meta) == {"version", "asset", "count", "means", "scales", "quats", "sh0", "shN"}
    assert meta["means"]["files"] == ["means_l.webp", "means_u.webp"] and meta["quats"]["files"] == ["quats.webp"]
    assert len(meta["scales"]["codebook"]) == 256 and len(meta["sh0"]["codebook"]) == 256
    assert meta["shN"]["bands"] == 2 and meta["shN"]["count"] == 512 and len(meta["shN"]["codebook"]) == 256
    assert (layout.width, layout.height) == (32, 32)  # 4·ceil(√1000/4) = 32, 4·ceil(1000/32/4) = 32
    for name in ("means_l.webp", "means_u.webp", "quats.webp", "scales.webp", "sh0.webp", "shN_labels.webp"):
        assert images[name].shape == (32, 32, 4), name
    assert images["shN_centroids.webp"].shape == (8, 64 * 8, 4)  # 512 centroids, 64 a row, 8 coefficients each
    quats = images["quats.webp"].reshape(-1, 4)
    assert set(np.unique(quats[:1000, 3])) <= {252, 253, 254, 255} and (quats[1000:] == 0).all()  # zero padding
    labels = images["shN_labels.webp"].reshape(-1, 4)[:1000]
    assert (labels[:, 2] == 0).all() and (labels[:, 3] == 255).all()
    assert (labels[:, 0].astype(int) | (labels[:, 1].astype(int) << 8)).max() < 512


@pytest.mark.parametrize("n", [1, 2, 15, 16, 17, 1000, 4096, 99_999, 1_000_001])
def test_texture_size_is_splat_transforms_formula(n):
    width = math.ceil(math.sqrt(n) / 4) * 4
    assert texture_size(n) == (width, math.ceil(n / width / 4) * 4)
    assert texture_size(n)[0] * texture_size(n)[1] >= n


@pytest.mark.parametrize("n", [1, 700, 1024, 5000, 10**6])
def test_palette_size_is_splat_transforms_formula(n):
    assert palette_size(n) == int(min(64, 2 ** math.floor(math.log2(n / 1024))) * 1024)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_degrees(tmp_path, degree):
    gs = _random_set(n=1024, degree=degree)  # a power of two: the palette holds every splat, SH exact to the codebook
    layout = write_sog(tmp_path / "g.sog", gs)
    meta, images = _bundle(tmp_path / "g.sog")
    assert ("shN" in meta) == (degree > 0) and layout.sh_degree == degree
    d = read_sog(tmp_path / "g.sog")
    assert len(d) == 1024 and d.sh_degree == degree
    if degree:
        coeffs = (degree + 1) ** 2 - 1
        assert meta["shN"]["bands"] == degree and images["shN_centroids.webp"].shape[1] == 64 * coeffs
        truth = gs.subset(layout.order).sh_rest.astype(np.float64)  # type: ignore[union-attr]
        err = np.abs(d.sh_rest - truth)
        bound = _half_gap(meta["shN"]["codebook"]) + SLACK
        assert err.max() <= bound and err.max() > 0.5 * bound
        assert bound <= (truth.max() - truth.min()) / 126 + 2 * SLACK  # the uniform grid of 64 entries


# -- precision -----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("sort", [True, False])
def test_round_trip_within_the_stated_bounds(tmp_path, sort):
    gs = _random_set(n=4096)
    layout = write_sog(tmp_path / "g.sog", gs, sort=sort)
    for key, (err, bound) in _errors_and_bounds(gs, tmp_path / "g.sog", layout.order).items():
        assert (err <= bound + SLACK * (key != "position")).all(), (key, float((err / bound).max()))
        assert (err / bound).max() > 0.5, key  # tight: some value sits near the bound
    meta, _ = _bundle(tmp_path / "g.sog")
    assert _half_gap(meta["scales"]["codebook"]) <= 11 / 126 + SLACK  # log σ spans [−9, 2]
    assert _half_gap(meta["sh0"]["codebook"]) <= 4 / 126 + SLACK  # f_dc spans [−2, 2]


def test_rotations_within_the_smallest_three_bounds(tmp_path):
    gs = _random_set(n=4096)
    layout = write_sog(tmp_path / "g.sog", gs)
    d = read_sog(tmp_path / "g.sog")
    q = gs.subset(layout.order).unit_quats.astype(np.float64)
    rows = np.arange(len(q))
    largest = np.argmax(np.abs(q), axis=1)
    q = q * np.where(q[rows, largest] < 0, -1.0, 1.0)[:, None]  # the file makes the largest positive
    stored = np.ones_like(q, bool)
    stored[rows, largest] = False
    err = np.abs(d.quats - q)
    assert err[stored].max() <= ROT_STORED_BOUND + SLACK and err[stored].max() > 0.9 * ROT_STORED_BOUND
    assert err[~stored].max() <= _largest_bound(ROT_STORED_BOUND) + SLACK
    _, images = _bundle(tmp_path / "g.sog")
    np.testing.assert_array_equal(images["quats.webp"].reshape(-1, 4)[: len(q), 3], 252 + largest)  # w, x, y, z


def test_codebook_bound_and_density():
    rng = np.random.default_rng(3)
    values = np.concatenate([rng.normal(-4, 0.3, 50_000), rng.uniform(-20, 3, 200)])  # dense core, sparse tail
    book, labels = quantise_codebook(values)
    assert book.dtype == np.float32 and book.shape == (256,) and (np.diff(book) >= 0).all()
    err = np.abs(book[labels].astype(np.float64) - values)
    assert err.max() <= (values.max() - values.min()) / 126 + SLACK
    uniform = np.linspace(values.min(), values.max(), 256)
    uniform_err = np.abs(uniform[np.abs(values[:, None] - uniform[None, :]).argmin(axis=1)] - values)
    assert np.sqrt((err**2).mean()) < np.sqrt((uniform_err**2).mean()) / 3  # entries follow the density
    book, labels = quantise_codebook(np.full(10, 2.5))
    assert (book == 2.5).all() and (labels == 0).all()


def test_kmeans_is_deterministic_and_two_level_for_large_palettes():
    rng = np.random.default_rng(1)
    centres = rng.normal(size=(300, 9))
    points = centres[rng.integers(0, 300, 6000)] + rng.normal(scale=0.01, size=(6000, 9))
    c1, l1 = kmeans(points, 4096, iterations=4, seed=0)  # > 1024: coarse 64, then a share each
    c2, l2 = kmeans(points, 4096, iterations=4, seed=0)
    np.testing.assert_array_equal(c1, c2)
    np.testing.assert_array_equal(l1, l2)
    assert c1.shape == (4096, 9) and l1.min() >= 0 and l1.max() < 4096
    assert np.sqrt(((c1[l1] - points) ** 2).sum(axis=1).mean()) < 0.05  # 300 tight clusters are found
    c, labels = kmeans(points[:10], 16)
    np.testing.assert_array_equal(c, points[:10].astype(np.float32))
    np.testing.assert_array_equal(labels, np.arange(10))


def test_clustered_sh_is_recovered_through_the_palette(tmp_path):
    rng = np.random.default_rng(2)
    palette = rng.normal(scale=0.3, size=(40, 15, 3))
    gs = _random_set(n=3000)
    gs.sh_rest[:] = palette[rng.integers(0, 40, 3000)]  # 40 distinct SH vectors, palette 2048
    layout = write_sog(tmp_path / "c.sog", gs)
    d = read_sog(tmp_path / "c.sog")
    meta, _ = _bundle(tmp_path / "c.sog")
    err = np.abs(d.sh_rest - gs.subset(layout.order).sh_rest)
    assert meta["shN"]["count"] == 2048 and err.max() <= _half_gap(meta["shN"]["codebook"]) + SLACK


# -- determinism, unbundled form -----------------------------------------------------------------------------------
def test_same_bytes_twice(tmp_path):
    gs = _random_set(n=3000)
    write_sog(tmp_path / "a.sog", gs)
    write_sog(tmp_path / "b.sog", gs)
    assert (tmp_path / "a.sog").read_bytes() == (tmp_path / "b.sog").read_bytes()


def test_unbundled_meta_json_holds_the_bundles_files(tmp_path):
    gs = _random_set(n=2000, degree=1)
    write_sog(tmp_path / "g.sog", gs)
    layout = write_sog(tmp_path / "u" / "meta.json", gs)
    with zipfile.ZipFile(tmp_path / "g.sog") as z:
        for name in layout.files:
            assert (tmp_path / "u" / name).read_bytes() == z.read(name), name
    a, b = read_sog(tmp_path / "g.sog"), read_sog(tmp_path / "u" / "meta.json")
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.sh_rest, b.sh_rest)


# -- degenerate and bad input --------------------------------------------------------------------------------------
def test_one_splat_and_coincident_splats_are_valid_files(tmp_path):
    one = _random_set(n=1, degree=3, origin=GEO_ORIGIN)
    layout = write_sog(tmp_path / "one.sog", one)
    d = read_sog(tmp_path / "one.sog")
    assert (layout.width, layout.height, layout.palette_size) == (4, 4, 1)
    np.testing.assert_allclose(d.positions, one.means, rtol=0, atol=1e-12)
    np.testing.assert_allclose(d.log_scales, one.log_scales, atol=SLACK)
    same = _random_set(n=300, degree=1)
    same.means[:] = [1.25, -2.5, 3.0]  # no extent on any axis
    same.log_scales[:] = -3.0
    write_sog(tmp_path / "same.sog", same)
    d = read_sog(tmp_path / "same.sog")
    np.testing.assert_allclose(d.positions, np.tile([1.25, -2.5, 3.0], (300, 1)), rtol=1e-15)
    assert (d.log_scales == -3.0).all()


def test_empty_set_is_refused_and_writes_nothing(tmp_path):
    with pytest.raises(DataError, match=r"e\.sog.*no Gaussians"):
        write_sog(tmp_path / "e.sog", _random_set(n=0))
    with pytest.raises(DataError, match="nothing to export"):
        export_sog(tmp_path / "e.sog", _random_set(n=5), ExportOptions(min_opacity=0.999999))
    assert not list(tmp_path.iterdir())


def test_nan_input_is_refused_with_the_file_named(tmp_path):
    gs = _random_set(n=20)
    gs.sh_dc[4, 2] = np.inf
    with pytest.raises(DataError, match=r"n\.sog.*1 Gaussians have NaN or infinite sh_dc"):
        export_sog(tmp_path / "n.sog", gs, ExportOptions(min_opacity=0))
    assert not list(tmp_path.iterdir())


def test_reader_errors_name_the_problem(tmp_path):
    (tmp_path / "bad.sog").write_bytes(b"not a zip")
    with pytest.raises(FormatError, match="not a zip"):
        read_sog(tmp_path / "bad.sog")
    with pytest.raises(InputFileError, match="not found"):
        read_sog(tmp_path / "missing.sog")
    (tmp_path / "v1").mkdir()
    (tmp_path / "v1" / "meta.json").write_text(json.dumps({"means": {"shape": [3, 3]}}))
    with pytest.raises(FormatError, match="version none"):
        read_sog(tmp_path / "v1" / "meta.json")
    write_sog(tmp_path / "u" / "meta.json", _random_set(n=50, degree=0))
    (tmp_path / "u" / "quats.webp").unlink()
    with pytest.raises(InputFileError, match="quats.webp"):
        read_sog(tmp_path / "u" / "meta.json")


# -- sidecar, dispatch, command line -------------------------------------------------------------------------------
def test_georeferenced_export_keeps_the_origin_in_the_sidecar(tmp_path):
    gs = _random_set(n=3000, origin=GEO_ORIGIN)
    out = tmp_path / "geo.sog"
    report = export_sog(out, gs, ExportOptions(min_opacity=0, crs="EPSG:32632"))
    assert report.format == "sog" and report.num_written == 3000 and report.origin == tuple(GEO_ORIGIN)
    side = json.loads(sidecar_path(out).read_text())
    assert sidecar_path(out) == tmp_path / "geo.origin.json"
    assert side["origin"] == GEO_ORIGIN.tolist() and side["crs"] == "EPSG:32632"
    meta, _ = _bundle(out)
    assert max(map(abs, meta["means"]["mins"] + meta["means"]["maxs"])) <= math.log1p(20.0)  # local, not UTM
    d = read_sog(out)
    np.testing.assert_array_equal(d.origin, GEO_ORIGIN)
    truth = gs.subset(morton_order(gs.means))  # the writer's order
    step = (np.asarray(meta["means"]["maxs"]) - np.asarray(meta["means"]["mins"])) / 65535
    bound = (np.abs(truth.means) + 1) * np.expm1(step / 2) + 1e-9  # float64 world = origin + decoded local
    assert (np.abs(d.to_gaussians().world_means - truth.world_means) <= bound).all()
    export_sog(out, _random_set(n=10), ExportOptions(min_opacity=0))
    assert not sidecar_path(out).exists()  # a stale sidecar goes when the origin is zero


def test_dispatch(tmp_path):
    gs = _random_set(n=64, degree=1)
    assert export_gaussians(tmp_path / "A.SOG", gs).format == "sog"
    assert export_gaussians(tmp_path / "unb" / "meta.json", gs).format == "sog"
    assert (tmp_path / "unb" / "shN_labels.webp").is_file()
    with pytest.raises(FormatError, match=r"\.spz, \.sog.*meta\.json"):
        export_gaussians(tmp_path / "a.obj", gs)


def _cli(argv: list) -> int:
    from hybridsplat.cli import main

    try:
        main([str(a) for a in argv])
    except SystemExit as ex:
        return int(ex.code or 0)
    return 0


def test_cli_export_writes_sog_bundle_and_folder(tmp_path):
    gs = _random_set(n=1500, origin=GEO_ORIGIN)
    write_gaussian_ply(tmp_path / "in.ply", gs)
    out, folder = tmp_path / "X.sog", tmp_path / "web" / "meta.json"
    assert _cli(["export", tmp_path / "in.ply", "--out", out, "--out", folder, "--min-opacity", "0"]) == 0
    np.testing.assert_array_equal(read_origin(out), GEO_ORIGIN)
    np.testing.assert_array_equal(read_origin(folder), GEO_ORIGIN)  # web/meta.origin.json
    d = read_sog(out)
    assert len(d) == 1500 and d.sh_degree == 3
    np.testing.assert_array_equal(d.positions, read_sog(folder).positions)


# -- an independent reader (optional: node + splat-transform) ------------------------------------------------------
def _splat_transform() -> str:
    return splat_transform()


@pytest.mark.parametrize(("name", "degree"), [("g.sog", 3), ("u/meta.json", 1), ("z.sog", 0)])
def test_splat_transform_reads_our_sog_with_our_values(tmp_path, name, degree):
    st = _splat_transform()
    gs = _random_set(n=3000, degree=degree)
    src = tmp_path / name
    layout = write_sog(src, gs)
    proc = subprocess.run([st, "-w", str(src), str(tmp_path / "back.ply")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    v = plyfile.PlyData.read(str(tmp_path / "back.ply"))["vertex"].data
    d = read_sog(src)
    assert len(v) == len(gs) == len(d)
    col = lambda *names: np.stack([np.asarray(v[n], np.float64) for n in names], axis=1)  # noqa: E731
    xyz = col("x", "y", "z")
    np.testing.assert_allclose(xyz, d.positions, rtol=1e-6, atol=1e-6)  # PLY float32
    np.testing.assert_allclose(col("f_dc_0", "f_dc_1", "f_dc_2"), d.sh_dc, atol=1e-6)
    np.testing.assert_allclose(col("scale_0", "scale_1", "scale_2"), d.log_scales, atol=1e-6)
    np.testing.assert_allclose(col("rot_0", "rot_1", "rot_2", "rot_3"), d.quats, atol=1e-6)
    alpha = 1 / (1 + np.exp(-np.asarray(v["opacity"], np.float64)))
    np.testing.assert_allclose(alpha, d.alphas, atol=1.01e-6)  # splat-transform clamps α to [1e-6, 1 − 1e-6]
    k = (degree + 1) ** 2 - 1
    if k:
        rest = col(*(f"f_rest_{i}" for i in range(3 * k))).reshape(len(v), 3, k).transpose(0, 2, 1)
        np.testing.assert_allclose(rest, d.sh_rest, atol=1e-6)
    # and their decoding against what we wrote, within our bounds
    g = gs.subset(layout.order)
    meta = json.loads(src.read_bytes() if src.suffix == ".json" else zipfile.ZipFile(src).read("meta.json"))
    step = (np.asarray(meta["means"]["maxs"]) - np.asarray(meta["means"]["mins"])) / 65535
    assert (np.abs(xyz - g.means) <= (np.abs(g.means) + 1) * np.expm1(step / 2) + 2e-6 * 21).all()
    colour_err = SH_C0 * np.abs(col("f_dc_0", "f_dc_1", "f_dc_2") - g.sh_dc)
    assert colour_err.max() <= SH_C0 * _half_gap(meta["sh0"]["codebook"]) + SLACK
