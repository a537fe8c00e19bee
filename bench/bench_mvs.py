"""Benchmark of the CPU MVS on a data_synth scene (tabletop by default), known poses.

Prints, per ``max_image_size``: time per view and per megapixel, fused points, and per material the fused
cloud's accuracy (median distance to the GT mesh and C2C to the GT LiDAR cloud, in GSD) and completeness
(share of GT LiDAR points with a fused point within 3 GSD), with ratios against the largest size.
Optionally (``--sfm``) full SfM without known poses, aligned to the true camera centres.

    python bench/bench_mvs.py [--quick] [--scene DIR] [--sizes 320,480,640] [--sfm]

With ``--before REV`` each size runs twice in one process, with ``recon/mvs_cpu.py`` of git revision REV
("before", e.g. the torch-only MVS of ``bench_mvs_profile.BEFORE_REV``) and with today's ("after"), and prints
their seconds per view, the fused cloud's C2C mean (fused -> GT LiDAR, all points) and completeness at τ (GT LiDAR
points with a fused point within ``--tau-gsd`` GSD), with the ratios after / before:

    python bench/bench_mvs.py --scene /tmp/demo29/scene --sizes 320 --before 4a92792

Real photos without ground truth: ``--workspace DIR`` reruns the depth maps and fusion of an existing dense
workspace (a copy of it, in ``--work``) before and after and prints seconds per view and fused points:

    python bench/bench_mvs.py --workspace /tmp/fountain/dense --held-out 0003.jpg,0007.jpg --before 4a92792

The scene is generated with ``data_synth.generate_scene`` into ``--cache`` when ``--scene`` is not given.
Timings on a shared machine are noisy; the MVS runs with ``--threads`` torch threads.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from types import ModuleType

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from core.io.ply import read_ply  # noqa: E402
from hybridsplat.layout import ProjectLayout  # noqa: E402
from recon.align import align_reconstruction_to_centers  # noqa: E402
from recon.model import from_reconstruction, read_reconstruction  # noqa: E402
from recon.mvs import MvsBackend, MvsOptions, MvsReport, run_mvs  # noqa: E402
from recon.mvs_cpu import CpuMvsOptions  # noqa: E402
from recon.sfm import SfmOptions, run_sfm, triangulate_known_poses  # noqa: E402
from recon.workspace import DenseWorkspace  # noqa: E402


@dataclass
class MaterialScore:
    name: str
    collaborative: bool
    fused_points: int
    median_mesh_gsd: float  # fused -> GT mesh, median, in GSD
    median_c2c_gsd: float  # fused -> GT LiDAR cloud, median, in GSD
    completeness: float  # GT LiDAR points with a fused point within tau


def evaluate(scene: Path, fused_ply: Path, tau_gsd: float = 3.0) -> tuple[float, list[MaterialScore]]:
    """Per-material accuracy and completeness of a fused cloud against the scene's ground truth."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    meta = json.loads((scene / "scene.json").read_text())
    gsd = float(meta["gsd_m"])
    gt = read_ply(scene / "gt" / "lidar.ply")
    fused = read_ply(fused_ply).with_origin(gt.origin)
    mat_gt = np.asarray(gt.fields["material"]).astype(int)
    mesh = o3d.t.geometry.TriangleMesh.from_legacy(o3d.io.read_triangle_mesh(str(scene / "gt" / "mesh.ply")))
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(mesh)
    mesh_origin = np.zeros(3)  # gt/mesh.ply is in the local frame; its sidecar (if any) gives the offset
    side = scene / "gt" / "mesh.origin.json"
    if side.is_file():
        mesh_origin = np.asarray(json.loads(side.read_text())["origin"], dtype=np.float64)
    q = (fused.positions + fused.origin - mesh_origin).astype(np.float32)
    d_mesh = rc.compute_distance(o3d.core.Tensor(q)).numpy() if len(q) else np.zeros(0)
    tree_gt = cKDTree(gt.positions)
    d_c2c, idx = tree_gt.query(fused.positions) if len(fused) else (np.zeros(0), np.zeros(0, int))
    mat_fused = mat_gt[idx] if len(fused) else np.zeros(0, int)
    d_back, _ = cKDTree(fused.positions).query(gt.positions) if len(fused) else (np.full(len(gt), np.inf), None)
    scores = []
    for m in meta["materials"]:
        sel_f = mat_fused == m["id"]
        sel_g = mat_gt == m["id"]
        if not sel_g.any():
            continue
        scores.append(
            MaterialScore(
                m["name"],
                bool(m["collaborative"]),
                int(sel_f.sum()),
                float(np.median(d_mesh[sel_f]) / gsd) if sel_f.any() else float("nan"),
                float(np.median(d_c2c[sel_f]) / gsd) if sel_f.any() else float("nan"),
                float(np.mean(d_back[sel_g] < tau_gsd * gsd)),
            )
        )
    return gsd, scores


@dataclass
class CloudScore:
    """Whole-cloud figures of a fused cloud against the GT LiDAR cloud (metres)."""

    points: int
    c2c_mean_m: float  # fused -> GT LiDAR, mean over all fused points
    completeness: float  # GT LiDAR points with a fused point within tau
    tau_m: float


def cloud_score(scene: Path, fused_ply: Path, tau_gsd: float = 3.0) -> CloudScore:
    """C2C mean and completeness at ``tau_gsd`` GSD of a fused cloud (``eval.c2c.compare_clouds``)."""
    from eval.c2c import compare_clouds

    gsd = float(json.loads((scene / "scene.json").read_text())["gsd_m"])
    fused = read_ply(fused_ply)
    result = compare_clouds(fused, read_ply(scene / "gt" / "lidar.ply"), tau=tau_gsd * gsd)
    return CloudScore(len(fused), result.stats.mean, result.scores.recall, tau_gsd * gsd)


@contextmanager
def mvs_module(module: ModuleType | None) -> Iterator[None]:
    """``recon.mvs`` imports the CPU MVS as ``recon.mvs_cpu`` when it runs: this block gives it ``module``."""
    if module is None:
        yield
        return
    import recon.mvs_cpu

    sys.modules["recon.mvs_cpu"] = module
    try:
        yield
    finally:
        sys.modules["recon.mvs_cpu"] = recon.mvs_cpu


def compare_before_after(scene: Path, sparse: Path, work: Path, size: int, opts, before: ModuleType, tau_gsd: float):
    """One size with the 'before' module and with today's, on the same model; prints both and their ratios."""
    rows = {}
    from bench_mvs_profile import BEFORE_EFFORT

    before_opts = replace(opts, cpu=replace(opts.cpu, **BEFORE_EFFORT))
    for name, module, run_opts in (("before", before, before_opts), ("after", None, opts)):
        dense = DenseWorkspace(work / f"dense_{size}_{name}")
        with mvs_module(module):
            report = run_mvs(sparse, scene / "images", dense.root, run_opts)
        rows[name] = (report, cloud_score(scene, dense.fused_ply, tau_gsd))
    gsd = float(json.loads((scene / "scene.json").read_text())["gsd_m"])
    print(f"\nmax_image_size {size}, before/after (load {os.getloadavg()[0]:.2f}):")
    print(f"  {'':<8}{'s/view':>8}{'points':>9}{'C2C mean mm':>13}{'C2C GSD':>9}{'compl@tau':>11}")
    for name, (rep, sc) in rows.items():
        print(
            f"  {name:<8}{rep.seconds_per_view:>8.3f}{sc.points:>9}{sc.c2c_mean_m * 1000:>13.3f}"
            f"{sc.c2c_mean_m / gsd:>9.3f}{sc.completeness:>11.4f}"
        )
    (rb, sb), (ra, sa) = rows["before"], rows["after"]
    print(
        f"  after/before: time x{ra.seconds_per_view / rb.seconds_per_view:.3f} (speed-up "
        f"{rb.seconds_per_view / ra.seconds_per_view:.2f}x), C2C mean x{sa.c2c_mean_m / sb.c2c_mean_m:.3f}, "
        f"completeness {sa.completeness - sb.completeness:+.4f} (tau {sa.tau_m * 1000:.2f} mm)"
    )


def _maps_and_outputs(folder: str, names: list[str]) -> list[str]:
    """What a copy of a dense workspace leaves out: depth and normal maps (under stereo/), fused cloud, logs."""
    in_stereo = "stereo" in Path(folder).parts
    fused = DenseWorkspace(Path(folder)).fused_ply.name
    return [n for n in names if (in_stereo and n.endswith(".bin")) or n.startswith(fused) or n.endswith(".log")]


def compare_on_workspace(workspace: Path, held_out: frozenset[str], work: Path, cpu, threads: int, before) -> None:
    """Depth maps, filter and fusion of a copy of a dense workspace with the 'before' module and with today's."""
    import shutil

    from bench_mvs_profile import BEFORE_EFFORT

    from recon.mvs import compute_depth_maps_cpu, fuse

    print(f"{workspace}, held out {sorted(held_out)}:")
    for name, module, opts in (("before", before, replace(cpu, **BEFORE_EFFORT)), ("after", None, cpu)):
        copy = work / f"workspace_{name}"
        shutil.rmtree(copy, ignore_errors=True)
        shutil.copytree(workspace, copy, ignore=_maps_and_outputs)
        options = MvsOptions(backend=MvsBackend.CPU, num_threads=threads, cpu=opts, held_out=held_out)
        with mvs_module(module):
            report = compute_depth_maps_cpu(DenseWorkspace(copy), options)
        points = fuse(copy, options.fusion, log_path=copy / "fusion.log")
        print(
            f"  {name:<7}{report.seconds_per_view:>8.2f} s/view ({report.num_views} views, depth "
            f"{report.seconds_depth:.1f} s + geometric {report.seconds_geometric:.1f} s), {points} fused points "
            f"(load {os.getloadavg()[0]:.2f})"
        )


def _ensure_scene(args) -> Path:
    if args.scene:
        return Path(args.scene)
    out = Path(args.cache) / args.preset
    if not (out / "scene.json").is_file():
        from data_synth.generate import generate_scene

        print(f"generating {args.preset} into {out} ...", flush=True)
        generate_scene(args.preset, out, seed=0, overwrite=True)
    return out


def _parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="one size (320 px) only")
    ap.add_argument("--scene", help="data_synth scene folder (default: generate --preset into --cache)")
    ap.add_argument("--preset", default="tabletop")
    ap.add_argument("--cache", default="/tmp/hybridsplat_bench")
    ap.add_argument("--sizes", default="320,480,640", help="max_image_size values to compare")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--sfm", action="store_true", help="also run full SfM (no known poses) and align to the truth")
    ap.add_argument("--work", default="/tmp/hybridsplat_bench/work")
    ap.add_argument("--reuse", action="store_true", help="reuse a known-pose model already in --work")
    ap.add_argument("--no-mvs", action="store_true", help="skip the MVS sizes (with --sfm: SfM only)")
    ap.add_argument("--before", help="also run recon/mvs_cpu.py of this git revision and compare (see above)")
    ap.add_argument("--tau-gsd", type=float, default=3.0, help="completeness threshold (whole cloud), in GSD")
    ap.add_argument("--workspace", help="existing dense workspace of real photos: before/after (needs --before)")
    ap.add_argument("--held-out", default="", help="with --workspace: photos kept out of depth, comma-separated")
    ap.add_argument("--quality", help="CpuMvsOptions preset of the 'after' runs (fast|balanced|high)")
    return ap.parse_args()


def _modules(args: argparse.Namespace) -> tuple[CpuMvsOptions, ModuleType | None]:
    """Today's options (``--quality``) and the 'before' module (``--before``, else None); warms today's kernels up."""
    from bench_mvs_profile import load_before, warm_up

    import recon.mvs_cpu

    print(f"first call of today's CPU MVS (numba compiles or loads its cache): {warm_up(recon.mvs_cpu):.1f} s")
    before = load_before(args.before) if args.before else None
    print(f"load {os.getloadavg()}")
    return CpuMvsOptions(quality=args.quality or "balanced"), before


def main() -> None:
    args = _parse_args()
    import pycolmap

    pycolmap.logging.minloglevel = 2
    if args.workspace:
        cpu, before = _modules(args)
        held_out = frozenset(n for n in args.held_out.split(",") if n)
        compare_on_workspace(Path(args.workspace), held_out, Path(args.work), cpu, args.threads, before)
        return
    scene = _ensure_scene(args)
    work = Path(args.work)
    project = ProjectLayout(work / "known")  # only its sparse model: the known-pose triangulation
    t0 = time.perf_counter()
    if args.no_mvs:
        pass
    elif args.reuse and (project.sparse / "points3D.bin").is_file():
        print(f"reusing the known-pose model in {project.sparse}")
    else:
        known = from_reconstruction(read_reconstruction(scene / "sparse" / "0"))
        _, rep = triangulate_known_poses(known, scene / "images", project.sparse, SfmOptions(num_threads=args.threads))
        print(
            f"known-pose triangulation: {len(rep.registered)} images, {rep.num_points} points, "
            f"{rep.mean_reprojection_error:.3f} px, {time.perf_counter() - t0:.1f} s"
        )
    sizes = [] if args.no_mvs else [320] if args.quick else [int(s) for s in args.sizes.split(",")]
    rows: list[tuple[int, MvsReport, list[MaterialScore]]] = []
    gsd = float(json.loads((scene / "scene.json").read_text())["gsd_m"])
    cpu, before = _modules(args)
    for size in sizes:
        opts = MvsOptions(backend=MvsBackend.CPU, max_image_size=size, num_threads=args.threads, cpu=cpu)
        if before is not None:
            compare_before_after(scene, project.sparse, work, size, opts, before, args.tau_gsd)
            continue
        dense = DenseWorkspace(work / f"dense_{size}")
        report = run_mvs(project.sparse, scene / "images", dense.root, opts)
        gsd, scores = evaluate(scene, dense.fused_ply)
        rows.append((size, report, scores))
        _print_size(size, report, scores, gsd)
        sc = cloud_score(scene, dense.fused_ply, args.tau_gsd)
        print(f"  whole cloud: C2C mean {sc.c2c_mean_m * 1000:.3f} mm, completeness {sc.completeness:.4f} at tau")
    if before is not None:
        print(f"load {os.getloadavg()}")
    if len(rows) > 1:
        _print_ratios(rows)
    if args.sfm:
        _full_sfm(scene, work, args.threads, gsd)


def _print_size(size: int, report: MvsReport, scores: list[MaterialScore], gsd: float) -> None:
    """The timings of one ``max_image_size`` and its per-material table (GSD in metres)."""
    print(
        f"\nmax_image_size {size}: {report.num_views} views, {report.megapixels:.2f} MP, "
        f"depth {report.seconds_depth:.1f} s + geometric {report.seconds_geometric:.1f} s + fusion "
        f"{report.seconds_fusion:.1f} s -> {report.seconds_per_view:.2f} s/view, "
        f"{report.seconds_per_megapixel:.2f} s/MP, "
        f"{report.num_points} points"
    )
    print(
        f"  {'material':<20}{'collab':>7}{'points':>9}{'mesh med':>10}{'c2c med':>9}{'compl@3':>9}"
        f"   (GSD {gsd * 1000:.2f} mm)"
    )
    for s in scores:
        print(
            f"  {s.name:<20}{'yes' if s.collaborative else 'no':>7}{s.fused_points:>9}"
            f"{s.median_mesh_gsd:>10.2f}{s.median_c2c_gsd:>9.2f}{s.completeness:>9.1%}"
        )


def _print_ratios(rows: list[tuple[int, MvsReport, list[MaterialScore]]]) -> None:
    """Time, collaborative completeness and collaborative mesh median of each size against the last (largest)."""
    ref_size, ref_rep, ref_scores = rows[-1]
    print(f"\nratios against max_image_size {ref_size} (time, collaborative completeness, collaborative mesh median):")
    ref_c = np.mean([s.completeness for s in ref_scores if s.collaborative])
    ref_a = np.nanmean([s.median_mesh_gsd for s in ref_scores if s.collaborative])
    for size, rep_, scores in rows:
        c = np.mean([s.completeness for s in scores if s.collaborative])
        a = np.nanmean([s.median_mesh_gsd for s in scores if s.collaborative])
        t = rep_.seconds_depth + rep_.seconds_geometric
        tr = ref_rep.seconds_depth + ref_rep.seconds_geometric
        print(f"  {size:>5}: time x{t / tr:.2f}  completeness x{c / ref_c:.2f}  accuracy x{a / ref_a:.2f}")


def _full_sfm(scene: Path, work: Path, threads: int, gsd: float) -> None:
    """Full SfM without known poses, aligned to the true camera centres; prints registration and alignment."""
    t1 = time.perf_counter()
    rec, srep = run_sfm(scene / "images", ProjectLayout(work / "full").sparse, SfmOptions(num_threads=threads))
    known = from_reconstruction(read_reconstruction(scene / "sparse" / "0"))
    centers = {v.name: v.center for v in known}
    extent = float(np.ptp(np.stack(list(centers.values())), axis=0).max())
    a = align_reconstruction_to_centers(rec, centers, 0.02 * extent, seed=0)
    print(
        f"\nfull SfM: {len(srep.registered)}/{srep.num_images} registered, {srep.num_points} points, "
        f"{srep.mean_reprojection_error:.3f} px, {time.perf_counter() - t1:.1f} s; aligned centres: "
        f"median {np.median(a.residuals) / gsd:.3f} GSD, max {a.residuals.max() / gsd:.3f} GSD "
        f"(rms {a.rms_inliers * 1000:.2f} mm, {a.num_inliers} inliers)"
    )


if __name__ == "__main__":
    main()
