"""Mesh benchmark: decimators side by side, triangle budgets, mesh-to-ground-truth distance per material, demo time.

    python bench/bench_mesh.py --scene S --project P              # S: a data_synth scene, P: `hybridsplat run S`
    python bench/bench_mesh.py --scene S --project P --demo-scene DS --demo-project DP   # + time on the demo scene

Sections (all printed in one run, JSON with --json):

1. Decimators: fast-simplification and open3d's quadric decimation on the same raw mesh (the project's MVS-only
   Poisson mesh with denser sampling, so that it exceeds the largest budget), for each budget: triangles obtained,
   |miss| / budget, attempts, seconds, degenerate triangles, and the mean / max distance of the decimated surface to
   the raw one; then the time ratio open3d / fast-simplification.
2. Budgets 1 k / 10 k / 100 k with the default decimator: count within 1 %, degenerate triangles, edge-manifold,
   boundary edges; untrimmed watertight?, trimmed edge-manifold and its boundary edges.
3. Mesh to ground truth (the scene's gt/mesh.ply, exact): accuracy = distance of points sampled uniformly on our
   mesh to the GT surface (mean, std, median, and precision = the share within τ; per material of the nearest GT
   triangle), completeness = share of GT surface
   samples within τ of our mesh, over the GT surface that at least two training views see (visibility from the
   scene's true depth maps: what any photogrammetry could reconstruct), overall and per material. MVS-only mesh
   always; the hybrid mesh (the merged Gaussians whose `surface` field is 1, i.e. the splats that pass the merge
   stage's surface test, + training snapshots of their regions) when the project has splats.
4. Time of the whole mesh chain (default options, the demo's 2 k budget) on the demo scene, with the machine's load.
5. Where coverage is lost, per material: completeness at τ (and accuracy) of the oriented points, of the untrimmed
   Poisson surface (caps left out), of the trimmed one and of the decimated mesh, MVS-only and hybrid; and, for the
   hybrid, of its three kinds of points alone (MVS surfels, trained splats, snapshot union).

Timings on a shared machine are noisy: the load average is printed next to each; re-run before quoting.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from core.cameras import Cameras  # noqa: E402
from core.gaussians import GaussianSet  # noqa: E402
from core.io.colmap import read_model  # noqa: E402
from core.io.gaussian_ply import read_gaussian_ply  # noqa: E402
from core.io.origin import read_origin  # noqa: E402
from fusion.convert import Source  # noqa: E402
from fusion.mesh import (  # noqa: E402
    DecimateOptions,
    Decimator,
    MeshOptions,
    MeshSource,
    MeshWarning,
    OrientedPointOptions,
    PoissonOptions,
    TriangleMesh,
    decimate,
    mesh_from_gaussians,
    mesh_quality,
)
from hybridsplat.layout import ProjectLayout  # noqa: E402
from hybridsplat.project_io import read_project_model  # noqa: E402


def load() -> str:
    return "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


# -- inputs ------------------------------------------------------------------------------------------------------
def load_merged(project: Path) -> GaussianSet:
    """The merge stage's Gaussians with their ``source`` field, read as the mesh stage reads them."""
    from hybridsplat.stages.mesh import load_merged_with_source

    layout = ProjectLayout(project)
    return load_merged_with_source(layout.merged_ply, layout.merged_points_ply)


def load_snapshots(project: Path) -> list[GaussianSet]:
    """The train stage's snapshots (the mesh stage's order)."""
    folder = ProjectLayout(project).snapshots_dir
    return [read_gaussian_ply(p) for p in sorted(folder.glob("*.ply"))] if folder.is_dir() else []


def project_cameras(project: Path) -> Cameras:
    """The project's sparse model cameras in world coordinates (the origin the sfm stage recorded)."""
    layout = ProjectLayout(project)
    return read_project_model(layout, layout.sparse)[0]


def viewpoints(project: Path, origin: np.ndarray) -> np.ndarray:
    """(V, 3) camera centres in the frame of ``origin`` (as the mesh stage orients normals)."""
    cams = project_cameras(project)
    return np.array([v.center for v in cams]) + cams.origin - origin


class GroundTruth:
    """The scene's exact mesh (float64, local + origin), face materials, legend, and visible surface samples."""

    def __init__(self, scene: Path, samples: int, seed: int = 0) -> None:
        import plyfile

        ply = plyfile.PlyData.read(str(scene / "gt" / "mesh.ply"))
        v = ply["vertex"]
        self.vertices = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
        faces = ply["face"]
        self.triangles = np.stack(faces["vertex_indices"]).astype(np.int64)
        self.material = np.asarray(faces["material"], dtype=np.int64)
        self.origin = read_origin(scene / "gt" / "mesh.ply")
        meta = json.loads((scene / "scene.json").read_text())
        self.legend = {m["id"]: m for m in meta["materials"]}
        self.gsd = float(meta["gsd_m"])
        self.scene = self._raycaster(self.vertices, self.triangles)
        pts, mat = self._sample(samples, seed)
        seen = self._views_seeing(scene, pts)
        self.samples, self.sample_material = pts[seen >= 2], mat[seen >= 2]

    @staticmethod
    def _raycaster(vertices: np.ndarray, triangles: np.ndarray):
        import open3d as o3d

        rc = o3d.t.geometry.RaycastingScene()
        rc.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
        return rc

    def _sample(self, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        t = self.vertices[self.triangles]
        area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
        rng = np.random.default_rng(seed)
        tri = rng.choice(len(area), size=n, p=area / area.sum())
        a, b = rng.random(n), rng.random(n)
        f = a + b > 1
        a[f], b[f] = 1 - a[f], 1 - b[f]
        p = t[tri, 0] + a[:, None] * (t[tri, 1] - t[tri, 0]) + b[:, None] * (t[tri, 2] - t[tri, 0])
        return p, self.material[tri]

    def _views_seeing(self, scene: Path, pts: np.ndarray) -> np.ndarray:
        """Per sample, the number of training views whose true depth map shows it (within 0.5 % + 1 mm)."""
        cams, _ = read_model(scene / "sparse" / "0")
        local = pts + self.origin - cams.origin
        count = np.zeros(len(pts), dtype=np.int64)
        for view in cams:
            depth = np.load(scene / "gt" / "depth" / "train" / (Path(view.name).stem + ".npy"))
            uv, z = cams.project(view, local)
            h, w = depth.shape
            col, row = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
            ok = (z > 0) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
            d = np.zeros(len(pts))
            d[ok] = depth[row[ok], col[ok]]
            count += ok & (d > 0) & (np.abs(d - z) < 0.005 * z + 0.001)
        return count

    def closest(self, pts_gt_frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        import open3d as o3d

        ans = self.scene.compute_closest_points(o3d.core.Tensor(pts_gt_frame.astype(np.float32)))
        closest = ans["points"].numpy().astype(np.float64)
        return np.linalg.norm(closest - pts_gt_frame, axis=1), self.material[ans["primitive_ids"].numpy()]


def surface_samples(mesh: TriangleMesh, n: int, seed: int = 1) -> np.ndarray:
    t = mesh.vertices[mesh.triangles]
    area = mesh.triangle_areas()
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(area), size=n, p=area / area.sum())
    a, b = rng.random(n), rng.random(n)
    f = a + b > 1
    a[f], b[f] = 1 - a[f], 1 - b[f]
    return t[tri, 0] + a[:, None] * (t[tri, 1] - t[tri, 0]) + b[:, None] * (t[tri, 2] - t[tri, 0])


def mesh_vs_truth(mesh: TriangleMesh, gt: GroundTruth, tau: float, n: int = 200_000) -> dict[str, dict[str, float]]:
    """Accuracy (mesh → GT) and completeness at τ (visible GT → mesh), overall and per material name."""
    shift = mesh.origin - gt.origin
    acc_d, acc_m = gt.closest(surface_samples(mesh, n) + shift)
    ours = GroundTruth._raycaster(mesh.vertices + shift, mesh.triangles)
    import open3d as o3d

    comp_d = ours.compute_distance(o3d.core.Tensor(gt.samples.astype(np.float32))).numpy().astype(np.float64)
    rows: dict[str, dict[str, float]] = {}
    groups = [("all", None)] + [(gt.legend[m]["name"], m) for m in sorted(set(gt.sample_material) | set(acc_m))]
    for name, m in groups:
        a = acc_d if m is None else acc_d[acc_m == m]
        c = comp_d if m is None else comp_d[gt.sample_material == m]
        kind = "" if m is None else gt.legend[m]["kind"]
        rows[name] = {
            "kind": kind,
            "acc_n": int(len(a)),
            "acc_mean_mm": float(a.mean() * 1e3) if len(a) else float("nan"),
            "acc_std_mm": float(a.std() * 1e3) if len(a) else float("nan"),
            "acc_median_mm": float(np.median(a) * 1e3) if len(a) else float("nan"),
            "precision": float((a < tau).mean()) if len(a) else float("nan"),
            "gt_n": int(len(c)),
            "completeness": float((c < tau).mean()) if len(c) else float("nan"),
        }
        p, r = rows[name]["precision"], rows[name]["completeness"]
        rows[name]["f_score"] = 2 * p * r / (p + r) if p + r > 0 else 0.0
    return rows


# -- sections ----------------------------------------------------------------------------------------------------
def decimator_section(raw: TriangleMesh, budgets: list[int]) -> list[dict[str, object]]:
    print(f"\n== 1. decimators on one raw mesh of {raw.num_triangles} triangles ({load()})")
    ref = GroundTruth._raycaster(raw.vertices, raw.triangles)
    import open3d as o3d

    rows = []
    print(
        f"{'budget':>8} {'method':>20} {'triangles':>9} {'miss%':>6} {'tries':>5} {'s':>7} {'degen':>5} "
        f"{'mean µm':>8} {'max µm':>8}"
    )
    for budget in budgets:
        if budget >= raw.num_triangles:
            print(f"{budget:>8} (above the raw mesh: skipped)")
            continue
        times = {}
        for method in (Decimator.FAST_SIMPLIFICATION, Decimator.OPEN3D):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", MeshWarning)
                out, st = decimate(raw, budget, DecimateOptions(method=method))
            d = ref.compute_distance(o3d.core.Tensor(surface_samples(out, 50_000).astype(np.float32))).numpy()
            q = mesh_quality(out)
            row = {
                "budget": budget,
                "method": method.value,
                "triangles": out.num_triangles,
                "miss_pct": 100 * abs(out.num_triangles - budget) / budget,
                "attempts": st.attempts,
                "seconds": st.seconds,
                "degenerate": q.degenerate_triangles,
                "non_manifold_edges": q.non_manifold_edges,
                "mean_um": float(d.mean() * 1e6),
                "max_um": float(d.max() * 1e6),
            }
            times[method] = st.seconds
            rows.append(row)
            print(
                f"{budget:>8} {method.value:>20} {out.num_triangles:>9} {row['miss_pct']:>6.2f} {st.attempts:>5} "
                f"{st.seconds:>7.3f} {q.degenerate_triangles:>5} {row['mean_um']:>8.1f} {row['max_um']:>8.1f}"
            )
        ratio = times[Decimator.OPEN3D] / max(times[Decimator.FAST_SIMPLIFICATION], 1e-9)
        print(f"{'':>8} time open3d / fast-simplification = {ratio:.1f}x")
    return rows


def budget_section(merged: GaussianSet, vp: np.ndarray, budgets: list[int], dense: MeshOptions) -> dict:
    print(f"\n== 2. budgets, MVS-only mesh, default decimator ({load()})")
    base = mesh_from_gaussians(merged, MeshOptions(budget=None, source=MeshSource.MVS), viewpoints=vp)
    raw = mesh_from_gaussians(merged, dense, viewpoints=vp)
    out: dict[str, object] = {"default": base.summary(), "dense": raw.summary(), "budgets": []}
    for name, r in (("default sampling", base), ("dense sampling (for the 100 k budget)", raw)):
        print(
            f"{name}: {len(r.points)} points, depth {r.poisson_depth}; untrimmed {r.quality_untrimmed.triangles} "
            f"triangles, watertight {r.quality_untrimmed.watertight} (boundary edges "
            f"{r.quality_untrimmed.boundary_edges}, non-manifold {r.quality_untrimmed.non_manifold_edges}); trimmed "
            f"{r.quality_trimmed.triangles}, edge-manifold {r.quality_trimmed.edge_manifold}, boundary edges "
            f"{r.quality_trimmed.boundary_edges}, pieces {r.quality_trimmed.pieces};\n  trim {r.trim_stats}"
        )
    for budget in budgets:
        src = base.trimmed if budget < base.trimmed.num_triangles else raw.trimmed
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MeshWarning)
            m, st = decimate(src, budget)
        q = mesh_quality(m)
        row = {
            "budget": budget,
            "raw": src.num_triangles,
            "triangles": q.triangles,
            "within_1pct": abs(q.triangles - budget) <= 0.01 * budget,
            "degenerate": q.degenerate_triangles,
            "edge_manifold": q.edge_manifold,
            "method": st.method,
            "boundary_edges": q.boundary_edges,
            "seconds": st.seconds,
        }
        out["budgets"].append(row)  # type: ignore[union-attr]
        print(
            f"budget {budget:>7}: raw {src.num_triangles:>7} -> {q.triangles:>7} triangles, within 1 %: "
            f"{row['within_1pct']}, degenerate {q.degenerate_triangles}, edge-manifold {q.edge_manifold}, "
            f"boundary edges {q.boundary_edges}, {st.seconds:.2f} s ({st.method})"
        )
    out["raw_mesh"] = raw.trimmed
    return out


def truth_section(merged, snapshots, vp, gt: GroundTruth, tau: float, budget: int) -> dict:
    print(
        f"\n== 3. mesh to ground truth, budget {budget}, τ = {tau * 1e3:.1f} mm "
        f"({gt.samples.shape[0]} visible GT samples; {load()})"
    )
    results = {}
    kinds = [("mvs-only", MeshOptions(budget=budget, source=MeshSource.MVS), ())]
    has_splats = bool((merged.fields["source"] == Source.SPLAT).any())
    if has_splats:
        kinds.append(("hybrid", MeshOptions(budget=budget), tuple(snapshots)))
    else:
        print(
            "hybrid: the project has no trained splats (source = 2) in merged.ply; only the MVS-only mesh is measured"
        )
    for name, opts, snaps in kinds:
        t = time.perf_counter()
        r = mesh_from_gaussians(merged, opts, snapshots=snaps, viewpoints=vp)
        sec = time.perf_counter() - t
        rows = mesh_vs_truth(r.mesh, gt, tau)
        results[name] = {"summary": r.summary(), "seconds": sec, "materials": rows}
        print(f"-- {name}: {r.mesh.num_triangles} triangles, {sec:.1f} s")
        print_truth_rows(rows)
    return results


def print_truth_rows(rows: dict[str, dict[str, float]]) -> None:
    print(
        f"{'material':>20} {'kind':>12} {'acc mean mm':>11} {'acc std mm':>10} {'acc med mm':>10} {'prec.':>6} "
        f"{'acc n':>7} {'compl.':>7} {'F':>6} {'GT n':>7}"
    )
    for mat, row in rows.items():
        print(
            f"{mat:>20} {row['kind']:>12} {row['acc_mean_mm']:>11.2f} {row['acc_std_mm']:>10.2f} "
            f"{row['acc_median_mm']:>10.2f} {row['precision']:>6.3f} {row['acc_n']:>7} {row['completeness']:>7.3f} "
            f"{row['f_score']:>6.3f} {row['gt_n']:>7}"
        )


def points_vs_truth(points: np.ndarray, origin: np.ndarray, gt: GroundTruth, tau: float) -> dict[str, dict]:
    """Completeness at τ of a point set (visible GT samples with a point within τ) and the points' accuracy."""
    from scipy.spatial import cKDTree

    local = points + origin - gt.origin
    rows: dict[str, dict] = {}
    if len(local) == 0:
        return {"all": {"completeness": 0.0, "acc_mean_mm": float("nan"), "n": 0}}
    comp_d, _ = cKDTree(local).query(gt.samples, k=1)
    acc_d, acc_m = gt.closest(local)
    for name, m in [("all", None)] + [(gt.legend[m]["name"], m) for m in sorted(set(gt.sample_material))]:
        c = comp_d if m is None else comp_d[gt.sample_material == m]
        a = acc_d if m is None else acc_d[acc_m == m]
        rows[name] = {
            "completeness": float((c < tau).mean()) if len(c) else float("nan"),
            "acc_mean_mm": float(a.mean() * 1e3) if len(a) else float("nan"),
            "n": int(len(a)),
        }
    return rows


def coverage_section(merged, snapshots, vp, gt: GroundTruth, tau: float, budget: int) -> dict:
    print(f"\n== 5. where coverage is lost: completeness at τ = {tau * 1e3:.1f} mm per step ({load()})")
    out: dict[str, dict] = {}
    kinds = [("mvs-only", MeshOptions(budget=budget, source=MeshSource.MVS), ())]
    if (merged.fields["source"] == Source.SPLAT).any():
        kinds.append(("hybrid", MeshOptions(budget=budget), tuple(snapshots)))
    for name, opts, snaps in kinds:
        r = mesh_from_gaussians(merged, opts, snapshots=snaps, viewpoints=vp)
        surface = TriangleMesh(r.untrimmed.vertices, r.untrimmed.triangles[~r.untrimmed_is_cap], r.untrimmed.origin)
        steps = {"points": points_vs_truth(r.points.positions, r.points.origin, gt, tau)}
        if name == "hybrid":
            for label, code in (("  MVS points", Source.MVS), ("  splat points", Source.SPLAT)):
                keep = r.points.source == code
                if code == Source.SPLAT:
                    keep &= r.points.gaussian_index >= 0
                steps[label] = points_vs_truth(r.points.positions[keep], r.points.origin, gt, tau)
            snap = r.points.gaussian_index < 0
            steps["  snapshot points"] = points_vs_truth(r.points.positions[snap], r.points.origin, gt, tau)
        steps["untrimmed"] = mesh_vs_truth(surface.compact(), gt, tau)
        steps["trimmed"] = mesh_vs_truth(r.trimmed, gt, tau)
        steps["decimated"] = mesh_vs_truth(r.mesh, gt, tau)
        materials = list(steps["trimmed"])
        print(f"-- {name}: {len(r.points)} points; trim {r.trim_stats}")
        print(f"{'step':>18} " + " ".join(f"{m[:12]:>12}" for m in materials))
        for step, rows in steps.items():
            print(
                f"{step:>18} "
                + " ".join(f"{rows[m]['completeness']:>12.3f}" if m in rows else f"{'':>12}" for m in materials)
            )
        out[name] = steps
    return out


def tsdf_section(project: Path, merged: GaussianSet, gt: GroundTruth, tau: float, budget: int) -> dict:
    from fusion.mesh.tsdf import tsdf_mesh

    cams = project_cameras(project)
    mvs = merged.subset(merged.fields["source"] == Source.MVS)
    t = time.perf_counter()
    raw = tsdf_mesh(mvs, cams)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MeshWarning)
        mesh, _ = decimate(raw, budget)
    sec = time.perf_counter() - t
    rows = mesh_vs_truth(mesh, gt, tau)
    print(
        f"-- TSDF of depth rendered from the MVS Gaussians at {len(cams)} cameras: {raw.num_triangles} raw, "
        f"{mesh.num_triangles} triangles, {sec:.1f} s ({load()})"
    )
    print_truth_rows(rows)
    return {"seconds": sec, "triangles_raw": raw.num_triangles, "materials": rows}


def demo_section(scene: Path, project: Path) -> dict:
    """The mesh stage's meshing with the demo's options (``DEMO_STAGES``: 2 k triangles), timed."""
    from dataclasses import replace

    from hybridsplat.commands.run import DEMO_STAGES
    from hybridsplat.options import options_with
    from hybridsplat.stages.mesh import MeshStageOptions

    stage = options_with(MeshStageOptions, DEMO_STAGES["mesh"])
    options = replace(stage.mesh, budget=stage.budget)  # as the mesh stage passes them
    merged = load_merged(project)
    vp = viewpoints(project, merged.origin)
    before = load()
    t = time.perf_counter()  # reading the snapshots included: the stage reads them too
    snapshots = load_snapshots(project) if options.use_snapshots else []
    r = mesh_from_gaussians(merged, options, snapshots=snapshots, viewpoints=vp)
    sec = time.perf_counter() - t
    print(
        f"\n== 4. demo scene {scene.name}: {len(merged)} Gaussians -> {r.mesh.num_triangles} triangles "
        f"in {sec:.2f} s "
        f"(points {r.timings.points:.2f}, Poisson {r.timings.poisson:.2f}, trim {r.timings.trim:.2f}, decimate "
        f"{r.timings.decimate:.2f}, colours {r.timings.colors:.2f}); before: {before}, after: {load()}, "
        f"{os.cpu_count()} cores"
    )
    return {"seconds": sec, "summary": r.summary(), "load_before": before, "load_after": load()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path)
    ap.add_argument("--project", type=Path)
    ap.add_argument("--sections", type=int, nargs="+", default=[1, 2, 3, 4], help="which sections to run")
    ap.add_argument("--tsdf", action="store_true", help="section 3: also the TSDF mesh of rendered depth")
    ap.add_argument("--budgets", type=int, nargs="+", default=[1_000, 10_000, 100_000])
    ap.add_argument("--truth-budget", type=int, default=100_000)
    ap.add_argument("--tau-gsd", type=float, default=2.0, help="τ in units of the scene's GSD (default 2)")
    ap.add_argument("--gt-samples", type=int, default=400_000)
    ap.add_argument(
        "--dense-spacing",
        type=float,
        default=0.4,
        help="sample spacing of the dense raw mesh, as a share of the default (default 0.4)",
    )
    ap.add_argument("--demo-scene", type=Path)
    ap.add_argument("--demo-project", type=Path)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()

    report: dict[str, object] = {}
    if {1, 2, 3, 5} & set(args.sections):
        if args.scene is None or args.project is None:
            raise SystemExit("sections 1-3 and 5 need --scene and --project")
        merged = load_merged(args.project)
        vp = viewpoints(args.project, merged.origin)
        snaps = load_snapshots(args.project)
        print(
            f"{args.project}: {len(merged)} merged Gaussians (source counts {np.bincount(merged.fields['source'])}), "
            f"{len(snaps)} snapshots, {len(vp)} cameras; {load()}"
        )
    if {1, 2} & set(args.sections):
        from fusion.mesh.oriented_points import oriented_points_from_gaussians

        _, st = oriented_points_from_gaussians(merged.subset(merged.fields["source"] == Source.MVS))
        dense = MeshOptions(
            budget=None,
            source=MeshSource.MVS,
            points=OrientedPointOptions(sample_spacing=args.dense_spacing * st.sample_spacing),
            poisson=PoissonOptions(max_depth=11),
        )
        budgets = budget_section(merged, vp, args.budgets, dense)
        raw = budgets.pop("raw_mesh")
        report["budgets"] = budgets
        if 1 in args.sections:
            report["decimators"] = decimator_section(raw, args.budgets)
    if 3 in args.sections:
        gt = GroundTruth(args.scene, args.gt_samples)
        tau = args.tau_gsd * gt.gsd
        report["truth"] = truth_section(merged, snaps, vp, gt, tau, args.truth_budget)
        if args.tsdf:
            report["tsdf"] = tsdf_section(args.project, merged, gt, tau, args.truth_budget)
        report["tau_m"] = tau
    if 5 in args.sections:
        gt = gt if 3 in args.sections else GroundTruth(args.scene, args.gt_samples)
        report["coverage"] = coverage_section(merged, snaps, vp, gt, args.tau_gsd * gt.gsd, args.truth_budget)
    if 4 in args.sections and args.demo_scene and args.demo_project:
        report["demo"] = demo_section(args.demo_scene, args.demo_project)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2, default=str) + "\n")


if __name__ == "__main__":
    main()
