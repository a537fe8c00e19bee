"""A generator of malformed inputs for the command line, one :class:`FuzzCase` per file and defect.

Each case builds its inputs in a fresh folder from a valid file written by the toolkit's own writers (or
by the reference tool: pycolmap, pye57, laspy), then breaks it: truncation at every section boundary of
the format, counts larger or smaller than the data, wrong dtypes, NaN/inf values, huge counts, empty
files, wrong magic, folders where files are expected, unwritable outputs. A case names the command to run,
the file the error must name, and the outputs that must not exist afterwards.

Used by ``tests/fuzz/test_fuzz_cli.py`` (each case in a subprocess under time and memory limits) and by
``bench/bench_fuzz.py`` (time and peak memory per case).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

UTM = np.array([500_000.0, 5_000_000.0, 100.0])


@dataclass(frozen=True)
class Invocation:
    """What to run and what to check: argv (without the program), the file the error must name, and
    the outputs that must not exist afterwards."""

    argv: list[str]
    culprit: str
    outputs: tuple[Path, ...] = ()
    expect_code: int = 2


@dataclass(frozen=True)
class FuzzCase:
    """One malformed input. ``build(folder)`` writes the inputs into ``folder`` and returns the invocation;
    ``fast`` cases also run in the normal test suite."""

    name: str
    build: Callable[[Path], Invocation]
    fast: bool = False
    tags: tuple[str, ...] = field(default_factory=tuple)


# -- valid base files -----------------------------------------------------------------------------------
def cloud_ply(path: Path, n: int = 20, binary: bool = True) -> Path:
    from core.io.ply import write_ply
    from core.pointcloud import PointCloud

    rng = np.random.default_rng(0)
    cloud = PointCloud(rng.normal(size=(n, 3)), colors=rng.integers(0, 256, (n, 3)).astype(np.uint8))
    return write_ply(path, cloud, binary=binary)


def gaussians(n: int = 10, origin: np.ndarray | None = None):
    from core.gaussians import GaussianSet

    rng = np.random.default_rng(1)
    return GaussianSet(
        means=rng.normal(size=(n, 3)),
        log_scales=np.full((n, 3), -3.0, np.float32),
        quats=np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
        logit_opacities=np.full(n, 2.0, np.float32),
        sh_dc=rng.normal(size=(n, 3)).astype(np.float32),
        sh_rest=np.zeros((n, 0, 3), np.float32),
        origin=np.zeros(3) if origin is None else origin,
    )


def gaussian_ply(path: Path, n: int = 10) -> Path:
    from core.io.gaussian_ply import write_gaussian_ply

    return write_gaussian_ply(path, gaussians(n))


def las_file(path: Path, n: int = 50) -> Path:
    from core.io.las import write_las
    from core.pointcloud import PointCloud

    rng = np.random.default_rng(2)
    return write_las(path, PointCloud.from_world(rng.normal(size=(n, 3)) + UTM))


def e57_file(path: Path, n: int = 100) -> Path:
    import pye57

    rng = np.random.default_rng(3)
    local = rng.uniform(0, 10, (n, 3))
    e57 = pye57.E57(str(path), mode="w")
    e57.write_scan_raw({"cartesianX": local[:, 0], "cartesianY": local[:, 1], "cartesianZ": local[:, 2]})
    e57.close()
    return path


def colmap_model(folder: Path, binary: bool = True) -> Path:
    """A pycolmap-written model: 2 cameras, 4 images, 15 points with tracks (rigs and frames included)."""
    import pycolmap

    opts = pycolmap.SyntheticDatasetOptions()
    opts.num_points3D = 15
    opts.num_cameras_per_rig = 1
    opts.num_frames_per_rig = 2
    opts.num_rigs = 2
    opts.camera_width, opts.camera_height = 64, 48
    opts.camera_model_id = pycolmap.CameraModelId.PINHOLE
    rec = pycolmap.synthesize_dataset(opts)
    folder.mkdir(parents=True, exist_ok=True)
    if binary:
        rec.write_binary(str(folder))
    else:
        rec.write_text(str(folder))
    return folder


def png(path: Path, h: int = 40, w: int = 48, seed: int = 0) -> Path:
    from core.io.images import write_image

    return write_image(path, np.random.default_rng(seed).integers(0, 256, (h, w, 3)).astype(np.uint8))


def image_pair(folder: Path) -> tuple[Path, Path]:
    renders, photos = folder / "renders", folder / "photos"
    png(renders / "v0.png", seed=1)
    png(photos / "v0.png", seed=2)
    return renders, photos


# -- helpers --------------------------------------------------------------------------------------------
def ply_header_end(data: bytes) -> int:
    return data.index(b"end_header") + len(b"end_header\n")


def truncate(path: Path, size: int) -> None:
    path.write_bytes(path.read_bytes()[:size])


def _boundaries(size: int, marks: list[int]) -> list[int]:
    """Sorted unique cut points strictly inside (0, size)."""
    return sorted({m for m in marks if 0 < m < size})


def _cloud_cmd(d: Path, src: Path) -> Invocation:
    out = d / "out" / "g.ply"
    return Invocation(["convert", str(src), "--out", str(out)], src.name, (out, out.with_name("g.origin.json")))


def _gs_cmd(d: Path, src: Path) -> Invocation:
    a, b = d / "out" / "a.splat", d / "out" / "b.las"
    return Invocation(["export", str(src), "--out", str(a), "--out", str(b)], src.name, (a, b))


def _model_cmd(d: Path, model: Path, culprit: str) -> Invocation:
    gs = gaussian_ply(d / "g.ply")
    out = d / "renders"
    return Invocation(["render", str(gs), "--cameras", str(model), "--out", str(out)], culprit, (out,))


# -- PLY point clouds -----------------------------------------------------------------------------------
def _ply_cases() -> list[FuzzCase]:
    cases: list[FuzzCase] = []

    def empty(d: Path) -> Invocation:
        p = d / "empty.ply"
        p.write_bytes(b"")
        return _cloud_cmd(d, p)

    def magic(d: Path) -> Invocation:
        p = cloud_ply(d / "magic.ply")
        p.write_bytes(b"plx" + p.read_bytes()[3:])
        return _cloud_cmd(d, p)

    def folder(d: Path) -> Invocation:
        p = d / "folder.ply"
        p.mkdir()
        return _cloud_cmd(d, p)

    cases += [FuzzCase("ply-empty", empty, fast=True), FuzzCase("ply-magic", magic), FuzzCase("ply-folder", folder)]

    # truncation at every section boundary of a binary PLY (20 vertices of 27 bytes)
    probe = cloud_ply(Path("/tmp") / f".fuzz_probe_{id(cases)}.ply")
    data = probe.read_bytes()
    probe.unlink()
    hdr = ply_header_end(data)
    rec = (len(data) - hdr) // 20
    for cut in _boundaries(
        len(data), [2, hdr // 2, hdr - 1, hdr, hdr + rec // 2, hdr + rec, len(data) - rec, len(data) - 1]
    ):

        def trunc(d: Path, cut: int = cut) -> Invocation:
            p = cloud_ply(d / f"cut{cut}.ply")
            truncate(p, cut)
            return _cloud_cmd(d, p)

        cases.append(FuzzCase(f"ply-truncated-{cut}", trunc, fast=cut == len(data) - rec))

    def header(text: str, body: bytes = b"") -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            p = d / "h.ply"
            p.write_bytes(text.encode("ascii") + body)
            return _cloud_cmd(d, p)

        return build

    xyz = "property float x\nproperty float y\nproperty float z\n"
    cases += [
        FuzzCase(
            "ply-xyz-as-lists",
            header(
                "ply\nformat ascii 1.0\nelement vertex 2\nproperty list uchar float x\nproperty list uchar float y\n"
                "property list uchar float z\nend_header\n",
                b"1 0.5 1 0.5 1 0.5\n1 0.5 1 0.5 1 0.5\n",
            ),
            fast=True,
        ),
        FuzzCase(
            "ply-ascii-2e31-vertices",
            header(f"ply\nformat ascii 1.0\nelement vertex {2**31}\n{xyz}end_header\n", b"0 0 0\n"),
            fast=True,
        ),
        FuzzCase(
            "ply-binary-2e31-vertices",
            header(f"ply\nformat binary_little_endian 1.0\nelement vertex {2**31}\n{xyz}end_header\n", bytes(12)),
        ),
        FuzzCase("ply-negative-count", header(f"ply\nformat ascii 1.0\nelement vertex -5\n{xyz}end_header\n")),
        FuzzCase("ply-count-not-a-number", header(f"ply\nformat ascii 1.0\nelement vertex many\n{xyz}end_header\n")),
        FuzzCase(
            "ply-ascii-short-line",
            header(f"ply\nformat ascii 1.0\nelement vertex 2\n{xyz}end_header\n", b"0 0 0\n1 1\n"),
        ),
        FuzzCase(
            "ply-ascii-bad-token", header(f"ply\nformat ascii 1.0\nelement vertex 1\n{xyz}end_header\n", b"0 zero 0\n")
        ),
        FuzzCase(
            "ply-ascii-nan",
            header(f"ply\nformat ascii 1.0\nelement vertex 2\n{xyz}end_header\n", b"0 0 0\nnan 1 1\n"),
        ),
        FuzzCase(
            "ply-binary-inf",
            header(
                f"ply\nformat binary_little_endian 1.0\nelement vertex 1\n{xyz}end_header\n",
                np.array([np.inf, 0, 0], "<f4").tobytes(),
            ),
        ),
        FuzzCase(
            "ply-unknown-type",
            header(
                "ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nproperty float y\n"
                "property float z\nend_header\n",
                b"0 0 0\n",
            ),
        ),
        FuzzCase(
            "ply-no-vertex",
            header("ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"),
        ),
        FuzzCase(
            "ply-unknown-format",
            header(f"ply\nformat binary_middle_endian 1.0\nelement vertex 1\n{xyz}end_header\n", bytes(12)),
        ),
        FuzzCase(
            "ply-float-colors-nan",
            header(
                f"ply\nformat ascii 1.0\nelement vertex 1\n{xyz}property float red\nproperty float green\n"
                "property float blue\nend_header\n",
                b"0 0 0 nan 0 0\n",
            ),
        ),
        FuzzCase(
            "ply-huge-header-count-with-list",
            header(
                f"ply\nformat binary_little_endian 1.0\nelement vertex 1\n{xyz}element face {2**40}\n"
                "property list uchar int vertex_indices\nend_header\n",
                bytes(12) + b"\x03" + bytes(12),
            ),
        ),
    ]

    def sidecar_folder(d: Path) -> Invocation:
        p = cloud_ply(d / "c.ply")
        (d / "c.origin.json").mkdir()
        inv = _cloud_cmd(d, p)
        return Invocation(inv.argv, "c.origin.json", inv.outputs)

    def sidecar_garbage(text: str) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            p = cloud_ply(d / "c.ply")
            (d / "c.origin.json").write_text(text)
            inv = _cloud_cmd(d, p)
            return Invocation(inv.argv, "c.origin.json", inv.outputs)

        return build

    cases += [
        FuzzCase("sidecar-folder", sidecar_folder, fast=True),
        FuzzCase("sidecar-bad-json", sidecar_garbage("{")),
        FuzzCase("sidecar-nan", sidecar_garbage('{"origin": [NaN, 0, 0]}')),
        FuzzCase("sidecar-wrong-type", sidecar_garbage('{"origin": "here"}')),
        FuzzCase("sidecar-wrong-length", sidecar_garbage('{"origin": [1, 2]}')),
        FuzzCase("sidecar-not-object", sidecar_garbage("[1, 2, 3]")),
        FuzzCase("sidecar-huge", sidecar_garbage('{"origin": [1e300, 1e300, 1e300]}')),
    ]
    return cases


# -- 3DGS PLY and .splat ---------------------------------------------------------------------------------
def _gs_cases() -> list[FuzzCase]:
    cases: list[FuzzCase] = []

    def poke(prop: str, value: float, name: str) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            import plyfile

            p = gaussian_ply(d / f"{name}.ply")
            ply = plyfile.PlyData.read(str(p), mmap=False)
            ply["vertex"].data[prop][3] = value
            ply.write(str(p))
            return _gs_cmd(d, p)

        return build

    cases += [
        FuzzCase("gs-inf-scale", poke("scale_0", np.inf, "infscale"), fast=True),
        FuzzCase("gs-nan-opacity", poke("opacity", np.nan, "nanopacity")),
        FuzzCase("gs-inf-position", poke("x", -np.inf, "infpos")),
        FuzzCase("gs-nan-color", poke("f_dc_1", np.nan, "nancolor")),
        FuzzCase("gs-huge-scale", poke("scale_2", 1e30, "hugescale")),
    ]

    def zero_quat(d: Path) -> Invocation:
        import plyfile

        p = gaussian_ply(d / "zeroquat.ply")
        ply = plyfile.PlyData.read(str(p), mmap=False)
        for k in range(4):
            ply["vertex"].data[f"rot_{k}"][2] = 0.0
        ply.write(str(p))
        return _gs_cmd(d, p)

    cases.append(FuzzCase("gs-zero-quaternion", zero_quat))

    probe = gaussian_ply(Path("/tmp") / f".fuzz_gs_probe_{id(cases)}.ply")
    data = probe.read_bytes()
    probe.unlink()
    hdr = ply_header_end(data)
    rec = (len(data) - hdr) // 10
    for cut in _boundaries(len(data), [hdr - 1, hdr, hdr + rec // 2, len(data) - rec, len(data) - 1]):

        def trunc(d: Path, cut: int = cut) -> Invocation:
            p = gaussian_ply(d / f"gcut{cut}.ply")
            truncate(p, cut)
            return _gs_cmd(d, p)

        cases.append(FuzzCase(f"gs-truncated-{cut}", trunc))

    def missing_prop(d: Path) -> Invocation:
        import plyfile

        p = gaussian_ply(d / "noscale.ply")
        v = plyfile.PlyData.read(str(p), mmap=False)["vertex"].data
        names = [n for n in v.dtype.names if n != "scale_1"]
        arr = np.empty(len(v), [(n, "<f4") for n in names])
        for n in names:
            arr[n] = v[n]
        plyfile.PlyData([plyfile.PlyElement.describe(arr, "vertex")]).write(str(p))
        return _gs_cmd(d, p)

    def wrong_dtype(d: Path) -> Invocation:
        import plyfile

        p = gaussian_ply(d / "listscale.ply")
        v = plyfile.PlyData.read(str(p), mmap=False)["vertex"].data
        dt = [(n, "<f4") if n != "opacity" else (n, object) for n in v.dtype.names]
        arr = np.empty(len(v), dt)
        for n in v.dtype.names:
            arr[n] = v[n] if n != "opacity" else [np.array([1.0], "<f4") for _ in range(len(v))]
        el = plyfile.PlyElement.describe(arr, "vertex", len_types={"opacity": "u1"}, val_types={"opacity": "f4"})
        plyfile.PlyData([el]).write(str(p))
        return _gs_cmd(d, p)

    cases += [
        FuzzCase("gs-missing-scale_1", missing_prop),
        FuzzCase("gs-opacity-as-list", wrong_dtype),
    ]
    return cases


# -- LAS / LAZ / E57 ---------------------------------------------------------------------------------------
def _las_cases() -> list[FuzzCase]:
    cases: list[FuzzCase] = []
    probe = las_file(Path("/tmp") / f".fuzz_las_probe_{id(cases)}.las")
    data = probe.read_bytes()
    probe.unlink()
    offset = struct.unpack_from("<I", data, 96)[0]
    rec = struct.unpack_from("<H", data, 105)[0]
    for cut in _boundaries(
        len(data), [4, 100, 226, 374, offset - 1, offset, offset + rec // 2, len(data) - rec, len(data) - 1]
    ):

        def trunc(d: Path, cut: int = cut) -> Invocation:
            p = las_file(d / f"cut{cut}.las")
            truncate(p, cut)
            return _cloud_cmd(d, p)

        cases.append(FuzzCase(f"las-truncated-{cut}", trunc, fast=cut == len(data) - rec))

    def patch(name: str, fmt: str, at: int, value: object) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            p = las_file(d / f"{name}.las")
            b = bytearray(p.read_bytes())
            struct.pack_into(fmt, b, at, value)
            p.write_bytes(bytes(b))
            return _cloud_cmd(d, p)

        return build

    # LAS 1.4: legacy point count at 107 (u32), point count at 247 (u64); scale x at 131 (f64); offset x at 155
    cases += [
        FuzzCase("las-count-larger-than-data", patch("more", "<Q", 247, 80), fast=True),
        FuzzCase("las-huge-count", patch("huge", "<Q", 247, 2**40)),
        FuzzCase("las-legacy-count-mismatch", patch("legacy", "<I", 107, 49)),
        FuzzCase("las-zero-scale", patch("scale0", "<d", 131, 0.0)),
        FuzzCase("las-nan-offset", patch("nanoff", "<d", 155, float("nan"))),
        FuzzCase("las-point-offset-past-end", patch("offpast", "<I", 96, 10_000_000)),
        FuzzCase("las-bad-record-length", patch("reclen", "<H", 105, 3)),
        FuzzCase("las-magic", patch("magic", "<4s", 0, b"LASX")),
    ]

    def laz_trunc(frac: float) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            p = las_file(d / "t.laz", n=3000)
            truncate(p, int(p.stat().st_size * frac))
            return _cloud_cmd(d, p)

        return build

    cases += [
        FuzzCase("laz-truncated-half", laz_trunc(0.5), fast=True),
        FuzzCase("laz-truncated-90pc", laz_trunc(0.9)),
        FuzzCase("laz-truncated-header", laz_trunc(0.05)),
    ]

    def empty(suffix: str) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            p = d / f"empty{suffix}"
            p.write_bytes(b"")
            return _cloud_cmd(d, p)

        return build

    def e57_trunc(frac: float) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            p = e57_file(d / "t.e57")
            truncate(p, int(p.stat().st_size * frac))
            return _cloud_cmd(d, p)

        return build

    def e57_garbage(d: Path) -> Invocation:
        p = d / "g.e57"
        p.write_bytes(b"ASTM-E57" + bytes(2000))
        return _cloud_cmd(d, p)

    cases += [
        FuzzCase("las-empty", empty(".las")),
        FuzzCase("laz-empty", empty(".laz")),
        FuzzCase("e57-empty", empty(".e57")),
        FuzzCase("e57-truncated-half", e57_trunc(0.5)),
        FuzzCase("e57-truncated-90pc", e57_trunc(0.9)),
        FuzzCase("e57-garbage", e57_garbage),
    ]
    return cases


# -- COLMAP models -----------------------------------------------------------------------------------------
def _colmap_cases() -> list[FuzzCase]:
    cases: list[FuzzCase] = []
    probe = colmap_model(Path("/tmp") / f".fuzz_colmap_probe_{id(cases)}")
    sizes = {n: (probe / f"{n}.bin").stat().st_size for n in ("cameras", "images", "points3D")}
    for f in probe.iterdir():
        f.unlink()
    probe.rmdir()
    marks = {
        "cameras": [4, 8, 8 + 12, 8 + 24, 8 + 40, sizes["cameras"] - 1],
        "images": [8, 8 + 30, 8 + 64, 8 + 70, sizes["images"] // 2, sizes["images"] - 1],
        "points3D": [8, 8 + 20, 8 + 52, sizes["points3D"] // 2, sizes["points3D"] - 1],
    }
    for name, cuts in marks.items():
        for cut in _boundaries(sizes[name], cuts):

            def trunc(d: Path, name: str = name, cut: int = cut) -> Invocation:
                m = colmap_model(d / "sparse")
                truncate(m / f"{name}.bin", cut)
                return _model_cmd(d, m, f"{name}.bin")

            fast = (name, cut) in (("cameras", sizes["cameras"] - 1), ("points3D", sizes["points3D"] // 2))
            cases.append(FuzzCase(f"colmap-{name}-truncated-{cut}", trunc, fast=fast))

    def patch(name: str, file: str, fmt: str, at: int, value: object) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            m = colmap_model(d / "sparse")
            p = m / file
            b = bytearray(p.read_bytes())
            struct.pack_into(fmt, b, at, value)
            p.write_bytes(bytes(b))
            return _model_cmd(d, m, file)

        return build

    cases += [
        FuzzCase("colmap-points3D-huge-count", patch("huge", "points3D.bin", "<Q", 0, 2**50)),
        FuzzCase("colmap-points3D-huge-track", patch("track", "points3D.bin", "<Q", 8 + 8 + 24 + 3 + 8, 2**40)),
        FuzzCase("colmap-cameras-unknown-model", patch("model", "cameras.bin", "<i", 8 + 4, 99)),
        FuzzCase("colmap-cameras-nan-focal", patch("nanf", "cameras.bin", "<d", 8 + 24, float("nan"))),
        FuzzCase("colmap-cameras-zero-width", patch("w0", "cameras.bin", "<Q", 8 + 8, 0)),
        FuzzCase("colmap-images-huge-count", patch("imgs", "images.bin", "<Q", 0, 2**33)),
        FuzzCase("colmap-images-unknown-camera", patch("cam", "images.bin", "<I", 8 + 4 + 56, 77)),
        FuzzCase("colmap-images-nan-pose", patch("pose", "images.bin", "<d", 8 + 4, float("nan"))),
    ]

    def missing(file: str) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            m = colmap_model(d / "sparse")
            (m / file).unlink()
            (m / file).mkdir()
            return _model_cmd(d, m, file)

        return build

    def text_edit(file: str, edit: Callable[[str], str]) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            m = colmap_model(d / "sparse", binary=False)
            p = m / file
            p.write_text(edit(p.read_text()))
            return _model_cmd(d, m, file)

        return build

    def drop_last_param(text: str) -> str:
        lines = text.splitlines()
        i = next(k for k, line in enumerate(lines) if line and not line.startswith("#"))
        lines[i] = " ".join(lines[i].split()[:-1])
        return "\n".join(lines) + "\n"

    def cut_half(text: str) -> str:
        return text[: len(text) // 2]

    cases += [
        FuzzCase("colmap-images-bin-is-folder", missing("images.bin")),
        FuzzCase("colmap-txt-cameras-missing-param", text_edit("cameras.txt", drop_last_param), fast=True),
        FuzzCase("colmap-txt-cameras-garbage", text_edit("cameras.txt", lambda t: t + "1 PINHOLE x y z\n")),
        FuzzCase("colmap-txt-images-truncated", text_edit("images.txt", cut_half)),
        FuzzCase("colmap-txt-points-truncated", text_edit("points3D.txt", cut_half)),
        FuzzCase("colmap-txt-points-nan", text_edit("points3D.txt", _nan_point)),
    ]

    def info_truncated(d: Path) -> Invocation:
        m = colmap_model(d / "sparse")
        truncate(m / "cameras.bin", 8 + 30)
        return Invocation(["info", str(m)], "cameras.bin")

    cases.append(FuzzCase("colmap-info-cameras-truncated", info_truncated))
    return cases


def _nan_point(text: str) -> str:
    lines = text.splitlines()
    i = next(k for k, line in enumerate(lines) if line and not line.startswith("#"))
    tok = lines[i].split()
    tok[1] = "nan"
    lines[i] = " ".join(tok)
    return "\n".join(lines) + "\n"


# -- images, masks, LPIPS weights, meshes, JSON ------------------------------------------------------------
def _eval_cases() -> list[FuzzCase]:
    cases: list[FuzzCase] = []

    def broken_photo(kind: str) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            renders, photos = image_pair(d)
            p = photos / "v0.png"
            if kind == "truncated":
                truncate(p, p.stat().st_size // 2)
            elif kind == "empty":
                p.write_bytes(b"")
            elif kind == "text":
                p.write_text("not an image")
            elif kind == "folder":
                p.unlink()
                p.mkdir()
            elif kind == "size":
                png(p, h=20, w=20)
            out = d / "out.json"
            return Invocation(
                ["eval", "images", str(renders), str(photos), "--no-lpips", "--json", str(out)], "v0.png", (out,)
            )

        return build

    for kind in ("truncated", "empty", "text", "folder", "size"):
        cases.append(FuzzCase(f"image-{kind}", broken_photo(kind), fast=kind == "truncated"))

    def broken_mask(kind: str) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            renders, photos = image_pair(d)
            masks = d / "masks"
            p = masks / "v0.png"
            if kind == "size":
                png(p, h=10, w=10)
            elif kind == "truncated":
                png(p)
                truncate(p, 30)
            out = d / "out.json"
            argv = [
                "eval",
                "images",
                str(renders),
                str(photos),
                "--masks",
                str(masks),
                "--no-lpips",
                "--json",
                str(out),
            ]
            return Invocation(argv, "v0.png", (out,))

        return build

    cases += [FuzzCase("mask-wrong-size", broken_mask("size")), FuzzCase("mask-truncated", broken_mask("truncated"))]

    def lpips(kind: str) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            renders, photos = image_pair(d)
            w = d / "lpips.npz"
            weights = {f"features.{i}.weight": np.zeros((4, 3, 3, 3), np.float32) for i in range(1)}
            np.savez(w, **weights)
            if kind == "truncated":
                truncate(w, w.stat().st_size // 2)
            elif kind == "empty":
                w.write_bytes(b"")
            elif kind == "notzip":
                w.write_bytes(b"PK\x03\x04" + bytes(100))
            elif kind == "pickle":
                np.save(d / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
                w = d / "obj.npy"
            out = d / "out.json"
            argv = ["eval", "images", str(renders), str(photos), "--lpips-weights", str(w), "--json", str(out)]
            return Invocation(argv, w.name, (out,))

        return build

    cases += [
        FuzzCase("lpips-truncated", lpips("truncated"), fast=True),
        FuzzCase("lpips-empty", lpips("empty")),
        FuzzCase("lpips-not-zip", lpips("notzip")),
        FuzzCase("lpips-wrong-shapes", lpips("shapes")),
        FuzzCase("lpips-pickle", lpips("pickle")),
    ]

    def mesh(kind: str) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            cloud = cloud_ply(d / "cloud.ply")
            m = d / "mesh.ply"
            idx = 7 if kind == "index" else 1
            coord = "nan" if kind == "nan" else "1"
            m.write_text(
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                f"0 0 0\n{coord} 0 0\n0 1 0\n3 0 {idx} 2\n"
            )
            out = d / "c2c.json"
            return Invocation(["eval", "c2c", str(cloud), str(m), "--json", str(out)], "mesh.ply", (out,))

        return build

    cases += [
        FuzzCase("mesh-face-index-out-of-range", mesh("index"), fast=True),
        FuzzCase("mesh-nan-vertex", mesh("nan")),
    ]

    def metrics(text: str) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            project = d / "project"
            (project / "eval").mkdir(parents=True)
            (project / "eval" / "metrics.json").write_text(text)
            out = project / "report"
            return Invocation(["report", str(project)], "metrics.json", (out / "report.json",))

        return build

    cases += [
        FuzzCase("metrics-wrong-types", metrics('{"products": {"mvs": {"c2c": {"mean": "big"}}}}'), fast=True),
        FuzzCase("metrics-product-list", metrics('{"products": {"mvs": [1, 2]}}')),
        FuzzCase("metrics-bare-nan", metrics('{"products": {"mvs": {"c2c": {"mean": NaN}}}}')),
        FuzzCase("metrics-not-json", metrics("{products")),
        FuzzCase("metrics-images-string", metrics('{"products": {"mvs": {"images": "none"}}}')),
    ]

    def manifest(text: str) -> Callable[[Path], Invocation]:
        def build(d: Path) -> Invocation:
            project = d / "project"
            project.mkdir()
            (project / "manifest.json").write_text(text)
            return Invocation(["report", str(project)], "manifest.json", (project / "report" / "report.json",))

        return build

    cases += [
        FuzzCase("manifest-stage-seconds-string", manifest('{"stages": {"mvs": {"seconds": "fast"}}}')),
        FuzzCase("manifest-stages-list", manifest('{"stages": [1, 2]}')),
    ]
    return cases


# -- output paths and usage -----------------------------------------------------------------------------------
def _output_cases() -> list[FuzzCase]:
    def out_is_folder(d: Path) -> Invocation:
        src = cloud_ply(d / "c.ply")
        out = d / "taken.ply"
        out.mkdir()
        return Invocation(["convert", str(src), "--out", str(out)], "taken.ply", ())

    def parent_is_file(d: Path) -> Invocation:
        src = cloud_ply(d / "c.ply")
        (d / "afile").write_text("x")
        out = d / "afile" / "g.ply"
        return Invocation(["convert", str(src), "--out", str(out)], "afile", ())

    def unwritable(d: Path) -> Invocation:
        src = cloud_ply(d / "c.ply")
        return Invocation(["convert", str(src), "--out", "/proc/hybridsplat_fuzz/g.ply"], "/proc/hybridsplat_fuzz", ())

    def export_second_fails(d: Path) -> Invocation:
        src = gaussian_ply(d / "g.ply")
        a = d / "out" / "a.ply"
        return Invocation(["export", str(src), "--out", str(a), "--out", "/proc/hybridsplat_fuzz/b.las"], "/proc", (a,))

    def export_second_is_folder(d: Path) -> Invocation:
        src = gaussian_ply(d / "g.ply")
        a, b = d / "out" / "a.splat", d / "out" / "b.las"
        b.mkdir(parents=True)
        return Invocation(["export", str(src), "--out", str(a), "--out", str(b)], "b.las", (a,))

    def render_out_is_file(d: Path) -> Invocation:
        m = colmap_model(d / "sparse")
        gs = gaussian_ply(d / "g.ply")
        out = d / "renders"
        out.write_text("a file")
        return Invocation(["render", str(gs), "--cameras", str(m), "--out", str(out)], "renders", ())

    def usage(argv: list[str], culprit: str) -> Callable[[Path], Invocation]:
        return lambda d: Invocation(argv, culprit, ())

    return [
        FuzzCase("out-is-folder", out_is_folder, fast=True),
        FuzzCase("out-parent-is-file", parent_is_file),
        FuzzCase("out-unwritable-proc", unwritable, fast=True),
        FuzzCase("export-second-output-fails", export_second_fails, fast=True),
        FuzzCase("export-second-output-is-folder", export_second_is_folder),
        FuzzCase("render-out-is-file", render_out_is_file),
        FuzzCase("usage-unknown-option", usage(["convert", "--bogus"], "--bogus"), fast=True),
        FuzzCase("usage-missing-argument", usage(["convert"], "cloud")),
        FuzzCase("usage-invalid-choice", usage(["convert", "x.ply", "--out", "y.ply", "--mode", "zz"], "zz")),
        FuzzCase("usage-bad-number", usage(["convert", "x.ply", "--out", "y.ply", "--k", "many"], "--k")),
        FuzzCase("usage-unknown-command", usage(["frobnicate"], "frobnicate")),
    ]


#: The subset that runs with the normal tests: one subprocess per file family of the issue; the others run
#: under `make fuzz` and, in-process, in tests/test_cli_errors.py. Bad input to the commands that compute
#: with torch (eval, render, train, mvs, view) is refused before torch is imported: tests/test_cli_no_torch.py.
FAST = frozenset(
    {
        "ply-xyz-as-lists",
        "las-count-larger-than-data",
        "laz-truncated-half",
        "colmap-info-cameras-truncated",
        "sidecar-folder",
        "gs-inf-scale",
        "export-second-output-fails",
        "metrics-wrong-types",
        "usage-unknown-option",
    }
)


def all_cases() -> list[FuzzCase]:
    """Every case, in a stable order (names are unique); ``fast`` set from :data:`FAST`."""
    cases = _ply_cases() + _gs_cases() + _las_cases() + _colmap_cases() + _eval_cases() + _output_cases()
    names = [c.name for c in cases]
    if len(names) != len(set(names)):
        raise ValueError("duplicate fuzz case names")
    return [FuzzCase(c.name, c.build, c.name in FAST, c.tags) for c in cases]
