"""Survey control on a synthetic aerial block: check-point accuracy with ground control against camera centres from
a consumer drone's GNSS, target detection, and the dense cloud in the control frame.

``python bench/bench_control.py --data D [--seed 100] [--views 24] [--width 640 --height 480] [--mvs-size 320]
[--gnss-sigma 1.0,2.0 --gnss-bias 1.0,2.5] [--no-dense] [--out bench_out/control]``

1. The scene: ``random-aerial`` at a scoring seed (100-199) with its coded targets (half control, half check; the
   exact target centres are the truth), ``views`` training views of ``width`` × ``height``.
2. Detection: every target wholly visible in a photo (all pixel centres inside its square labelled as the target in
   the scene's label maps) should be found; the share found, spurious finds, and the centre's pixel error against
   the exact projection of the target centre (mean, RMS, max).
3. GNSS only: full SfM aligned to camera centres perturbed like a consumer drone's GNSS (per photo N(0, σ_h) per
   horizontal axis and N(0, σ_v) vertically, plus one offset for the flight drawn from N(0, bias)), every target
   triangulated from its marks in that model and compared with the truth: the check points' ASPRS figures.
4. With control: the same project adjusted to the control targets (the control stage) and its statement.
5. Dense: the MVS cloud (CPU MVS at ``mvs-size``) of the controlled project, of full SfM aligned to the exact camera
   centres (the alignment without control), and of the exact cameras themselves (known poses, triangulation only):
   C2C against the LiDAR (mean, median, RMS of the fused points' distances, precision at 3 GSD).

Prints a table and writes ``OUT/bench_control.json``. Figures in GSD use the scene's ``gsd_m`` (median depth over
the focal length of the training views) and the GSD at the targets (median z-depth of the targets' marks over
the focal length).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402


def _scene(data: Path, args: argparse.Namespace) -> Path:
    from data_synth import generate_scene

    root = data / f"random-aerial-{args.seed}-{args.views}-{args.width}"
    if not (root / "scene.json").is_file():
        generate_scene("random-aerial", root, seed=args.seed, views=args.views, test_views=2, width=args.width,
                       height=args.height, overwrite=True)  # fmt: skip
    return root


def _targets(scene):
    from data_synth.targets import Target

    return [Target(p["marker_id"], tuple(p["center_local_m"]), p["size_m"], p["yaw_deg"], p["role"])
            for p in scene.description.extra["targets"]["points"]]  # fmt: skip


def detection(scene) -> dict[str, Any]:
    """Step 2 of the module docstring."""
    import cv2

    from data_synth.materials import TARGET_MATERIAL_ID
    from recon.targets import detect_markers

    targets = _targets(scene)
    errors, visible, spurious, depths = [], 0, 0, []
    for view in scene.train:
        found = {m.marker_id: m for m in detect_markers(scene.image("train", view.name))}
        spurious += len(set(found) - {t.marker_id for t in targets})
        labels = scene.labels("train", view.name)
        cam = scene.train.camera_of(view)
        for t in targets:
            uv, z = scene.train.project(view, np.vstack([np.asarray(t.center_m)[None], t.corners()]))
            inside = (uv[:, 0] > 1) & (uv[:, 0] < cam.width - 1) & (uv[:, 1] > 1) & (uv[:, 1] < cam.height - 1)
            if not inside.all() or (z <= 0).any():
                continue
            mask = np.zeros(labels.shape, np.uint8)
            cv2.fillConvexPoly(mask, np.round((uv[1:] - 0.5) * 16).astype(np.int32), 1, shift=4)
            mask = cv2.erode(mask, np.ones((3, 3), np.uint8))  # pixel centres inside the square
            if not (labels[mask > 0] == TARGET_MATERIAL_ID).all():
                continue
            visible += 1
            depths.append(float(z[0]) / cam.focal[0])
            if t.marker_id in found:
                errors.append(float(np.linalg.norm(found[t.marker_id].center - uv[0])))
    e = np.asarray(errors)
    return {"visible": visible, "found": len(e), "spurious": spurious, "share": len(e) / max(visible, 1),
            "error_mean_px": float(e.mean()), "error_rms_px": float(np.sqrt(np.mean(e**2))),
            "error_max_px": float(e.max()), "gsd_at_targets_m": float(np.median(depths))}  # fmt: skip


def _gnss_reference(scene, out: Path, sigma: tuple[float, float], bias: tuple[float, float], seed: int) -> Path:
    from recon.reference import write_reference_text

    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x6E55]))
    offset = rng.normal(0.0, [bias[0], bias[0], bias[1]])
    centers = {}
    for view in scene.train:
        noise = rng.normal(0.0, [sigma[0], sigma[0], sigma[1]])
        centers[view.name] = scene.origin + view.center + offset + noise
    write_reference_text(out, centers)
    return out


def _run(scene_root: Path, project: Path, stages: list[str], **inputs: Any):
    from hybridsplat.config import InputOptions, ProjectConfig
    from hybridsplat.pipeline import run_pipeline
    from hybridsplat.stages import stage_named
    from hybridsplat.terminal import Terminal
    from recon.mvs import MvsOptions

    size = inputs.pop("mvs_size")
    config = ProjectConfig(input=InputOptions(path=str(scene_root.resolve()), **inputs),
                           stages={"mvs": MvsOptions(backend="cpu", max_image_size=size)})  # fmt: skip
    start = time.perf_counter()
    manifest = run_pipeline(project, config, stages=[stage_named(s) for s in stages], terminal=Terminal(quiet=True))
    return manifest, time.perf_counter() - start


def gnss_only_statement(scene, project: Path) -> dict[str, Any]:
    """Step 3: every target measured in the GNSS-aligned model, none held (the statement over the same check points
    as with control; ``all_points``: over every target)."""
    from core.io.control import read_gcp_csv
    from eval.accuracy import PointResidual, accuracy_statement
    from hybridsplat.layout import ProjectLayout
    from hybridsplat.project_io import model_origin
    from recon.control import ImageMark, measure_points
    from recon.model import read_reconstruction
    from recon.targets import detect_marks

    layout = ProjectLayout(project)
    rec = read_reconstruction(layout.sparse)
    origin = model_origin(layout)
    images = {rec.image(i).name: int(i) for i in rec.reg_image_ids()}
    marks: dict[str, list] = {}
    for m in detect_marks((n, scene.paths.images_dir / n) for n in sorted(images)):
        marks.setdefault(m.point_id, []).append(ImageMark(images[m.image], m.uv))
    gcp = read_gcp_csv(scene.paths.gcp_csv)
    survey = {p.id: (p.role.value, p.xyz_m - origin) for p in gcp.points}
    measured, _ = measure_points(rec, marks, survey, 3.0)
    residuals = [PointResidual(p.id, p.role, tuple(p.survey), *(p.model - p.survey), p.marks, p.reprojection_px)
                 for p in measured if np.isfinite(p.model).all()]  # fmt: skip
    out = accuracy_statement(residuals).to_json()
    every = [PointResidual(r.id, "check", *tuple(vars(r).values())[2:]) for r in residuals]
    out["all_points"] = {k: v for k, v in accuracy_statement(every).to_json().items() if k != "points"}
    return out


def dense_c2c(scene, project: Path, tau: float) -> dict[str, Any]:
    from core.io.ply import read_ply
    from eval.c2c import compare_clouds
    from hybridsplat.layout import ProjectLayout

    fused = read_ply(ProjectLayout(project).fused_ply)
    result = compare_clouds(fused, scene.gt_cloud, tau=tau)
    d = result.distances
    precision = float(result.scores.precision)
    return {"points": len(fused), "mean_m": float(d.mean()), "median_m": float(np.median(d)),
            "rms_m": float(np.sqrt(np.mean(d**2))), "precision_tau": precision, "tau_m": tau}  # fmt: skip


def _figures(name: str, s: dict[str, Any], gsd: float) -> str:
    return (f"| {name} | {s['check_points']} | {s['rmse_h'] * 1000:.1f} mm ({s['rmse_h'] / gsd:.3f} GSD) | "
            f"{s['rmse_v'] * 1000:.1f} mm ({s['rmse_v'] / gsd:.3f} GSD) | {s['rmse_3d'] * 1000:.1f} mm |")  # fmt: skip


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", type=Path, required=True, help="Folder for the scene and the projects.")
    p.add_argument("--seed", type=int, default=100, help="Scene seed (scoring seeds: 100-199).")
    p.add_argument("--views", type=int, default=24)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--mvs-size", type=int, default=320, help="Longer side of the dense images (px).")
    p.add_argument("--gnss-sigma", default="1.0,2.0", help="Per-photo GNSS noise sigma, horizontal,vertical (m).")
    p.add_argument("--gnss-bias", default="1.0,2.5", help="Sigma of the flight's common GNSS offset, h,v (m).")
    p.add_argument("--no-dense", action="store_true", help="Skip the MVS runs and their C2C.")
    p.add_argument("--out", type=Path, default=Path("bench_out/control"))
    args = p.parse_args(argv)
    from data_synth import load_scene

    args.data.mkdir(parents=True, exist_ok=True)
    scene_root = _scene(args.data, args)
    scene = load_scene(scene_root)
    out: dict[str, Any] = {"seed": args.seed, "views": len(scene.train), "size": [args.width, args.height],
                           "gsd_m": scene.gsd_m}  # fmt: skip
    out["detection"] = detection(scene)
    sigma = tuple(float(v) for v in args.gnss_sigma.split(","))
    bias = tuple(float(v) for v in args.gnss_bias.split(","))
    reference = _gnss_reference(scene, args.data / f"gnss-{args.seed}.txt", sigma, bias, args.seed)  # type: ignore[arg-type]
    out["gnss"] = {"sigma_m": sigma, "bias_sigma_m": bias}
    project = args.data / f"project-{args.seed}-control"
    common = {"use_scene_cameras": False, "reference": str(reference), "mvs_size": args.mvs_size}
    _, out["sfm_seconds"] = _run(scene_root, project, ["sfm"], **common)
    out["gnss_only"] = gnss_only_statement(scene, project)
    control = str(scene.paths.gcp_csv.resolve())
    stages = ["sfm", "control"] + ([] if args.no_dense else ["mvs"])
    _, out["control_seconds"] = _run(scene_root, project, stages, control=control, **common)
    out["with_control"] = json.loads((project / "control" / "accuracy.json").read_text())
    if not args.no_dense:
        exact = args.data / f"project-{args.seed}-exact"
        _run(scene_root, exact, ["sfm", "mvs"], mvs_size=args.mvs_size)
        aligned = args.data / f"project-{args.seed}-aligned-exact"
        _run(scene_root, aligned, ["sfm", "mvs"], use_scene_cameras=False, mvs_size=args.mvs_size)
        tau = 3 * scene.gsd_m
        out["dense"] = {"control": dense_c2c(scene, project, tau),
                        "sfm_aligned_to_exact_centres": dense_c2c(scene, aligned, tau),
                        "exact_cameras": dense_c2c(scene, exact, tau)}  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_control.json").write_text(json.dumps(out, indent=1, default=float) + "\n")
    _print(out)
    return out


def _print(out: dict[str, Any]) -> None:
    d, gsd = out["detection"], out["gsd_m"]
    print(f"scene random-aerial seed {out['seed']}: {out['views']} views of {out['size'][0]}x{out['size'][1]}, "
          f"GSD {gsd * 100:.2f} cm (at the targets {d['gsd_at_targets_m'] * 100:.2f} cm)")  # fmt: skip
    print(f"detection: {d['found']}/{d['visible']} wholly visible targets found ({d['share']:.1%}), "
          f"{d['spurious']} spurious; centre error mean {d['error_mean_px']:.3f} px, RMS {d['error_rms_px']:.3f} px, "
          f"max {d['error_max_px']:.3f} px")  # fmt: skip
    print("| run | check points | RMSE_H | RMSE_V | RMSE_3D |\n|---|---|---|---|---|")
    print(_figures("GNSS camera centres only", out["gnss_only"], gsd))
    print(_figures("GNSS camera centres only, every target", out["gnss_only"]["all_points"], gsd))
    print(_figures("with control (BA held to GCPs)", out["with_control"], gsd))
    for name, c in (out.get("dense") or {}).items():
        print(f"dense {name}: {c['points']} points, C2C mean {c['mean_m'] * 1000:.1f} mm, median "
              f"{c['median_m'] * 1000:.1f} mm, RMS {c['rms_m'] * 1000:.1f} mm, precision@{c['tau_m']:.2f} m "
              f"{c['precision_tau']:.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
