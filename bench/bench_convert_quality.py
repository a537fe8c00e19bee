"""Benchmark: image quality of MVS → Gaussian conversion, ``paper`` (Eq. 1–4) against ``adaptive`` surfels.

A data_synth scene is generated (or read with ``--scene``); an ideal "fused MVS" cloud is built from its training
views: the true depth maps are back-projected on the pixels of textured (collaborative) materials, coloured from the
photos, and merged per voxel (voxel = ``--voxel-gsd`` × the scene's ground sample distance; colour = mean; the
visibility of a voxel = the views that saw it, as COLMAP's fused.ply.vis). Both conversions are rendered with
``fusion.render.render_gaussian_set`` at every training camera (and the held-out test cameras) and compared with the
photos by PSNR over the pixels of textured materials only (where MVS is expected to succeed).

    python bench/bench_convert_quality.py            # tabletop preset at 320×240, 24 views
    python bench/bench_convert_quality.py --quick    # tiny preset (96×72, 10 views)
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from core.pointcloud import PointCloud  # noqa: E402
from fusion.convert import ConvertOptions, convert_points  # noqa: E402


@dataclass
class Views:
    """Per view: name, photo (H, W, 3) uint8, mask of textured pixels (H, W) bool."""

    names: list[str]
    photos: list[np.ndarray]
    masks: list[np.ndarray]


def fused_cloud(scene, voxel: float, stride: int = 1) -> PointCloud:
    """Back-projected true depth on textured pixels of all training views, merged per voxel (mean colour)."""
    textured = np.array(scene.material_ids(collaborative=True))
    pts, cols, vids = [], [], []
    for k, view in enumerate(scene.train):
        depth = scene.depth("train", view.name)
        labels = scene.labels("train", view.name)
        photo = scene.image("train", view.name)
        rows, cs = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride]
        ok = (depth[rows, cs] > 0) & np.isin(labels[rows, cs], textured)
        pix = np.c_[cs[ok] + 0.5, rows[ok] + 0.5].astype(np.float64)  # pixel centres (COLMAP convention)
        pts.append(scene.train.unproject(view, pix, depth[rows, cs][ok].astype(np.float64)))
        cols.append(photo[rows[ok], cs[ok]].astype(np.float64))
        vids.append(np.full(ok.sum(), k))
    p, c, v = np.concatenate(pts), np.concatenate(cols), np.concatenate(vids)
    keys = np.floor(p / voxel).astype(np.int64)
    _, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    m = len(counts)
    mean = lambda a: np.stack([np.bincount(inv, a[:, j], m) for j in range(a.shape[1])], 1) / counts[:, None]  # noqa: E731
    pos, col = mean(p), mean(c)
    pairs = np.unique(np.c_[inv, v], axis=0)  # (voxel, view) pairs
    split = np.flatnonzero(np.diff(pairs[:, 0])) + 1
    vis = np.split(pairs[:, 1], split)
    return PointCloud(pos, origin=scene.train.origin, colors=np.rint(col).astype(np.uint8), visibility=vis)


def load_views(scene, split: str) -> Views:
    textured = np.array(scene.material_ids(collaborative=True))
    cams = scene.train if split == "train" else scene.test
    names, photos, masks = [], [], []
    for view in cams:
        names.append(view.name)
        photos.append(scene.image(split, view.name))
        masks.append((scene.depth(split, view.name) > 0) & np.isin(scene.labels(split, view.name), textured))
    return Views(names, photos, masks)


def psnr_masked(render: np.ndarray, photo: np.ndarray, mask: np.ndarray) -> float:
    """PSNR (dB) over masked pixels, images in [0, 1]."""
    err = ((render - photo.astype(np.float64) / 255.0) ** 2)[mask].mean()
    return float(10 * np.log10(1.0 / max(err, 1e-12)))


def evaluate(gs, scene, split: str, views: Views) -> float:
    from fusion.render import render_gaussian_set

    cams = scene.train if split == "train" else scene.test
    values = []
    for view, photo, mask in zip(cams, views.photos, views.masks, strict=True):
        if mask.sum() < 10:
            continue
        out = render_gaussian_set(gs, cams.camera_of(view), view, cameras_origin=cams.origin, background=(0, 0, 0))
        colour = out.colour.detach().cpu().numpy().astype(np.float64)
        values.append(psnr_masked(colour, photo, mask))
    return float(np.mean(values))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="tiny preset instead of a reduced tabletop")
    ap.add_argument("--scene", type=Path, help="an existing data_synth scene folder (skips generation)")
    ap.add_argument("--voxel-gsd", type=float, default=2.0, help="fused-cloud voxel in ground sample distances")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    from data_synth import generate_scene, load_scene

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        if args.scene is not None:
            root = args.scene
        elif args.quick:
            root = generate_scene("tiny", Path(tmp) / "scene", seed=args.seed)
        else:
            root = generate_scene(
                "tabletop",
                Path(tmp) / "scene",
                seed=args.seed,
                views=24,
                test_views=4,
                width=320,
                height=240,
                supersample=1,
            )
        scene = load_scene(root)
        t_gen = time.perf_counter() - t0
        cloud = fused_cloud(scene, voxel=args.voxel_gsd * scene.gsd_m)
        train, test = load_views(scene, "train"), load_views(scene, "test")
        print(
            f"bench_convert_quality: scene {scene.preset} ({len(scene.train)} train / {len(scene.test)} test views, "
            f"GSD {scene.gsd_m * 1000:.2f} mm, generated/read in {t_gen:.1f} s), fused cloud {len(cloud)} points "
            f"(voxel {args.voxel_gsd} GSD); load average {os.getloadavg()[0]:.1f}"
        )
        print(f"{'conversion':>34} {'PSNR train':>11} {'PSNR test':>10} {'median σ mm':>12} {'s':>6}")
        configs = [
            ("paper (Eq. 1-4)", "paper", ConvertOptions()),
            ("adaptive (defaults)", "adaptive", ConvertOptions()),
            ("adaptive tangent_scale 0.3", "adaptive", ConvertOptions(tangent_scale=0.3)),
            ("adaptive tangent_scale 0.6", "adaptive", ConvertOptions(tangent_scale=0.6)),
            ("adaptive thickness_ratio 1 (disc)", "adaptive", ConvertOptions(thickness_ratio=1.0)),
        ]
        results = {}
        for label, mode, opts in configs:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                t = time.perf_counter()
                res = convert_points(cloud, mode, opts)
                dt = time.perf_counter() - t
            gs = res.gaussians
            p_train = evaluate(gs, scene, "train", train)
            p_test = evaluate(gs, scene, "test", test) if len(scene.test) else float("nan")
            sigma = float(np.median(gs.scales[:, 0])) * 1000
            results[label] = p_train
            print(f"{label:>34} {p_train:11.2f} {p_test:10.2f} {sigma:12.3f} {dt:6.2f}", flush=True)
        gain = results["adaptive (defaults)"] - results["paper (Eq. 1-4)"]
        print(f"adaptive - paper at the training cameras: {gain:+.2f} dB (textured pixels only)")


if __name__ == "__main__":
    main()
