"""Splat-training benchmarks.

``python bench/bench_train.py speed [--n 50000] [--size 256x192] [--steps 20] [--mask-share 0]``
    One full training iteration (mask = whole image: render, loss, backward, Adam, densification bookkeeping)
    on a random scene, each part timed, next to OpenSplat 1.1.5's CPU figures (0.119 s/iter at 5 k, 0.209 s/iter
    at 50 k Gaussians, 256×192, 2 cores, measured on this kind of machine). Also the time of every kernel inside
    those parts (projection, binning, rasteriser forward / backward, per-Gaussian sums, loss forward / backward,
    Adam), wall and process CPU, medians per iteration; first-call compile / cache-load time reported apart.
    The kernels split their work over 2 threads, so on an idle machine the wall time of those parts is about half
    their CPU time. On the shared machine (kernel.sched_autogroup_enabled = 1) a busy process of another session,
    even niced, takes one core's share: both threads then run one after the other and wall = CPU time (measured
    with two GIL-free numba loops: 1 thread 1.2 s, 2 threads 2.35 s wall / 2.4 s CPU at load 3.3). Read such
    figures as CPU time. ``--mask-share S`` (0 < S < 1): the loss mask is a centred ellipse over that share of
    the image, as in the hybrid's masked training; the Gaussians culled to the active tiles; each iteration is then
    run twice side by side, compositing every pixel of the active tiles and only the loss's pixels
    (``render_step(loss_pixels_only=True)``, the trainer's default), and the ratio of the medians is printed.

``python bench/bench_train.py tabletop --scene SCENE --project PROJECT [--iterations 2000] ...``
    The hybrid on a data_synth scene that ``hybridsplat run`` has processed: masks and ``needs_splats`` from the
    scene's truth (material labels of the training photos; fused points labelled by the nearest LiDAR point's
    material) until the classify stage exists; MVS Gaussians of trusted points frozen as context; seeds; masked
    training; cleaning; merge. Then the whole-scene baseline (same trainer, mask = whole image, no context, SfM
    init, same cap) and the held-out metrics (PSNR / SSIM / LPIPS, inside the non-collaborative masks and whole
    image) of merged, MVS-only and baseline, with times. Every figure is printed with the machine load. Options:
    ``--depth-prior/--normal-prior/--prior-border`` (fusion.train.priors; 0 0 = off), ``--hard-views``,
    ``--photometric smoothl1_msssim``; per-material geometry of MVS-only, the splat centres, merged with every splat
    and the merged survey points (fusion.clean.select_survey_points) is printed and written to geometry.json.

``python bench/bench_train.py geometry --scene SCENE --project PROJECT [--splats L=PLY ...] [--points L=PLY ...]``
    Where the geometric error comes from, per truth material (the LiDAR's ``material`` field): accuracy (mean
    distance product → truth, by the nearest truth point's material; splat centres opacity-weighted) and
    completeness at τ = 3 GSD (truth → product) of MVS-only, the MVS points kept / dropped (``needs_splats`` from the
    truth, or ``--needs classified`` with the pipeline's masks), the ``needs_splats`` MVS points and splats that
    pass the survey-point rule at each ``--rim`` limit, and merged products; ``--points`` measures written point
    clouds (e.g. a project's export/merged_points.ply) as they are.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402


def load() -> str:
    return "load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


# -- speed -------------------------------------------------------------------------------------------
def bench_speed(args: argparse.Namespace) -> None:
    from fusion.render.synthetic import random_scene
    from fusion.train.loss import masked_photometric_loss
    from fusion.train.params import make_optimizer, make_parameters
    from fusion.train.render import render_step
    from fusion.train.strategy import DefaultStrategy
    from fusion.train.views import TrainView, active_tile_prefix, pixels_within_reach

    width, height = (int(x) for x in args.size.split("x"))
    scene = random_scene(args.n, width, height, seed=0, sh_degree=args.sh_degree)
    truth = random_scene(args.n, width, height, seed=1, sh_degree=0)
    from fusion.render import render

    with torch.no_grad():
        target = render(*truth.params, *truth.camera, backend="cpu").colour.clamp(0, 1)
    if 0 < args.mask_share < 1:
        rows, cols = np.mgrid[0:height, 0:width]
        r = ((cols + 0.5 - width / 2) / width) ** 2 + ((rows + 0.5 - height / 2) / height) ** 2
        mask = r <= np.quantile(r, args.mask_share)
        view = TrainView("bench", target, torch.from_numpy(mask), torch.zeros((height, width), dtype=torch.bool),
                         scene.viewmat, scene.K, width, height, int(mask.sum()), active_tile_prefix(mask),
                         pixels_within_reach(mask))  # fmt: skip
        modes = (False, True)
        reach = float(view.render_pixels.mean())
        print(f"mask: {mask.mean():.1%} of the pixels, {reach:.1%} within the SSIM reach")
    else:
        view = TrainView("bench", target, None, torch.zeros((height, width), dtype=torch.bool), scene.viewmat,
                         scene.K, width, height, width * height, None)  # fmt: skip
        modes = (False,)
    params = make_parameters(scene.trainable)
    optimizer = make_optimizer(params, {k: 1e-4 for k in params})
    strategy = DefaultStrategy(cap=args.n)  # bookkeeping every step; no refinement before step 500
    state = strategy.initial_state(args.n)
    bg = torch.zeros(3)
    names = ("render fwd", "loss fwd", "backward", "adam", "densify stats", "total")
    parts = {m: {k: [] for k in names} for m in modes}
    cpu = {m: {k: [] for k in names} for m in modes}  # process CPU seconds (all threads): less load-sensitive

    def clock() -> tuple[float, float]:
        return time.perf_counter(), time.process_time()

    from fusion.render.threads import kernel_times, record_times

    kernels: dict[bool, dict[str, list[tuple[float, float]]]] = {m: {} for m in modes}
    print(f"before: {load()}")
    for i in range(args.steps + 3):
        if i == 3:
            record_times(True)
        for only in modes:  # side by side, alternating, so that both see the same machine load
            kernel_times()
            c0 = clock()
            out = render_step(params, view, None, args.sh_degree, bg, loss_pixels_only=only)
            c1 = clock()
            terms = masked_photometric_loss(out.colour, view.image, view.loss_mask)
            c2 = clock()
            terms.loss.backward()
            c3 = clock()
            optimizer.step()
            optimizer.zero_grad(set_to_none=True)
            c4 = clock()
            strategy.after_backward(state, out.means2d, width, height, i)
            strategy.refine(state, params, optimizer, i + 1, 10**9, 1.0, torch.Generator())
            c5 = clock()
            if i == 0:
                print(f"first iteration (numba compile or cache load, thread pool): {c5[0] - c0[0]:.2f} s")
            if i >= 3:  # warm-up (kernel compilation, thread pool)
                spans = ((c0, c1), (c1, c2), (c2, c3), (c3, c4), (c4, c5), (c0, c5))
                for k, (a, b) in zip(names, spans, strict=True):
                    parts[only][k].append(b[0] - a[0])
                    cpu[only][k].append(b[1] - a[1])
                for k, v in kernel_times().items():
                    kernels[only].setdefault(k, []).append(v)
    record_times(False)
    print(f"one training iteration, {args.n} Gaussians, {width}x{height}, SH degree {args.sh_degree}, "
          f"{torch.get_num_threads()} torch threads; after: {load()}")  # fmt: skip
    for only in modes:
        if len(modes) > 1:
            print("compositing " + ("only the loss's pixels" if only else "every pixel of the active tiles"))
        for k, v in parts[only].items():
            print(f"  {k:14s} wall median {1000 * np.median(v):7.1f} ms  min {1000 * np.min(v):7.1f} ms   "
                  f"CPU median {1000 * np.median(cpu[only][k]):7.1f} ms")  # fmt: skip
        print("  kernels inside those parts (median per iteration):")
        for k, v in kernels[only].items():
            arr = np.array(v)
            print(f"    {k:14s} wall {1000 * np.median(arr[:, 0]):7.2f} ms   CPU {1000 * np.median(arr[:, 1]):7.2f} ms")
    if len(modes) > 1:
        ratio = {w: np.median(parts[True][w]) / np.median(parts[False][w]) for w in ("render fwd", "backward", "total")}
        cpu_ratio = np.median(cpu[True]["total"]) / np.median(cpu[False]["total"])
        print("  loss pixels only / every active pixel: render fwd {:.2f}, backward {:.2f}, total {:.2f} (CPU {:.2f})"
              .format(ratio["render fwd"], ratio["backward"], ratio["total"], cpu_ratio))  # fmt: skip
        return
    total = float(np.median(parts[False]["total"]))
    peer = 0.209 if args.n >= 50_000 else 0.119
    print(f"  OpenSplat 1.1.5 CPU: {peer:.3f} s/iter -> ours {total:.3f} s/iter, ratio {peer / total:.2f}x "
          f"(target <= 0.100 s)")  # fmt: skip


# -- tabletop ----------------------------------------------------------------------------------------
def truth_inputs(scene: Path, cameras, fused_positions: np.ndarray):
    """Training masks (name -> bool) from the scene's material labels and needs_splats per fused point."""
    from scipy.spatial import cKDTree

    from core.io import read_point_cloud
    from core.io.images import read_image

    meta = json.loads((scene / "scene.json").read_text())
    non_collab = [int(m["id"]) for m in meta["materials"] if not m["collaborative"]]
    masks = {}
    for view in cameras:
        labels = read_image(scene / "gt" / "labels" / "train" / view.name, grayscale=True)
        masks[view.name] = np.isin(labels, non_collab)
    lidar = read_point_cloud(scene / "gt" / "lidar.ply")
    material = np.asarray(lidar.fields["material"]).astype(np.int64)
    world = lidar.world_positions
    _, idx = cKDTree(world).query(fused_positions, k=1, workers=-1)
    needs = np.isin(material[idx], non_collab)
    return masks, needs, non_collab


def splat_geometry(splats, lidar_world: np.ndarray, material: np.ndarray, non_collab, tau: float) -> dict:
    """Opacity-weighted C2C (metres) of splat centres to the LiDAR truth, per nearest material, and the count of
    splats outside the true region (nearest truth point collaborative, or farther than ``tau``)."""
    from scipy.spatial import cKDTree

    if len(splats) == 0:
        return {"outside_true_region": 0, "per_material": {}}
    d, idx = cKDTree(lidar_world).query(splats.world_means, k=1, workers=-1)
    w = splats.opacities.astype(np.float64)
    mat = material[idx]
    per = {}
    for m in np.unique(mat):
        sel = mat == m
        per[int(m)] = {"n": int(sel.sum()), "c2c_weighted_mean_m": float((d[sel] * w[sel]).sum() / w[sel].sum()),
                       "c2c_median_m": float(np.median(d[sel]))}  # fmt: skip
    outside = (~np.isin(mat, non_collab)) | (d > tau)
    return {"outside_true_region": int(outside.sum()), "per_material": per}


@dataclass(frozen=True)
class MaterialGeometry:
    """Geometry of one product on one truth material: accuracy = mean distance (m) product -> truth of the product
    points whose nearest truth point has this material (weighted when the product has weights), and
    completeness = share of this material's truth points with a product point within tau."""

    points: int
    accuracy_mean_m: float
    accuracy_median_m: float
    completeness: float


def product_geometry(
    points_world: np.ndarray,
    weights: np.ndarray | None,
    truth_world: np.ndarray,
    truth_material: np.ndarray,
    tau: float,
    truth_tree=None,
) -> dict[int, MaterialGeometry]:
    """Per truth material (and -1 = all): :class:`MaterialGeometry` of a product (points (N, 3) world, float64)."""
    from scipy.spatial import cKDTree

    tree = truth_tree if truth_tree is not None else cKDTree(truth_world)
    out: dict[int, MaterialGeometry] = {}
    if len(points_world):
        d, idx = tree.query(points_world, k=1, workers=-1)
        back, _ = cKDTree(points_world).query(truth_world, k=1, workers=-1, distance_upper_bound=tau)
    else:
        d, idx, back = np.zeros(0), np.zeros(0, np.int64), np.full(len(truth_world), np.inf)
    w = np.ones(len(d)) if weights is None else np.asarray(weights, np.float64)
    mat = truth_material[idx]
    for m in [-1, *np.unique(truth_material).tolist()]:
        sel = np.ones(len(d), bool) if m == -1 else mat == m
        tsel = np.ones(len(truth_world), bool) if m == -1 else truth_material == m
        acc = float((d[sel] * w[sel]).sum() / max(w[sel].sum(), 1e-30)) if sel.any() else float("nan")
        med = float(np.median(d[sel])) if sel.any() else float("nan")
        out[int(m)] = MaterialGeometry(int(sel.sum()), acc, med, float(np.mean(back[tsel] < tau)))
    return out


def print_geometry(products: dict[str, dict[int, MaterialGeometry]], names: dict[int, str], tau: float) -> None:
    """One table per measure: rows = products, columns = truth materials."""
    mats = sorted({m for p in products.values() for m in p})
    head = "".join(f"{names.get(m, 'all'):>12s}" for m in mats)
    tables = (
        ("accuracy mean (mm, product -> truth)", "accuracy_mean_m", 1000, "{:12.2f}"),
        ("accuracy median (mm)", "accuracy_median_m", 1000, "{:12.2f}"),
        ("points", "points", 1, "{:12d}"),
        (f"completeness at tau {tau * 1000:.1f} mm", "completeness", 1, "{:12.3f}"),
    )
    for title, key, scale, fmt in tables:
        print(f"  {title}:\n  {'product':24s}{head}")
        for name, per in products.items():
            cells = ""
            for m in mats:
                v = getattr(per[m], key) if m in per else float("nan")
                cells += fmt.format(v * scale if key != "points" else v) if v == v else f"{'-':>12s}"
            print(f"  {name:24s}{cells}")


def bench_geometry(args: argparse.Namespace) -> None:
    """Step 1 of issue 14's geometry: where the error comes from. MVS points kept / dropped, the trained splats'
    centres (opacity-weighted), the survey-point selection and the merged point products, per truth material."""
    from scipy.spatial import cKDTree

    from core.io import read_point_cloud
    from core.io.colmap import read_model
    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.clean import SurveyPointOptions, select_survey_points

    scene, project = Path(args.scene), Path(args.project)
    meta = json.loads((scene / "scene.json").read_text())
    names = {int(m["id"]): m["name"] for m in meta["materials"]}
    tau = args.tau_gsd * meta["gsd_m"]
    cameras, _ = read_model(project / "sparse")
    fused = read_point_cloud(project / "dense" / "fused.ply")
    masks, needs, _ = truth_inputs(scene, cameras, fused.world_positions)
    if args.needs == "classified":  # the pipeline's classification and masks instead of the scene's truth
        from core.io.images import read_image

        cls = read_point_cloud(project / "classify" / "points.ply")
        needs = np.asarray(cls.fields["needs_splats"]).astype(bool)
        masks = {}
        for view in cameras:
            path = project / "classify" / "masks" / f"{view.name}.png"
            if path.is_file():
                masks[view.name] = read_image(path, grayscale=True) > 127
    lidar = read_point_cloud(scene / "gt" / "lidar.ply")
    truth = lidar.world_positions
    material = np.asarray(lidar.fields["material"]).astype(np.int64)
    tree = cKDTree(truth)
    spacing = float(np.median(cKDTree(fused.positions[~needs]).query(fused.positions[~needs], k=2)[0][:, 1]))
    print(f"scene {scene}, project {project}: {len(fused)} fused points, {int(needs.sum())} need splats "
          f"({args.needs}); tau {tau * 1000:.2f} mm; trusted MVS spacing {spacing * 1000:.2f} mm; "
          f"{load()}")  # fmt: skip
    world = fused.world_positions
    products = {
        "MVS-only": product_geometry(world, None, truth, material, tau, tree),
        "MVS kept (trusted)": product_geometry(world[~needs], None, truth, material, tau, tree),
        "MVS dropped (needs)": product_geometry(world[needs], None, truth, material, tau, tree),
    }
    from dataclasses import replace

    from core.io.gaussian_ply import read_gaussian_ply as _read_gs

    trusted_local = fused.with_origin(cameras.origin).positions[~needs]
    mvs_gs = _read_gs(project / "export" / "mvs_gaussians.ply")
    needs_gs = mvs_gs.subset(needs)
    needs_kept = {}
    for rim in args.rim:
        o = replace(SurveyPointOptions(), shape_checks=False, max_rim_spacing=rim if rim > 0 else None)
        sel = select_survey_points(needs_gs, cameras, masks, trusted_local, spacing, o)
        needs_kept[rim] = needs_gs.world_means[sel.keep]
        print(f"MVS needs points, view rules, rim {rim}: {sel.counts}")
        products[f"MVS needs, views, rim {rim:g}"] = product_geometry(
            needs_gs.world_means[sel.keep], None, truth, material, tau, tree)  # fmt: skip
    for spec in args.points:  # point products as written (e.g. a project's export/merged_points.ply)
        label, _, path = spec.partition("=")
        cloud = read_point_cloud(path)
        products[label] = product_geometry(cloud.world_positions, None, truth, material, tau, tree)
    for spec in args.splats:
        label, _, path = spec.partition("=")
        splats = read_gaussian_ply(path)
        w = splats.opacities.astype(np.float64)
        products[f"{label} centres (α-w)"] = product_geometry(splats.world_means, w, truth, material, tau, tree)
        products[f"merged all {label}"] = product_geometry(
            np.concatenate([world[~needs], splats.world_means]), None, truth, material, tau, tree)  # fmt: skip
        for rim in args.rim:
            o = replace(SurveyPointOptions(), max_rim_spacing=rim if rim > 0 else None, min_opacity=args.min_opacity)
            sel = select_survey_points(splats, cameras, masks, trusted_local, spacing, o)
            print(f"survey-point selection of {label}, rim {rim}: {sel.counts}")
            kept = splats.world_means[sel.keep]
            products[f"{label} pts rim {rim:g}"] = product_geometry(kept, None, truth, material, tau, tree)
            products[f"merged {label} rim {rim:g}"] = product_geometry(
                np.concatenate([world[~needs], kept]), None, truth, material, tau, tree)  # fmt: skip
            products[f"merged+MVSn {label} rim {rim:g}"] = product_geometry(
                np.concatenate([world[~needs], needs_kept[rim], kept]), None, truth, material, tau, tree)  # fmt: skip
    print_geometry(products, names, tau)
    if args.json:
        Path(args.json).write_text(json.dumps({k: {str(m): vars(g) for m, g in v.items()} for k, v in products.items()},
                                              indent=1))  # fmt: skip


def evaluate(name, gaussians, test_cams, scene: Path, masks_dir: Path, lpips_model, out_dir):
    from eval.render_eval import evaluate_gaussians

    res = evaluate_gaussians(gaussians, test_cams, list(test_cams), scene / "test", masks_dir, lpips_model,
                             out_dir, name)  # fmt: skip
    return res


def fmt_scores(s) -> str:
    if s is None:
        return "n/a"
    m = s.mean
    lp = "n/a" if m.lpips is None else f"{m.lpips:.3f}"
    return f"PSNR {m.psnr:6.2f} dB  SSIM {m.ssim:.3f}  LPIPS {lp}"


def bench_tabletop(args: argparse.Namespace) -> None:
    from core.io import read_point_cloud
    from core.io.colmap import read_model
    from core.io.gaussian_ply import read_gaussian_ply, write_gaussian_ply
    from core.io.images import read_image
    from eval.lpips import LPIPS
    from fusion.clean import CleanOptions, clean_splats
    from fusion.merge import merge_hybrid
    from fusion.train import DefaultStrategy, TrainOptions, train_splats
    from fusion.train.init import InitOptions, seed_splats

    scene, project = Path(args.scene), Path(args.project)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cameras, sfm = read_model(project / "sparse")
    fused = read_point_cloud(project / "dense" / "fused.ply")
    mvs = read_gaussian_ply(project / "export" / "mvs_gaussians.ply")
    images = {v.name: read_image(scene / "images" / v.name) for v in cameras}
    masks, needs, non_collab = truth_inputs(scene, cameras, fused.world_positions)
    test_cams, _ = read_model(scene / "sparse" / "test")
    test_masks = out / "truth_masks_test"
    test_masks.mkdir(exist_ok=True)
    from core.io.images import write_image

    for label in sorted((scene / "gt" / "labels" / "test").glob("*.png")):
        lab = read_image(label, grayscale=True)
        write_image(test_masks / label.name, (np.isin(lab, non_collab) * 255).astype(np.uint8))
    try:
        lpips_model = LPIPS.from_path(args.lpips)
    except Exception as err:  # noqa: BLE001
        print("LPIPS left out:", err)
        lpips_model = None
    print(f"scene {scene}: {len(cameras)} training views, {len(fused)} fused points, {int(needs.sum())} need splats, "
          f"{sum(int(m.sum()) for m in masks.values())} mask pixels; {load()}")  # fmt: skip

    results = {}
    if args.only == "baseline":
        return bench_baseline(args, cameras, sfm, images, test_cams, scene, test_masks, lpips_model, out, results)
    t0 = time.perf_counter()
    init = seed_splats(cameras, masks, images, fused.positions, fused.colors, needs, sfm.positions, sfm.colors,
                       InitOptions(rays_per_view=args.rays, seed=args.seed))  # fmt: skip
    t_init = time.perf_counter() - t0
    print(f"init: {len(init.gaussians)} seeds (mvs {init.from_mvs}, sfm {init.from_sfm}, rays {init.from_rays}, "
          f"no depth {init.rays_without_depth}) in {t_init:.1f} s")  # fmt: skip
    context = mvs.subset(~needs)
    strategy = DefaultStrategy(cap=args.cap, refine_start=args.refine_start, refine_every=args.refine_every,
                               reset_every=args.reset_every)  # fmt: skip
    from fusion.train import HardViewOptions, PriorOptions

    priors = None
    if args.depth_prior > 0 or args.normal_prior > 0:
        priors = PriorOptions(args.depth_prior, args.normal_prior, args.prior_border if args.prior_border > 0 else None)
    opts = TrainOptions(iterations=args.iterations, downscale=args.downscale, seed=args.seed, strategy=strategy,
                        sh_degree=args.sh_degree, lr_sh_dc=args.lr_sh_dc, flat=args.flat,
                        patience=args.patience, priors=priors,
                        hard_views=HardViewOptions() if args.hard_views else None,
                        photometric=args.photometric)  # fmt: skip
    print(f"training options: {opts}")
    tr = train_splats(cameras, images, masks, init.gaussians, context, opts)
    print(f"hybrid training: {tr.iterations} it in {tr.seconds:.1f} s ({tr.seconds / tr.iterations:.3f} s/it), "
          f"{len(tr.splats)} splats, views {tr.views_used}, context {tr.context_total} ({tr.context_culled} culled), "
          f"early stop {tr.stopped_early}, refine {tr.refine}; {load()}")  # fmt: skip
    print(f"priors: {tr.prior_views} views, {tr.prior_pixels} prior pixels; steps per view {tr.view_steps}")
    for c in tr.history:
        print(f"   step {c.step:5d}  loss {c.loss:.4f}  hold-out PSNR {c.holdout_psnr:6.2f}  n {c.gaussians}  "
              f"{c.seconds:6.1f} s  prior depth {c.prior_depth:.4f}  normal {c.prior_normal:.4f}")  # fmt: skip
    t1 = time.perf_counter()
    cleaned = clean_splats(tr.splats, cameras, masks, CleanOptions())
    t_clean = time.perf_counter() - t1
    print(f"clean: {cleaned.counts} in {t_clean:.1f} s")
    from core.io import read_point_cloud as _read

    lidar = _read(scene / "gt" / "lidar.ply")
    lmat = np.asarray(lidar.fields["material"]).astype(np.int64)
    tau = 3 * json.loads((scene / "scene.json").read_text())["gsd_m"]
    g_before = splat_geometry(tr.splats, lidar.world_positions, lmat, non_collab, tau)
    g_after = splat_geometry(cleaned.splats, lidar.world_positions, lmat, non_collab, tau)
    print(f"splats outside the true region (nearest truth collaborative or > {tau * 1000:.1f} mm): "
          f"{g_before['outside_true_region']} of {len(tr.splats)} before cleaning, "
          f"{g_after['outside_true_region']} of {len(cleaned.splats)} after")  # fmt: skip
    for m, v in g_after["per_material"].items():
        print(f"   material {m}: {v['n']} splats, opacity-weighted mean C2C {1000 * v['c2c_weighted_mean_m']:.2f} mm, "
              f"median {1000 * v['c2c_median_m']:.2f} mm")  # fmt: skip
    merged = merge_hybrid(mvs, cleaned.splats, needs).gaussians
    from scipy.spatial import cKDTree

    from fusion.clean import SurveyPointOptions, select_survey_points
    from fusion.merge import subset

    trusted = mvs.subset(~needs).with_origin(cameras.origin).means
    spacing = float(np.median(cKDTree(trusted).query(trusted, k=2)[0][:, 1]))
    sel = select_survey_points(cleaned.splats, cameras, masks, trusted, spacing, SurveyPointOptions())
    print(f"survey points from splats: {sel.counts} (trusted MVS spacing {spacing * 1000:.2f} mm)")
    from dataclasses import replace

    sel_mvs = select_survey_points(mvs.subset(needs), cameras, masks, trusted, spacing,
                                   replace(SurveyPointOptions(), shape_checks=False))  # fmt: skip
    print(f"survey points from needs_splats MVS points: {sel_mvs.counts}")
    needs_left_out = needs.copy()
    needs_left_out[np.flatnonzero(needs)[sel_mvs.keep]] = False  # as the merge stage does
    points = merge_hybrid(mvs, subset(cleaned.splats, sel.keep), needs_left_out).gaussians
    meta = json.loads((scene / "scene.json").read_text())
    names = {int(m["id"]): m["name"] for m in meta["materials"]}
    tree = cKDTree(lidar.world_positions)
    geo = {
        "MVS-only": product_geometry(fused.world_positions, None, lidar.world_positions, lmat, tau, tree),
        "splat centres (α-w)": product_geometry(
            cleaned.splats.world_means, cleaned.splats.opacities, lidar.world_positions, lmat, tau, tree
        ),  # fmt: skip
        "merged, every splat": product_geometry(merged.world_means, None, lidar.world_positions, lmat, tau, tree),
        "merged points": product_geometry(points.world_means, None, lidar.world_positions, lmat, tau, tree),
    }
    print_geometry(geo, names, tau)
    (out / "geometry.json").write_text(
        json.dumps({k: {str(m): vars(g) for m, g in v.items()} for k, v in geo.items()}, indent=1)
    )
    write_gaussian_ply(out / "merged.ply", merged, extra_fields=True)
    write_gaussian_ply(out / "splats.ply", tr.splats, extra_fields=True)
    hybrid_time = t_init + tr.seconds + t_clean
    results["merged"] = evaluate("merged", merged, test_cams, scene, test_masks, lpips_model, out)
    results["mvs"] = evaluate("mvs", mvs, test_cams, scene, test_masks, lpips_model, out)
    results["splats_only"] = evaluate("splats", cleaned.splats, test_cams, scene, test_masks, lpips_model, out)
    print(f"hybrid time (init + train + clean, MVS excluded): {hybrid_time:.1f} s")
    if args.only == "both":
        bench_baseline(args, cameras, sfm, images, test_cams, scene, test_masks, lpips_model, out, results)
        return
    report(results, out, load)


def bench_baseline(args, cameras, sfm, images, test_cams, scene, test_masks, lpips_model, out, results) -> None:
    """The whole-scene 3DGS baseline: same trainer, mask = whole image, no context, SfM init, same cap."""
    from core.io.gaussian_ply import write_gaussian_ply
    from fusion.train import DefaultStrategy, TrainOptions, train_splats
    from fusion.train.init import sfm_seeds

    strategy = DefaultStrategy(cap=args.cap, refine_start=args.refine_start, refine_every=args.refine_every,
                               reset_every=args.reset_every)  # fmt: skip
    base_init = sfm_seeds(sfm.positions, sfm.colors, cameras.origin)
    bopts = TrainOptions(iterations=args.baseline_iterations, downscale=args.downscale, seed=args.seed,
                         strategy=strategy, sh_degree=args.sh_degree, lr_sh_dc=args.lr_sh_dc,
                         patience=args.patience)  # fmt: skip
    base = train_splats(cameras, images, None, base_init, None, bopts)
    print(f"baseline training: {base.iterations} it in {base.seconds:.1f} s "
          f"({base.seconds / base.iterations:.3f} s/it), {len(base.splats)} splats; {load()}")  # fmt: skip
    for c in base.history:
        print(f"   step {c.step:5d}  loss {c.loss:.4f}  hold-out PSNR {c.holdout_psnr:6.2f}  n {c.gaussians}  "
              f"{c.seconds:6.1f} s")  # fmt: skip
    write_gaussian_ply(out / "baseline.ply", base.splats)
    results["baseline"] = evaluate("baseline", base.splats, test_cams, scene, test_masks, lpips_model, out)
    report(results, out, load)


def report(results, out: Path, load_fn) -> None:
    print(f"\nheld-out views, {load_fn()}:")
    for name, r in results.items():
        print(f"  {name:12s} masked: {fmt_scores(r.masked)} | whole: {fmt_scores(r.full)}")
    summary = {
        name: {"masked": None if r.masked is None else r.masked.as_dict(), "whole": r.full.as_dict()}
        for name, r in results.items()
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    return None


def bench_score(args: argparse.Namespace) -> None:
    """Held-out metrics of saved products: MVS-only, merged (cleaned / uncleaned splats) and baseline PLYs."""
    from core.io import read_point_cloud
    from core.io.colmap import read_model
    from core.io.gaussian_ply import read_gaussian_ply
    from core.io.images import read_image, write_image
    from eval.lpips import LPIPS
    from fusion.merge import merge_hybrid

    scene, project, out = Path(args.scene), Path(args.project), Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cameras, _ = read_model(project / "sparse")
    fused = read_point_cloud(project / "dense" / "fused.ply")
    mvs = read_gaussian_ply(project / "export" / "mvs_gaussians.ply")
    _, needs, non_collab = truth_inputs(scene, cameras, fused.world_positions)
    test_cams, _ = read_model(scene / "sparse" / "test")
    test_masks = out / "truth_masks_test"
    test_masks.mkdir(exist_ok=True)
    for label in sorted((scene / "gt" / "labels" / "test").glob("*.png")):
        lab = read_image(label, grayscale=True)
        write_image(test_masks / label.name, (np.isin(lab, non_collab) * 255).astype(np.uint8))
    lpips_model = LPIPS.from_path(args.lpips)
    products = {"mvs": mvs}
    for spec in args.ply:
        name, _, path = spec.partition("=")
        gs = read_gaussian_ply(path)
        if name.startswith("merged_from_"):  # raw trained splats: merge them with the trusted MVS first
            gs = merge_hybrid(mvs, gs, needs).gaussians
        products[name] = gs
    results = {}
    for name, gs in products.items():
        results[name] = evaluate(name, gs, test_cams, scene, test_masks, lpips_model, out)
        print(f"  {name:22s} ({len(gs)} Gaussians) masked: {fmt_scores(results[name].masked)} | "
              f"whole: {fmt_scores(results[name].full)}; {load()}", flush=True)  # fmt: skip
    report(results, out, load)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("speed")
    s.add_argument("--n", type=int, default=50_000)
    s.add_argument("--size", default="256x192")
    s.add_argument("--steps", type=int, default=20)
    s.add_argument("--sh-degree", type=int, default=0)
    s.add_argument("--mask-share", type=float, default=0.0, help="0 < S < 1: a masked view, both render modes")
    t = sub.add_parser("tabletop")
    t.add_argument("--scene", required=True)
    t.add_argument("--project", required=True)
    t.add_argument("--out", default="bench/out/train_tabletop")
    t.add_argument("--iterations", type=int, default=2000)
    t.add_argument("--baseline-iterations", type=int, default=0)
    t.add_argument("--downscale", type=int, default=1)
    t.add_argument("--cap", type=int, default=60_000)
    t.add_argument("--rays", type=int, default=400)
    t.add_argument("--refine-start", type=int, default=300)
    t.add_argument("--refine-every", type=int, default=100)
    t.add_argument("--reset-every", type=int, default=3000)
    t.add_argument("--sh-degree", type=int, default=3)
    t.add_argument("--lr-sh-dc", type=float, default=2.5e-3)
    t.add_argument("--patience", type=int, default=3)
    t.add_argument("--flat", action="store_true")
    t.add_argument("--depth-prior", type=float, default=0.0, help="0 with --normal-prior 0: no priors (default)")
    t.add_argument("--normal-prior", type=float, default=0.0)
    t.add_argument("--prior-border", type=float, default=8.0, help="px; <= 0: the whole mask")
    t.add_argument("--hard-views", action="store_true")
    t.add_argument("--photometric", choices=("l1_ssim", "smoothl1_msssim"), default="l1_ssim")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--only", choices=("hybrid", "baseline", "both"), default="both")
    t.add_argument("--lpips", default="/work/shared/data/lpips/alexnet_lpips_v0.1.npz")
    c = sub.add_parser("score")
    c.add_argument("--scene", required=True)
    c.add_argument("--project", required=True)
    c.add_argument("--out", default="bench/out/train_score")
    c.add_argument("--ply", nargs="*", default=[], help="NAME=PATH; names merged_from_* are merged with MVS first")
    c.add_argument("--lpips", default="/work/shared/data/lpips/alexnet_lpips_v0.1.npz")
    g = sub.add_parser("geometry")
    g.add_argument("--scene", required=True)
    g.add_argument("--project", required=True)
    g.add_argument("--splats", nargs="*", default=[], help="LABEL=PATH of trained (cleaned) splats")
    g.add_argument("--points", nargs="*", default=[], help="LABEL=PATH of point clouds to measure as they are")
    g.add_argument("--needs", choices=("truth", "classified"), default="truth")
    g.add_argument("--tau-gsd", type=float, default=3.0)
    g.add_argument("--json", default="")
    g.add_argument("--min-opacity", type=float, default=0.5, help="survey-point rule for splats")
    g.add_argument("--rim", type=float, nargs="*", default=[0.0], help="rim limits in spacings (0: no rim test)")
    args = p.parse_args()
    torch.manual_seed(0)
    commands = {"speed": bench_speed, "tabletop": bench_tabletop, "score": bench_score, "geometry": bench_geometry}
    commands[args.cmd](args)


if __name__ == "__main__":
    main()
