"""The GPU paths on an NVIDIA GPU (issue 32): COLMAP PatchMatch in ``recon.mvs``; gsplat against the CPU renderer.

CI never has a GPU, so this runs in two halves:

``device`` (on the GPU machine, with a CUDA build of pycolmap and gsplat importable)::

    python bench/bench_gpu_paths.py device [--workspace NAME=DIR[:HELD,...]] [--gaussians FILE --cameras DIR] --out OUT

For each undistorted dense workspace (``images/`` and ``sparse/``, as ``hybridsplat mvs`` leaves it; copied first,
the input is not touched): :func:`recon.mvs.compute_depth_maps_colmap` (our ``patch-match.cfg``: held-out photos are
no reference and no source) and :func:`recon.mvs.fuse`, timed; the geometric depth and normal maps are packed into
``OUT/NAME_maps.tar.xz`` to be fused and scored on the CPU (figures: ``OUT/patch_match.json``). The Gaussians (a
3DGS PLY or an SPZ) are rendered at four views of the COLMAP model in ``--cameras`` by the ``cpu`` and the ``gsplat``
backends: PSNR between the two renders, the largest difference, and the seconds per render of each (figures:
``OUT/renderers.json``). ``bench/run_gpu_paths.sh`` runs both on the machine, with the GPU tests.

``score`` (here, on the CPU)::

    python bench/bench_gpu_paths.py score --maps OUT/demo_maps.tar.xz --workspace DIR --scene SCENE

unpacks the maps into a copy of the workspace, fuses them with :func:`recon.mvs.fuse` (COLMAP's CPU fusion, the
options every run uses) and scores the fused cloud against the synthetic scene's ground truth beside the workspace's
own fused cloud (the CPU MVS), with :func:`bench_mvs.evaluate` (per material: accuracy in GSD, completeness at
3 GSD).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from recon.mvs import FusionOptions, MvsBackend, MvsOptions, compute_depth_maps_colmap, fuse  # noqa: E402
from recon.workspace import DenseWorkspace  # noqa: E402


def _parse_workspace(spec: str) -> tuple[str, Path, frozenset[str]]:
    name, _, rest = spec.partition("=")
    folder, _, held = rest.partition(":")
    return name, Path(folder), frozenset(h for h in held.split(",") if h)


def _copy_workspace(src: Path, dst: Path) -> DenseWorkspace:
    """images/ and sparse/ of an undistorted workspace, nothing computed from them."""
    dst.mkdir(parents=True)
    for sub in ("images", "sparse"):
        shutil.copytree(src / sub, dst / sub)
    ws = DenseWorkspace(dst)
    ws.make_dirs()
    return ws


def patch_match_on(
    name: str, src: Path, held_out: frozenset[str], out: Path, repeat: int = 1, pack_maps: bool = True
) -> dict:
    """COLMAP PatchMatch (``repeat`` times, each on a fresh copy of ``src``: the first run of a process pays CUDA's
    start-up) and fusion of the last run's maps; those maps packed into ``out/NAME_maps.tar.xz``."""
    seconds = []
    options = MvsOptions(backend=MvsBackend.COLMAP, held_out=held_out)
    for _ in range(repeat):
        ws = _copy_workspace(src, Path(tempfile.mkdtemp()) / name)
        report = compute_depth_maps_colmap(ws, options)
        seconds.append(round(report.seconds_depth, 2))
    t0 = time.perf_counter()
    points = fuse(ws, FusionOptions())
    seconds_fusion = time.perf_counter() - t0
    with tarfile.open(out / f"{name}_maps.tar.xz", "w:xz") if pack_maps else _Discard() as tar:
        for sub in ("depth_maps", "normal_maps"):
            for p in sorted((ws.stereo / sub).glob("*.geometric.bin")):
                tar.add(p, arcname=f"{sub}/{p.name}")
        for cfg in (ws.patch_match_cfg, ws.fusion_cfg):
            tar.add(cfg, arcname=cfg.name)
    return {
        "views": report.num_views,
        "image_sizes": sorted(set(map(tuple, report.image_sizes))),
        "seconds_patch_match": seconds,
        "seconds_per_view": round(seconds[-1] / max(report.num_views, 1), 3),
        "fused_points": int(points),
        "seconds_fusion_here": round(seconds_fusion, 2),
        "held_out": sorted(held_out),
        "warnings": report.warnings,
    }


class _Discard:
    def __enter__(self) -> _Discard:
        return self

    def __exit__(self, *exc) -> None:
        return None

    def add(self, *args, **kwargs) -> None:
        pass


def _load_gaussians(path: Path):
    if path.suffix == ".spz":
        from fusion.spz_format import read_spz

        return read_spz(path).to_gaussians()
    from core.io.gaussian_ply import read_gaussian_ply

    return read_gaussian_ply(path)


def compare_renderers(gaussians_path: Path, model: Path, num_views: int = 4) -> dict:
    """The same Gaussians through the ``cpu`` and ``gsplat`` backends at ``num_views`` views of a COLMAP model."""
    import torch

    from fusion.render.scene import render_gaussian_set
    from recon.model import from_reconstruction, read_reconstruction

    gaussians = _load_gaussians(gaussians_path)
    cameras = from_reconstruction(read_reconstruction(model))
    views = sorted(cameras, key=lambda v: v.name)
    picks = [views[i] for i in np.linspace(0, len(views) - 1, num_views).round().astype(int)]
    rows = []
    for view in picks:
        camera = cameras.camera_of(view)
        row: dict = {"view": view.name}
        images = {}
        for backend in ("cpu", "gsplat"):
            render_gaussian_set(gaussians, camera, view, cameras_origin=cameras.origin, backend=backend)  # warm-up
            if backend == "gsplat":
                torch.cuda.synchronize()
            t0 = time.perf_counter()
            result = render_gaussian_set(gaussians, camera, view, cameras_origin=cameras.origin, backend=backend)
            images[backend] = result.colour.detach().cpu().double().numpy()
            row[f"seconds_{backend}"] = round(time.perf_counter() - t0, 4)
            row[f"alpha_mean_{backend}"] = round(float(result.alpha.detach().cpu().double().mean()), 5)
        diff = images["gsplat"] - images["cpu"]
        row["psnr_db"] = round(float(10 * np.log10(1.0 / max(np.mean(diff**2), 1e-20))), 2)
        row["max_abs_diff"] = round(float(np.abs(diff).max()), 5)
        rows.append(row)
    return {"gaussians": len(gaussians), "views": rows}


def device(args: argparse.Namespace) -> None:
    import pycolmap
    import torch

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    figures: dict = {
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "pycolmap": pycolmap.__version__,
        "pycolmap_has_cuda": bool(getattr(pycolmap, "has_cuda", False)),
        "patch_match": {},
    }
    for name, folder, held in map(_parse_workspace, args.workspace or []):
        figures["patch_match"][name] = patch_match_on(name, folder, held, out, args.repeat, not args.no_maps)
        print(name, json.dumps(figures["patch_match"][name]), flush=True)
        (out / "patch_match.json").write_text(json.dumps(figures, indent=2))
    if args.gaussians:
        renders = compare_renderers(Path(args.gaussians), Path(args.cameras))
        print("renderers", json.dumps(renders), flush=True)
        (out / "renderers.json").write_text(json.dumps(renders, indent=2))


def score(args: argparse.Namespace) -> None:
    from bench_mvs import evaluate

    src = Path(args.workspace)
    ws = _copy_workspace(src, Path(tempfile.mkdtemp()) / "gpu")
    with tarfile.open(args.maps) as tar:
        tar.extractall(ws.stereo, filter="data")
    t0 = time.perf_counter()
    points = fuse(ws, FusionOptions())
    print(f"fused {points} points from the GPU maps in {time.perf_counter() - t0:.1f} s (CPU fusion)")
    gsd, rows_gpu = evaluate(Path(args.scene), ws.fused_ply)
    _, rows_cpu = evaluate(Path(args.scene), DenseWorkspace(src).fused_ply)
    head = f"{'acc GSD':>9}{'compl':>7}"
    print(f"{'material':<22}{'CPU MVS: pts':>14}{head}{'GPU PM: pts':>14}{head}")
    for a, b in zip(rows_cpu, rows_gpu, strict=True):
        print(
            f"{a.name:<22}{a.fused_points:>14}{a.median_c2c_gsd:>9.2f}{a.completeness:>7.3f}"
            f"{b.fused_points:>14}{b.median_c2c_gsd:>9.2f}{b.completeness:>7.3f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="mode", required=True)
    d = sub.add_parser("device", help="on the GPU machine")
    d.add_argument("--workspace", action="append", help="NAME=DIR[:HELD,...] (repeatable)")
    d.add_argument("--no-maps", action="store_true", help="do not pack the maps (large workspaces)")
    d.add_argument("--repeat", type=int, default=1, help="PatchMatch runs per workspace (timings of each)")
    d.add_argument("--gaussians", help="a 3DGS PLY or SPZ rendered by both backends")
    d.add_argument("--cameras", help="the COLMAP model whose views the Gaussians are rendered at")
    d.add_argument("--out", required=True)
    s = sub.add_parser("score", help="here, on the CPU")
    s.add_argument("--maps", required=True)
    s.add_argument("--workspace", required=True, help="the workspace the maps were computed on (with its fused.ply)")
    s.add_argument("--scene", required=True, help="the synthetic scene (scene.json, gt/)")
    args = parser.parse_args()
    device(args) if args.mode == "device" else score(args)


if __name__ == "__main__":
    main()
