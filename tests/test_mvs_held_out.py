"""Held-out photos are kept out of every depth estimate, on every MVS backend (issue 32).

A held-out photo is registered and undistorted (evaluation renders at its pose) but it is no reference (no depth or
normal map), no source of another photo's depth and not fused; the classifier's multi-view features never see its
camera, photo or any depth map of its name. Proof: the same dense run with the held-out photo's pixels replaced by
noise (its camera unchanged) gives bit-identical maps and fused cloud. COLMAP PatchMatch (CUDA) is steered through an
explicit ``stereo/patch-match.cfg``; its writer and reader are tested here without a GPU, and the same contract runs on
COLMAP where pycolmap has CUDA.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest
from test_recon_scene import Scene, make_scene, write_scene

from classify.features.multiview import multiview_features, views_from_workspace
from core.errors import FormatError, ReconstructionError
from recon.mvs import MvsBackend, MvsOptions, run_mvs
from recon.mvs_colmap import COLMAP_NUM_SOURCES, colmap_available, patch_match_problems
from recon.mvs_cpu import normals_from_depth
from recon.mvs_cpu_options import CpuMvsOptions
from recon.view_selection import select_views
from recon.workspace import (
    DenseWorkspace,
    read_array,
    read_fused,
    read_patch_match_cfg,
    setup_dense_workspace,
    write_array,
)

SIZE = (96, 72)  # (width, height) of the photos, px: the whole contract runs in seconds on 2 cores
HELD = "img_002.png"  # a held-out photo that the view selection would otherwise pick as a source (asserted below)
NEEDS_CUDA = "needs a CUDA GPU (pycolmap built with CUDA) for COLMAP PatchMatch"


@pytest.fixture(scope="module")
def scene() -> Scene:
    """8 views of an orbit around textured boxes (analytic, exact depths), 96 × 72 px."""
    return make_scene(num_views=8, width=SIZE[0], height=SIZE[1])


@pytest.fixture(scope="module")
def inputs(scene: Scene, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """images/ (clean), images_noise/ (HELD replaced by uniform noise of its size) and sparse/0 (true cameras,
    ground-truth points with tracks)."""
    root = tmp_path_factory.mktemp("held_out")
    write_scene(scene, root, num_points=300)
    shutil.copytree(root / "images", root / "images_noise")
    noise = np.random.default_rng(7).integers(0, 256, (SIZE[1], SIZE[0], 3), dtype=np.uint8)
    cv2.imwrite(str(root / "images_noise" / HELD), noise)
    return root


def _options(backend: MvsBackend) -> MvsOptions:
    """Small, single-threaded options: deterministic CPU MVS and fusion."""
    cpu = CpuMvsOptions(coarse_size=48, geom_min_consistent=1, num_sources=4)
    return MvsOptions(backend=backend, max_image_size=SIZE[0], num_threads=1, cpu=cpu, held_out=frozenset({HELD}))


def _run_pair(root: Path, backend: MvsBackend) -> tuple[DenseWorkspace, DenseWorkspace]:
    """The dense run on the clean photos and on the photos with HELD's pixels replaced by noise (same cameras)."""
    out = []
    for images, dense in (("images", "dense_clean"), ("images_noise", "dense_noise")):
        run_mvs(root / "sparse" / "0", root / images, root / f"{dense}_{backend.value}", _options(backend))
        out.append(DenseWorkspace(root / f"{dense}_{backend.value}"))
    return out[0], out[1]


def _map_files(ws: DenseWorkspace) -> dict[str, bytes]:
    """Every depth and normal map file of the workspace (relative path → bytes)."""
    stereo = ws.stereo
    return {
        str(p.relative_to(stereo)): p.read_bytes()
        for sub in ("depth_maps", "normal_maps")
        for p in sorted((stereo / sub).glob("*.bin"))
    }


def _assert_held_out_changes_nothing(clean: DenseWorkspace, noisy: DenseWorkspace, names: list[str]) -> None:
    """The contract: HELD's pixels differ between the runs (its camera does not), nothing else does."""
    assert not np.array_equal(cv2.imread(str(clean.images / HELD)), cv2.imread(str(noisy.images / HELD)))
    for f in ("cameras.bin", "images.bin"):  # the held-out photo's camera and pose: unchanged
        assert (clean.sparse / f).read_bytes() == (noisy.sparse / f).read_bytes()
    maps = _map_files(clean)
    assert maps, "the run wrote no depth map"
    assert not [k for k in maps if Path(k).name.startswith(HELD)], "a map was computed for the held-out photo"
    assert {Path(k).name.split(".png.")[0] + ".png" for k in maps} == {n for n in names if n != HELD}
    other = _map_files(noisy)
    assert sorted(maps) == sorted(other)
    changed = [k for k in maps if maps[k] != other[k]]
    assert not changed, f"the held-out photo's pixels changed {len(changed)} maps (first: {changed[0]})"
    assert clean.fused_ply.read_bytes() == noisy.fused_ply.read_bytes()
    assert clean.fused_vis.read_bytes() == noisy.fused_vis.read_bytes()
    assert HELD not in (clean.fused_names() or [])


# -- COLMAP's patch-match.cfg: writer and reader -------------------------------------------------------------
def test_patch_match_cfg_format_round_trips_as_colmap_reads_it(tmp_path: Path):
    ws = DenseWorkspace(tmp_path)
    ws.make_dirs()
    ws.write_patch_match_cfg({"a.png": ["b.png", "c.png"], "b.png": ["a.png"], "c.png": ["a.png", "b.png"]})
    assert ws.patch_match_cfg.read_text() == "a.png\nb.png, c.png\nb.png\na.png\nc.png\na.png, b.png\n"
    assert read_patch_match_cfg(ws.patch_match_cfg) == [
        ("a.png", ["b.png", "c.png"]),
        ("b.png", ["a.png"]),
        ("c.png", ["a.png", "b.png"]),
    ]
    # COLMAP's own spellings (src/colmap/mvs/patch_match.h, ReadProblems): comments, blank lines, ';', a trailing
    # ", " (its PMVS importer writes one), CRLF, keywords kept as written; a dangling reference is ignored.
    ws.patch_match_cfg.write_text(
        "# comment\r\n a.png \r\n\r\n__all__\nb.png\n__auto__, 20\nc.png\na.png;b.png, \n\nd.png\n", encoding="utf-8"
    )
    assert read_patch_match_cfg(ws.patch_match_cfg) == [
        ("a.png", ["__all__"]),
        ("b.png", ["__auto__", "20"]),
        ("c.png", ["a.png", "b.png"]),
    ]


@pytest.mark.parametrize(
    "problems",
    [
        {"a,b.png": ["c.png"]},
        {"a.png": ["b;c.png"]},
        {"#a.png": ["b.png"]},
        {" a.png": ["b.png"]},
        {"a.png": []},  # COLMAP would read the next reference's name as this one's sources
        {"a.png": ["__all__"]},
    ],
    ids=["comma", "semicolon", "hash", "space", "no-sources", "keyword"],
)
def test_patch_match_cfg_refuses_what_colmap_would_misread(tmp_path: Path, problems: dict[str, list[str]]):
    ws = DenseWorkspace(tmp_path)
    ws.make_dirs()
    with pytest.raises(FormatError, match="patch-match.cfg"):
        ws.write_patch_match_cfg(problems)
    assert not ws.patch_match_cfg.exists()


def test_patch_match_cfg_keeps_held_out_photos_out(inputs: Path):
    """The cfg the COLMAP backend writes for 8 photos, one held out: 7 references, explicit sources from the CPU
    backend's view selection, the held-out photo nowhere; COLMAP's undistorter default (``__auto__, 20``) would have
    made it a reference and, by shared points, a source of its neighbours."""
    ws = setup_dense_workspace(inputs / "sparse" / "0", inputs / "images", inputs / "dense_cfg", SIZE[0])
    names = sorted(p.name for p in (inputs / "images").iterdir())
    assert read_patch_match_cfg(ws.patch_match_cfg) == [(n, ["__auto__", str(COLMAP_NUM_SOURCES)]) for n in names]
    rec = pycolmap.Reconstruction(str(ws.sparse))
    held_id = next(int(i) for i in rec.reg_image_ids() if rec.image(i).name == HELD)
    unrestricted = select_views(rec, num_sources=COLMAP_NUM_SOURCES)
    assert any(held_id in srcs for srcs in unrestricted.sources.values()), "HELD would not be a source anyway"

    problems = patch_match_problems(rec, {HELD})
    ws.write_patch_match_cfg(problems)
    parsed = read_patch_match_cfg(ws.patch_match_cfg)
    assert [ref for ref, _ in parsed] == [n for n in names if n != HELD]  # image-id order
    assert all(HELD not in srcs and ref not in srcs and srcs for ref, srcs in parsed)
    refs = {ref for ref, _ in parsed}
    assert all(set(srcs) <= refs for _, srcs in parsed)  # the geometric pass reads each source's photometric map
    chosen = select_views(rec, num_sources=COLMAP_NUM_SOURCES, exclude=frozenset({held_id}))
    assert dict(parsed) == {rec.image(r).name: [rec.image(s).name for s in chosen.sources[r]] for r in chosen.sources}


def test_colmap_backend_runs_the_cfg_it_wrote(inputs: Path, scene: Scene, monkeypatch: pytest.MonkeyPatch):
    """The COLMAP backend's steps without a GPU: a stand-in PatchMatch parses the cfg present when it is called, as
    COLMAP would, reads only the photos of its problems and writes ground-truth maps for the references."""
    import recon.mvs

    seen: dict[str, object] = {}

    def fake_patch_match(dense_dir: str | Path, max_image_size: int = -1, **_: object) -> None:
        ws = DenseWorkspace(Path(dense_dir))
        problems = read_patch_match_cfg(ws.patch_match_cfg)
        seen["problems"] = problems
        seen["read"] = {n for ref, srcs in problems for n in [ref, *srcs]}
        for ref, _srcs in problems:
            view = scene.cameras.by_name(ref)
            K = scene.cameras.camera_of(view).K()
            g = scene.depths[ref]  # z-depth at pixel centres; COLMAP's grid is the mean of the 4 around (exact: planes)
            grid = np.full_like(g, np.inf)
            grid[1:, 1:] = (g[1:, 1:] + g[:-1, 1:] + g[1:, :-1] + g[:-1, :-1]) / 4
            depth = np.where(np.isfinite(grid), grid, 0.0).astype(np.float32)
            write_array(ws.depth_map(ref), depth)
            write_array(ws.normal_map(ref), normals_from_depth(depth, K, 2))

    monkeypatch.setattr(recon.mvs, "colmap_available", lambda: True)
    monkeypatch.setattr(recon.mvs, "run_patch_match", fake_patch_match)
    report = run_mvs(inputs / "sparse" / "0", inputs / "images", inputs / "dense_fake", _options(MvsBackend.COLMAP))
    ws = DenseWorkspace(inputs / "dense_fake")
    assert report.backend == "colmap" and report.num_views == 7 and report.num_points > 0
    assert HELD not in seen["read"] and len(seen["read"]) == 7
    assert ws.fused_names() == [ref for ref, _ in seen["problems"]]
    assert not list(ws.stereo.glob(f"*/{HELD}.*"))


def test_colmap_backend_needs_two_photos_with_sources(inputs: Path, monkeypatch: pytest.MonkeyPatch):
    import recon.mvs

    monkeypatch.setattr(recon.mvs, "colmap_available", lambda: True)
    names = {p.name for p in (inputs / "images").iterdir()}
    opts = MvsOptions(backend=MvsBackend.COLMAP, max_image_size=SIZE[0], held_out=frozenset(names - {HELD}))
    with pytest.raises(ReconstructionError, match="at least 2 photos with source photos"):
        run_mvs(inputs / "sparse" / "0", inputs / "images", inputs / "dense_one", opts)


# -- the contract on every backend ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cpu_pair(inputs: Path) -> tuple[DenseWorkspace, DenseWorkspace]:
    return _run_pair(inputs, MvsBackend.CPU)


def test_cpu_held_out_pixels_change_no_depth_map_nor_fused_point(
    inputs: Path, cpu_pair: tuple[DenseWorkspace, DenseWorkspace]
):
    names = sorted(p.name for p in (inputs / "images").iterdir())
    _assert_held_out_changes_nothing(*cpu_pair, names)
    assert len(read_fused(cpu_pair[0].root)) > 500


@pytest.mark.gpu
@pytest.mark.skipif(not colmap_available(), reason=NEEDS_CUDA)
def test_colmap_held_out_pixels_change_no_depth_map_nor_fused_point(inputs: Path):
    """Bit-identical is expected: COLMAP's PatchMatch seeds its per-pixel random states by pixel index and sweeps
    rows without atomics, and fusion runs single-threaded (FusionOptions.deterministic)."""
    clean, noisy = _run_pair(inputs, MvsBackend.COLMAP)
    names = sorted(p.name for p in (inputs / "images").iterdir())
    assert read_patch_match_cfg(clean.patch_match_cfg)  # ours, not the undistorter's "__auto__, 20"
    assert all(HELD not in [ref, *srcs] for ref, srcs in read_patch_match_cfg(clean.patch_match_cfg))
    _assert_held_out_changes_nothing(clean, noisy, names)


# -- the classifier's multi-view features -------------------------------------------------------------------------
def test_multiview_features_never_read_a_held_out_photo(
    cpu_pair: tuple[DenseWorkspace, DenseWorkspace], tmp_path: Path
):
    """Neither the held-out photo's camera, pixels nor a depth map of its name (as COLMAP wrote before issue 32)
    changes a feature, with or without the visibility lists (without them every frustum view's photo is read)."""
    clean, noisy = cpu_pair
    stale = DenseWorkspace(tmp_path / "stale")
    shutil.copytree(noisy.root, stale.root)
    h, w = read_array(clean.depth_map("img_001.png")).shape
    write_array(stale.depth_map(HELD), np.full((h, w), 0.5, np.float32))  # a wrong depth map under its name
    write_array(stale.normal_map(HELD), np.dstack([np.zeros((h, w, 2)), -np.ones((h, w))]))
    cloud = read_fused(clean.root)
    views = views_from_workspace(clean.root)
    assert HELD not in {v.name for v in views.cameras} and len(views.cameras) == 7
    with pytest.raises(KeyError, match="not a photo of the dense reconstruction"):
        views.image(HELD)
    for visibility in (cloud.visibility, None):
        ref = multiview_features(cloud.positions, visibility, views)
        for ws in (noisy, stale):
            got = multiview_features(cloud.positions, visibility, views_from_workspace(ws.root))
            for name, values in ref.items():
                np.testing.assert_array_equal(got[name], values, err_msg=f"{name} ({ws.root.name})")
    # Sensitivity: a workspace without fusion.cfg takes every registered photo, and the noise then shows.
    stale.fusion_cfg.unlink()
    leaky = multiview_features(cloud.positions, None, views_from_workspace(stale.root))
    assert not all(np.array_equal(leaky[n], ref[n]) for n in ref)
