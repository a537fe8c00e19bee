"""CPU MVS against exact synthetic ground truth (tests/test_recon_scene.py), fusion through pycolmap."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from test_recon_scene import TEXTURED, TEXTURELESS, Scene, make_scene, write_scene

from core.errors import ConfigError, ReconstructionError
from recon.mvs import MvsBackend, MvsOptions, fuse, resolve_backend, run_mvs
from recon.mvs_cpu import CpuMvsOptions, estimate_depth, geometric_filter, normals_from_depth, pixel_rays
from recon.mvs_cpu_options import MvsQuality
from recon.workspace import DenseWorkspace, import_dense_workspace, read_array, read_fused


@pytest.fixture(scope="module")
def scene() -> Scene:
    return make_scene(num_views=10, width=160, height=120)


def _gt_colmap_grid(depth_centres: np.ndarray) -> np.ndarray:
    """GT z-depth on COLMAP's dense grid (element (r, c) on the ray through (c, r)): mean of the 4 pixel centres
    around it, exact for planes; inf where any is background or at the border."""
    g = depth_centres
    out = np.full_like(g, np.inf)
    out[1:, 1:] = (g[1:, 1:] + g[:-1, 1:] + g[1:, :-1] + g[:-1, :-1]) / 4
    return out


def _gray(img: np.ndarray) -> np.ndarray:
    return (img.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)) / 255.0


def _pair_inputs(scene: Scene, ref: int, srcs: list[int]):
    views = list(scene.cameras)
    K = scene.cameras.camera_of(views[0]).K()
    ref_v = views[ref]
    m = [
        np.vstack([views[s].cam_from_world, [0, 0, 0, 1]])
        @ np.linalg.inv(np.vstack([ref_v.cam_from_world, [0, 0, 0, 1]]))
        for s in srcs
    ]
    return (
        _gray(scene.images[ref_v.name]),
        [_gray(scene.images[views[s].name]) for s in srcs],
        K,
        [K] * len(srcs),
        m,
        ref_v,
    )


@pytest.mark.parametrize("quality", list(MvsQuality))
def test_estimate_depth_matches_truth_on_textured_surfaces(scene: Scene, quality: MvsQuality):
    ref_img, src_imgs, K, Ks, rel, ref_v = _pair_inputs(scene, 0, [1, 9, 2, 8])
    gt = _gt_colmap_grid(scene.depths[ref_v.name])
    fin = np.isfinite(gt)
    depth_range = (0.7 * gt[fin].min(), 1.3 * gt[fin].max())
    est = estimate_depth(ref_img, src_imgs, K, Ks, rel, depth_range, CpuMvsOptions(quality=quality))
    mat = scene.materials[ref_v.name]
    tex = fin & (mat == TEXTURED)
    ok = tex & (est.depth > 0)
    assert ok.sum() / tex.sum() > 0.7  # most textured pixels get a depth
    rel_err = np.abs(est.depth[ok] - gt[ok]) / gt[ok]
    # 1 px of disparity is ~1.5 % of depth here (baseline ~2 m at ~4 m, f = 144 px): sub-pixel median required
    assert np.median(rel_err) < 0.006
    # the textureless slab is mostly rejected (no texture in the NCC window)
    slab = fin & (mat == TEXTURELESS)
    interior = slab & (np.abs(np.gradient(ref_img)[0]) + np.abs(np.gradient(ref_img)[1]) < 1e-6)
    assert (est.depth[interior] > 0).mean() < 0.3


def test_geometric_filter_keeps_consistent_and_rejects_corrupted(scene: Scene):
    views = list(scene.cameras)
    K = scene.cameras.camera_of(views[0]).K()
    depths = [
        np.where(np.isfinite(g := _gt_colmap_grid(scene.depths[v.name])), g, 0).astype(np.float32) for v in views[:3]
    ]
    T = [np.vstack([v.cam_from_world, [0, 0, 0, 1]]) for v in views[:3]]
    rel = [T[1] @ np.linalg.inv(T[0]), T[2] @ np.linalg.inv(T[0])]
    out, count = geometric_filter(depths[0], K, depths[1:], [K, K], rel, 1.0, 0.01, 1)
    valid = depths[0] > 0
    assert (out[valid] > 0).mean() > 0.6  # co-visible part of the view survives
    kept = out > 0
    np.testing.assert_allclose(out[kept], depths[0][kept], rtol=0.01)
    bad = depths[0].copy()
    bad[valid] *= 1.05  # 5 % wrong everywhere -> inconsistent with both sources
    out_bad, _ = geometric_filter(bad, K, depths[1:], [K, K], rel, 1.0, 0.01, 1)
    assert (out_bad > 0).mean() < 0.02


def test_normals_of_a_tilted_plane_are_analytic_and_face_the_camera():
    K = np.array([[100.0, 0, 40], [0, 100.0, 30], [0, 0, 1]])
    n_true = np.array([0.3, -0.2, -1.0])
    n_true /= np.linalg.norm(n_true)
    rays = pixel_rays(K, 60, 80).numpy().astype(np.float64)
    d0 = 5.0  # plane n·X = -d0  ->  z = -d0 / (n·ray)
    depth = (-d0 / (rays @ n_true)).astype(np.float32)
    normals = normals_from_depth(depth, K, radius=2)
    err = np.degrees(np.arccos(np.clip(normals.reshape(-1, 3) @ n_true, -1, 1)))
    assert np.median(err) < 0.1 and err.max() < 1.0
    assert np.all((normals.reshape(-1, 3) * (rays.reshape(-1, 3) * depth.reshape(-1, 1))).sum(1) < 0)


def test_cpu_mvs_and_fusion_end_to_end(scene: Scene, tmp_path: Path):
    write_scene(scene, tmp_path, num_points=600)
    opts = MvsOptions(
        backend=MvsBackend.CPU, max_image_size=120, num_threads=1, cpu=CpuMvsOptions(geom_min_consistent=1)
    )
    report = run_mvs(tmp_path / "sparse" / "0", tmp_path / "images", tmp_path / "dense", opts)
    assert report.num_views == 10 and report.num_points > 1000
    ws = DenseWorkspace(tmp_path / "dense")
    assert ws.fused_ply.is_file() and ws.fused_vis.is_file()
    cloud = read_fused(ws.root)
    assert len(cloud) == report.num_points and cloud.visibility is not None
    ids = {v.image_id for v in scene.cameras}
    assert all(set(v.tolist()) <= ids for v in cloud.visibility)
    assert np.median([len(v) for v in cloud.visibility]) >= 3  # min_num_pixels = 3 agreeing pixels
    gsd = 4.0 / 108  # metres per pixel at the typical 4 m viewing distance (120 px wide, f = 108 px)
    d, idx = cKDTree(scene.gt_points).query(cloud.positions)
    tex = scene.gt_material[idx] == TEXTURED
    assert np.median(d[tex]) < 1.0 * gsd
    dd, _ = cKDTree(cloud.positions).query(scene.gt_points[scene.gt_material == TEXTURED])
    assert np.mean(dd < 3 * gsd) > 0.4  # 10 low-res views of an orbit: not every surface is seen by 3
    # normals written by our MVS are unit length and face the cameras that see the points
    n = read_array(ws.normal_map(next(iter(scene.cameras)).name))
    lens = np.linalg.norm(n.reshape(-1, 3), axis=1)
    assert np.allclose(lens[lens > 0], 1.0, atol=1e-4)
    # import of an existing dense workspace: copied, validated, same cloud
    imported = import_dense_workspace(ws.root, tmp_path / "imported")
    again = read_fused(imported.root)
    np.testing.assert_array_equal(again.positions, cloud.positions)
    assert [v.tolist() for v in again.visibility] == [v.tolist() for v in cloud.visibility]


def test_fusion_is_deterministic(scene: Scene, tmp_path: Path):
    write_scene(scene, tmp_path, num_points=300)
    small = MvsOptions(
        backend=MvsBackend.CPU, max_image_size=80, cpu=CpuMvsOptions(coarse_size=40, geom_min_consistent=1)
    )
    run_mvs(tmp_path / "sparse" / "0", tmp_path / "images", tmp_path / "dense", small)
    first = (tmp_path / "dense" / "fused.ply").read_bytes()
    n_again = fuse(tmp_path / "dense", small.fusion)
    assert (tmp_path / "dense" / "fused.ply").read_bytes() == first and n_again > 0


def test_import_rejects_non_workspace(tmp_path: Path):
    from core.errors import InputFileError

    with pytest.raises(InputFileError, match="not a COLMAP dense workspace"):
        import_dense_workspace(tmp_path, tmp_path / "dst")
    (tmp_path / "sparse").mkdir()
    (tmp_path / "images").mkdir()
    with pytest.raises(InputFileError, match="neither fused.ply"):
        import_dense_workspace(tmp_path, tmp_path / "dst")


def test_colmap_backend_probe():
    import pycolmap

    if pycolmap.has_cuda:
        pytest.skip("pycolmap has CUDA here: the 'not available' path cannot be exercised")
    with pytest.raises(ConfigError, match="CUDA"):
        resolve_backend("colmap")
    assert resolve_backend("auto") is MvsBackend.CPU


def test_model_without_points_is_a_clear_error(scene: Scene, tmp_path: Path):
    from recon.model import to_reconstruction

    write_scene(scene, tmp_path, num_points=50)
    to_reconstruction(scene.cameras).write(str(tmp_path / "sparse" / "0"))  # cameras only, no points
    with pytest.raises(ReconstructionError, match="no 3D points"):
        run_mvs(tmp_path / "sparse" / "0", tmp_path / "images", tmp_path / "dense", MvsOptions(backend=MvsBackend.CPU))
