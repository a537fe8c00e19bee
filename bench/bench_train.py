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
    The hybrid on a data_synth scene that ``hybridsplat run`` has processed, through the functions the pipeline's
    stages call, with the stages' options types: ``train`` = fusion.train.masked.train_in_masks (seeds, masked
    training, MVS Gaussians of trusted points frozen as context), ``clean`` = fusion.clean.clean_splats, ``merge``
    = fusion.survey.hybrid_products (viewer set and survey points). Their inputs are read as the stages read them
    (hybridsplat.project_io: the dense workspace's cameras and photos, held-out photos excluded; the MVS Gaussians;
    the SfM points), except that the classify and masks stages' products come from the scene's truth: training
    masks = the non-collaborative materials of the label images, and per MVS Gaussian ``needs_splats`` and the
    class (the shipped class set's class of the material's kind) of the nearest LiDAR point. Options not on the
    command line are the stages' defaults. Then the whole-scene baseline (the ``baseline`` stage's
    fusion.train.masked.train_whole_scene: same trainer, mask = whole image, no context, SfM init, same cap) and the
    held-out metrics (PSNR / SSIM / LPIPS, inside the non-collaborative masks and whole image) of merged, MVS-only
    and baseline, with times. Every figure is printed with the machine load. Options:
    per-material geometry of MVS-only, the splat centres, merged with every splat
    and the merged survey points is printed and written to OUT/geometry.json. The products go where a project keeps
    them (hybridsplat.layout.ProjectLayout of OUT): the merged set, the trained splats and the baseline.

``python bench/bench_train.py score --scene SCENE --project PROJECT [--ply NAME=PLY ...]``
    Held-out metrics of saved products: the project's MVS Gaussians and each PLY (``merged_from_*``: raw trained
    splats, merged first as the merge stage merges them, with the truth's ``needs_splats``).

``python bench/bench_train.py geometry --scene SCENE --project PROJECT [--splats L=PLY ...] [--points L=PLY ...]``
    Where the geometric error comes from, per truth material (the LiDAR's ``material`` field): accuracy (mean
    distance product → truth, by the nearest truth point's material; splat centres opacity-weighted) and
    completeness at τ = 3 GSD (truth → product) of MVS-only, the MVS points kept / dropped (``needs_splats`` from the
    truth, or ``--needs classified`` with the pipeline's classified cloud and region masks), the ``needs_splats``
    MVS points and splats that pass the merge stage's survey-point selection (fusion.survey.survey_selections) at
    each ``--rim`` limit, and merged products; ``--points`` measures written point clouds (e.g. a project's
    ``ProjectLayout.merged_points_ply``) as they are.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402


def load() -> str:
    return "load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


# -- speed -------------------------------------------------------------------------------------------
PART_NAMES = ("render fwd", "loss fwd", "backward", "adam", "densify stats", "total")


@dataclass(frozen=True)
class SpeedCase:
    """The speed section's random scene (``random_scene``), its one training view and the render modes to time
    (``loss_pixels_only`` False, and True too with a mask)."""

    scene: Any
    view: Any
    modes: tuple[bool, ...]
    width: int
    height: int


@dataclass
class SpeedTimes:
    """Per render mode: wall and process-CPU seconds of each part (PART_NAMES) per iteration, and the kernel times
    ((wall, CPU) per iteration, by kernel name) inside them."""

    wall: dict[bool, dict[str, list[float]]]
    cpu: dict[bool, dict[str, list[float]]]
    kernels: dict[bool, dict[str, list[tuple[float, float]]]]


def speed_case(args: argparse.Namespace) -> SpeedCase:
    from fusion.render import render
    from fusion.render.synthetic import random_scene
    from fusion.train.views import TrainView, active_tile_prefix, pixels_within_reach

    width, height = (int(x) for x in args.size.split("x"))
    scene = random_scene(args.n, width, height, seed=0, sh_degree=args.sh_degree)
    truth = random_scene(args.n, width, height, seed=1, sh_degree=0)
    with torch.no_grad():
        target = render(*truth.params, *truth.camera, backend="cpu").colour.clamp(0, 1)
    if 0 < args.mask_share < 1:
        rows, cols = np.mgrid[0:height, 0:width]
        r = ((cols + 0.5 - width / 2) / width) ** 2 + ((rows + 0.5 - height / 2) / height) ** 2
        mask = r <= np.quantile(r, args.mask_share)
        view = TrainView("bench", target, torch.from_numpy(mask), torch.zeros((height, width), dtype=torch.bool),
                         scene.viewmat, scene.K, width, height, int(mask.sum()), active_tile_prefix(mask),
                         pixels_within_reach(mask))  # fmt: skip
        reach = float(view.render_pixels.mean())
        print(f"mask: {mask.mean():.1%} of the pixels, {reach:.1%} within the SSIM reach")
        return SpeedCase(scene, view, (False, True), width, height)
    view = TrainView("bench", target, None, torch.zeros((height, width), dtype=torch.bool), scene.viewmat,
                     scene.K, width, height, width * height, None)  # fmt: skip
    return SpeedCase(scene, view, (False,), width, height)


def speed_loop(args: argparse.Namespace, case: SpeedCase) -> SpeedTimes:
    """``args.steps`` timed training iterations after 3 warm-up ones, the render modes side by side."""
    from fusion.render.threads import kernel_times, record_times
    from fusion.train.loss import masked_photometric_loss
    from fusion.train.params import make_optimizer, make_parameters
    from fusion.train.render import render_step
    from fusion.train.strategy import DefaultStrategy

    view, modes = case.view, case.modes
    params = make_parameters(case.scene.trainable)
    optimizer = make_optimizer(params, {k: 1e-4 for k in params})
    strategy = DefaultStrategy(cap=args.n)  # bookkeeping every step; no refinement before step 500
    state = strategy.initial_state(args.n)
    bg = torch.zeros(3)
    times = SpeedTimes({m: {k: [] for k in PART_NAMES} for m in modes},
                       {m: {k: [] for k in PART_NAMES} for m in modes},  # process CPU seconds: less load-sensitive
                       {m: {} for m in modes})  # fmt: skip

    def clock() -> tuple[float, float]:
        return time.perf_counter(), time.process_time()

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
            strategy.after_backward(state, out.means2d, case.width, case.height, i)
            strategy.refine(state, params, optimizer, i + 1, 10**9, 1.0, torch.Generator())
            c5 = clock()
            if i == 0:
                print(f"first iteration (numba compile or cache load, thread pool): {c5[0] - c0[0]:.2f} s")
            if i >= 3:  # warm-up (kernel compilation, thread pool)
                spans = ((c0, c1), (c1, c2), (c2, c3), (c3, c4), (c4, c5), (c0, c5))
                for k, (a, b) in zip(PART_NAMES, spans, strict=True):
                    times.wall[only][k].append(b[0] - a[0])
                    times.cpu[only][k].append(b[1] - a[1])
                for k, v in kernel_times().items():
                    times.kernels[only].setdefault(k, []).append(v)
    record_times(False)
    return times


def print_speed(args: argparse.Namespace, case: SpeedCase, times: SpeedTimes) -> None:
    print(f"one training iteration, {args.n} Gaussians, {case.width}x{case.height}, SH degree {args.sh_degree}, "
          f"{torch.get_num_threads()} torch threads; after: {load()}")  # fmt: skip
    parts, cpu = times.wall, times.cpu
    for only in case.modes:
        if len(case.modes) > 1:
            print("compositing " + ("only the loss's pixels" if only else "every pixel of the active tiles"))
        for k, v in parts[only].items():
            print(f"  {k:14s} wall median {1000 * np.median(v):7.1f} ms  min {1000 * np.min(v):7.1f} ms   "
                  f"CPU median {1000 * np.median(cpu[only][k]):7.1f} ms")  # fmt: skip
        print("  kernels inside those parts (median per iteration):")
        for k, v in times.kernels[only].items():
            arr = np.array(v)
            print(f"    {k:14s} wall {1000 * np.median(arr[:, 0]):7.2f} ms   CPU {1000 * np.median(arr[:, 1]):7.2f} ms")
    if len(case.modes) > 1:
        ratio = {w: np.median(parts[True][w]) / np.median(parts[False][w]) for w in ("render fwd", "backward", "total")}
        cpu_ratio = np.median(cpu[True]["total"]) / np.median(cpu[False]["total"])
        print("  loss pixels only / every active pixel: render fwd {:.2f}, backward {:.2f}, total {:.2f} (CPU {:.2f})"
              .format(ratio["render fwd"], ratio["backward"], ratio["total"], cpu_ratio))  # fmt: skip
        return
    total = float(np.median(parts[False]["total"]))
    peer = 0.209 if args.n >= 50_000 else 0.119
    print(f"  OpenSplat 1.1.5 CPU: {peer:.3f} s/iter -> ours {total:.3f} s/iter, ratio {peer / total:.2f}x "
          f"(target <= 0.100 s)")  # fmt: skip


def bench_speed(args: argparse.Namespace) -> None:
    case = speed_case(args)
    print_speed(args, case, speed_loop(args, case))


# -- the project and the scene's truth -----------------------------------------------------------------
@dataclass(frozen=True)
class SceneTruth:
    """A data_synth scene's truth: its folder (data_synth.layout.SceneLayout), origin (world, metres), GSD (metres),
    material legend (id → name, id → kind, non-collaborative ids) and LiDAR points (world, float64) with their
    material id and a KD-tree over them."""

    scene: Any
    origin: np.ndarray
    gsd: float
    names: dict[int, str]
    kinds: dict[int, str]
    non_collab: list[int]
    lidar_world: np.ndarray
    lidar_material: np.ndarray
    tree: Any


def read_truth(scene: str | Path) -> SceneTruth:
    from scipy.spatial import cKDTree

    from core.io import read_point_cloud
    from data_synth.layout import SceneLayout

    layout = SceneLayout(Path(scene))
    meta = json.loads(layout.scene_json.read_text())
    lidar = read_point_cloud(layout.lidar_ply)
    world = lidar.world_positions
    return SceneTruth(
        layout, np.asarray(meta.get("origin", (0.0, 0.0, 0.0)), np.float64), float(meta["gsd_m"]),
        {int(m["id"]): m["name"] for m in meta["materials"]}, {int(m["id"]): m["kind"] for m in meta["materials"]},
        [int(m["id"]) for m in meta["materials"] if not m["collaborative"]], world,
        np.asarray(lidar.fields["material"]).astype(np.int64), cKDTree(world),
    )  # fmt: skip


@dataclass(frozen=True)
class ProjectInputs:
    """What the train, clean, merge and baseline stages read from a finished project, read as they read it:
    the dense workspace's cameras (world frame at the origin the sfm stage recorded), the SfM points (world), the
    MVS Gaussians moved to the cameras' origin (one per fused point), the fused cloud and the training photos
    (undistorted, held-out photos excluded; empty unless asked for)."""

    layout: Any
    cameras: Any
    sfm: Any
    mvs: Any
    fused: Any
    images: dict[str, np.ndarray]


def read_project(project: str | Path, images: bool) -> ProjectInputs:
    from core.io import read_point_cloud
    from core.io.gaussian_ply import read_gaussian_ply
    from core.io.images import read_image
    from hybridsplat.layout import ProjectLayout
    from hybridsplat.pipeline import load_config
    from hybridsplat.project_io import read_project_model
    from hybridsplat.source import resolve_source

    layout = ProjectLayout(project)
    ws = layout.dense_workspace
    cameras, _ = read_project_model(layout, ws.sparse)
    _, sfm = read_project_model(layout, layout.sparse)
    mvs = read_gaussian_ply(layout.mvs_gaussians).with_origin(cameras.origin)
    photos = {}
    if images:
        held_out = set(resolve_source(load_config(layout.root).input).holdout_names)  # never trained on
        photos = {v.name: read_image(ws.images / v.name) for v in cameras if v.name not in held_out}
    return ProjectInputs(layout, cameras, sfm, mvs, read_point_cloud(layout.fused_ply), photos)


@dataclass(frozen=True)
class TruthInputs:
    """The scene's truth in place of the classify and masks stages' products.

    masks: photo name → (H, W) bool at the camera's size, True on non-collaborative materials (the training
    masks, and the region masks of the merge stage's view tests). needs: (N,) bool per MVS Gaussian, its nearest
    LiDAR point is non-collaborative. classes: (N,) int64 class code per MVS Gaussian (the shipped class set's class
    of that point's material kind); class_codes: that set's needs-splats classes, name → code."""

    masks: dict[str, np.ndarray]
    needs: np.ndarray
    classes: np.ndarray
    class_codes: dict[str, int]


def truth_inputs(truth: SceneTruth, cameras: Any, mvs: Any) -> TruthInputs:
    import cv2

    from classify.classes import load_classes
    from core.io.images import read_image

    masks = {}
    for view in cameras:
        labels = read_image(truth.scene.labels("train", view.name), grayscale=True)
        cam = cameras.camera_of(view)
        if labels.shape != (cam.height, cam.width):  # the dense workspace's photos may be downscaled
            labels = cv2.resize(labels, (cam.width, cam.height), interpolation=cv2.INTER_NEAREST)
        masks[view.name] = np.isin(labels, truth.non_collab)
    _, idx = truth.tree.query(mvs.world_means, k=1, workers=-1)
    material = truth.lidar_material[idx]
    class_set = load_classes()
    code_of = np.zeros(max(truth.kinds) + 1, np.int64)
    for m, kind in truth.kinds.items():
        code_of[m] = class_set.code_of_kind(kind)
    codes = {c.name: c.code for c in class_set.classes if c.needs_splats}
    return TruthInputs(masks, np.isin(material, truth.non_collab), code_of[material], codes)


def merge_products(inputs: ProjectInputs, truth_in: TruthInputs, splats: Any) -> Any:
    """The merge stage's products (fusion.survey.hybrid_products, its default options) of ``splats`` and the
    project's MVS Gaussians, with the truth's masks, ``needs_splats`` and classes."""
    from fusion.merge_options import MergeOptions
    from fusion.survey import hybrid_products, view_tests

    views = view_tests(inputs.cameras, truth_in.masks, inputs.mvs, truth_in.needs, splats)
    products = hybrid_products(inputs.mvs, splats, truth_in.needs, views, MergeOptions(), truth_in.classes,
                               truth_in.class_codes)  # fmt: skip
    products.counts["trusted_spacing_m"] = views.spacing
    return products


# -- held-out views ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class HeldOut:
    """The scene's held-out views: their cameras (at the scene's origin, as the eval stage reads them), photos,
    the folder of their truth masks (non-collaborative materials, ``<stem>.png``) and the LPIPS network (or None)."""

    cameras: Any
    photos: Path
    masks: Path
    lpips: Any


def held_out_views(truth: SceneTruth, out: Path, lpips_path: str, lpips_required: bool) -> HeldOut:
    from core.io.images import read_image, write_image
    from eval.lpips import LPIPS
    from hybridsplat.project_io import read_model_at

    cameras, _ = read_model_at(truth.scene.sparse_test, truth.origin)
    masks = out / "truth_masks_test"
    masks.mkdir(parents=True, exist_ok=True)
    for view in cameras:
        label = truth.scene.labels("test", view.name)
        if label.is_file():
            lab = read_image(label, grayscale=True)
            write_image(masks / f"{Path(view.name).stem}.png", (np.isin(lab, truth.non_collab) * 255).astype(np.uint8))
    try:
        lpips = LPIPS.from_path(lpips_path)
    except Exception as err:  # noqa: BLE001
        if lpips_required:
            raise
        print("LPIPS left out:", err)
        lpips = None
    return HeldOut(cameras, truth.scene.test_dir, masks, lpips)


def evaluate(name: str, gaussians: Any, held: HeldOut, out_dir: Path) -> Any:
    from eval.render_eval import evaluate_gaussians

    return evaluate_gaussians(gaussians, held.cameras, list(held.cameras), held.photos, held.masks, held.lpips,
                              out_dir, name)  # fmt: skip


def fmt_scores(s) -> str:
    if s is None:
        return "n/a"
    m = s.mean
    lp = "n/a" if m.lpips is None else f"{m.lpips:.3f}"
    return f"PSNR {m.psnr:6.2f} dB  SSIM {m.ssim:.3f}  LPIPS {lp}"


def report(results: dict[str, Any], out: Path) -> None:
    print(f"\nheld-out views, {load()}:")
    for name, r in results.items():
        print(f"  {name:12s} masked: {fmt_scores(r.masked)} | whole: {fmt_scores(r.full)}")
    summary = {
        name: {"masked": None if r.masked is None else r.masked.as_dict(), "whole": r.full.as_dict()}
        for name, r in results.items()
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1))


# -- geometry against the truth ----------------------------------------------------------------------
def splat_geometry(splats, truth: SceneTruth, tau: float) -> dict:
    """Opacity-weighted C2C (metres) of splat centres to the LiDAR truth, per nearest material, and the count of
    splats outside the true region (nearest truth point collaborative, or farther than ``tau``)."""
    if len(splats) == 0:
        return {"outside_true_region": 0, "per_material": {}}
    d, idx = truth.tree.query(splats.world_means, k=1, workers=-1)
    w = splats.opacities.astype(np.float64)
    mat = truth.lidar_material[idx]
    per = {}
    for m in np.unique(mat):
        sel = mat == m
        per[int(m)] = {"n": int(sel.sum()), "c2c_weighted_mean_m": float((d[sel] * w[sel]).sum() / w[sel].sum()),
                       "c2c_median_m": float(np.median(d[sel]))}  # fmt: skip
    outside = (~np.isin(mat, truth.non_collab)) | (d > tau)
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


def truth_geometry(truth: SceneTruth, tau: float):
    """``measure(points_world, weights=None)``: :func:`product_geometry` against the scene's LiDAR truth."""

    def measure(points_world: np.ndarray, weights: np.ndarray | None = None) -> dict[int, MaterialGeometry]:
        return product_geometry(points_world, weights, truth.lidar_world, truth.lidar_material, tau, truth.tree)

    return measure


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


def write_geometry(path: Path, products: dict[str, dict[int, MaterialGeometry]]) -> None:
    path.write_text(json.dumps({k: {str(m): vars(g) for m, g in v.items()} for k, v in products.items()}, indent=1))


def rim_rule(rim: float, min_opacity: float, needs_mvs: bool = True) -> Any:
    """The merge stage's options (MergeOptions) with the survey-point rim limit ``rim`` (spacings; 0: no rim test)
    for splats and ``needs_splats`` MVS points alike, and the splats' opacity floor ``min_opacity``."""
    from fusion.merge_options import MergeOptions
    from hybridsplat.options import options_with

    limit = rim if rim > 0 else "none"
    return options_with(MergeOptions, {"points.max_rim_spacing": limit, "points.min_opacity": min_opacity,
                                       "needs_mvs_max_rim_spacing": limit, "needs_mvs": needs_mvs},
                        where="bench_train.py geometry")  # fmt: skip


@dataclass
class GeometryRows:
    """The geometry section's inputs and rows: the merge stage's view tests (fusion.survey.ViewTests), the MVS
    Gaussians and their ``needs_splats`` (N,) bool, ``measure`` (truth_geometry) and the rows so far (label →
    per-material geometry)."""

    views: Any
    mvs: Any
    needs: np.ndarray
    measure: Any
    products: dict[str, dict[int, MaterialGeometry]]


def needs_rows(args: argparse.Namespace, rows: GeometryRows) -> dict[float, np.ndarray]:
    """Rows of the ``needs_splats`` MVS points that pass the merge stage's selection at each rim limit; returns
    those points (world) by rim."""
    from fusion.survey import survey_selections

    mvs, needs = rows.mvs, rows.needs
    no_splats = mvs.subset(np.zeros(len(mvs), bool))
    needs_world = mvs.subset(needs).world_means
    kept = {}
    for rim in args.rim:
        _, sel = survey_selections(rows.views, mvs, needs, no_splats, rim_rule(rim, args.min_opacity))
        kept[rim] = needs_world[sel.keep] if sel is not None else np.zeros((0, 3))
        print(f"MVS needs points, view rules, rim {rim}: {None if sel is None else sel.counts}")
        rows.products[f"MVS needs, views, rim {rim:g}"] = rows.measure(kept[rim])
    return kept


def splat_rows(args: argparse.Namespace, rows: GeometryRows, label: str, splats: Any, needs_kept: dict) -> None:
    """Rows of one set of trained splats: centres, merged with the trusted MVS points, and the splats that pass
    the merge stage's selection at each rim limit (alone, merged, merged with the kept ``needs_splats`` points)."""
    from fusion.survey import survey_selections

    measure, products = rows.measure, rows.products
    trusted = rows.mvs.world_means[~rows.needs]
    products[f"{label} centres (α-w)"] = measure(splats.world_means, splats.opacities.astype(np.float64))
    products[f"merged all {label}"] = measure(np.concatenate([trusted, splats.world_means]))
    for rim in args.rim:
        rule = rim_rule(rim, args.min_opacity, needs_mvs=False)
        sel, _ = survey_selections(rows.views, rows.mvs, rows.needs, splats, rule)
        print(f"survey-point selection of {label}, rim {rim}: {sel.counts}")
        kept = splats.world_means[sel.keep]
        products[f"{label} pts rim {rim:g}"] = measure(kept)
        products[f"merged {label} rim {rim:g}"] = measure(np.concatenate([trusted, kept]))
        products[f"merged+MVSn {label} rim {rim:g}"] = measure(np.concatenate([trusted, needs_kept[rim], kept]))


def bench_geometry(args: argparse.Namespace) -> None:
    """Step 1 of issue 14's geometry: where the error comes from. MVS points kept / dropped, the trained splats'
    centres (opacity-weighted), the survey-point selection and the merged point products, per truth material."""
    from core.io import read_point_cloud
    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.survey import view_tests
    from hybridsplat import project_io

    truth = read_truth(args.scene)
    inputs = read_project(args.project, images=False)
    mvs, tau = inputs.mvs, args.tau_gsd * truth.gsd
    if args.needs == "classified":  # the pipeline's classification and region masks instead of the scene's truth
        needs = project_io.needs_splats_per_gaussian(inputs.layout, mvs)
        masks = project_io.read_region_masks(inputs.layout, inputs.cameras)
    else:
        truth_in = truth_inputs(truth, inputs.cameras, mvs)
        needs, masks = truth_in.needs, truth_in.masks
    views = view_tests(inputs.cameras, masks, mvs, needs, mvs.subset(needs))
    print(f"scene {args.scene}, project {args.project}: {len(inputs.fused)} fused points, {int(needs.sum())} need "
          f"splats ({args.needs}); tau {tau * 1000:.2f} mm; trusted MVS spacing {views.spacing * 1000:.2f} mm; "
          f"{load()}")  # fmt: skip
    measure = truth_geometry(truth, tau)
    world = mvs.world_means
    rows = GeometryRows(views, mvs, needs, measure, {
        "MVS-only": measure(inputs.fused.world_positions),
        "MVS kept (trusted)": measure(world[~needs]),
        "MVS dropped (needs)": measure(world[needs]),
    })  # fmt: skip
    needs_kept = needs_rows(args, rows)
    for spec in args.points:  # point products as written (e.g. a project's ProjectLayout.merged_points_ply)
        label, _, path = spec.partition("=")
        rows.products[label] = measure(read_point_cloud(path).world_positions)
    for spec in args.splats:
        label, _, path = spec.partition("=")
        splat_rows(args, rows, label, read_gaussian_ply(path), needs_kept)
    products = rows.products
    print_geometry(products, truth.names, tau)
    if args.json:
        write_geometry(Path(args.json), products)


# -- tabletop ----------------------------------------------------------------------------------------
def shared_training(args: argparse.Namespace) -> dict[str, Any]:
    """Options both trainings take from the command line, by their paths in the train and baseline stages'
    options (config.toml's spelling)."""
    paths = {
        "training.downscale": args.downscale,
        "training.sh_degree": args.sh_degree,
        "training.lr_sh_dc": args.lr_sh_dc,
        "training.patience": args.patience,
        "training.strategy.cap": args.cap,
        "training.strategy.refine_start": args.refine_start,
        "training.strategy.refine_every": args.refine_every,
        "training.strategy.reset_every": args.reset_every,
    }
    if args.max_image_size is not None:
        paths["max_image_size"] = args.max_image_size
    return paths


def hybrid_options(args: argparse.Namespace) -> Any:
    """The train stage's options (fusion.train.masked.MaskedTrainingOptions) of the command line."""
    from fusion.train.masked import MaskedTrainingOptions
    from hybridsplat.options import options_with

    paths = {
        **shared_training(args),
        "training.iterations": args.iterations,
        "init.rays_per_view": args.rays,
    }
    if args.splats_per_mask_pixel is not None:
        paths["splats_per_mask_pixel"] = args.splats_per_mask_pixel
    return options_with(MaskedTrainingOptions, paths, where="bench_train.py tabletop")


def baseline_options(args: argparse.Namespace) -> Any:
    """The baseline stage's options (fusion.train.masked.WholeSceneOptions) of the command line."""
    from fusion.train.masked import WholeSceneOptions
    from hybridsplat.options import options_with

    paths = {"enabled": True, **shared_training(args)}
    if args.baseline_iterations > 0:
        paths["training.iterations"] = args.baseline_iterations
    return options_with(WholeSceneOptions, paths, where="bench_train.py tabletop")


def train_hybrid(args: argparse.Namespace, inputs: ProjectInputs, truth_in: TruthInputs) -> tuple[Any, float]:
    """The train stage's training (train_in_masks) on the truth's masks; the result and the call's seconds."""
    from fusion.train.masked import train_in_masks

    opts = hybrid_options(args)
    print(f"training options: {opts}")
    masks = {k: m for k, m in truth_in.masks.items() if k in inputs.images}  # held-out photos: never trained on
    sfm = inputs.sfm
    sfm_points = (sfm.world_positions - inputs.cameras.origin, sfm.colors) if len(sfm) else None
    t0 = time.perf_counter()
    tr, init, used = train_in_masks(inputs.cameras, inputs.images, masks, inputs.mvs, truth_in.needs, sfm_points,
                                    opts, args.seed)  # fmt: skip
    seconds = time.perf_counter() - t0
    print(f"init: {len(init.gaussians)} seeds (mvs {init.from_mvs}, sfm {init.from_sfm}, rays {init.from_rays}, "
          f"no depth {init.rays_without_depth}) in {seconds - tr.seconds:.1f} s (the call less the training); "
          f"downscale {used['downscale']}, cap {used['cap']}")  # fmt: skip
    print(f"hybrid training: {tr.iterations} it in {tr.seconds:.1f} s ({tr.seconds / tr.iterations:.3f} s/it), "
          f"{len(tr.splats)} splats, views {tr.views_used}, context {tr.context_total} ({tr.context_culled} culled), "
          f"early stop {tr.stopped_early}, refine {tr.refine}; {load()}")  # fmt: skip
    print(f"steps per view {tr.view_steps}")
    for c in tr.history:
        print(f"   step {c.step:5d}  loss {c.loss:.4f}  hold-out PSNR {c.holdout_psnr:6.2f}  n {c.gaussians}  "
              f"{c.seconds:6.1f} s")  # fmt: skip
    return tr, seconds


def clean_hybrid(inputs: ProjectInputs, truth_in: TruthInputs, truth: SceneTruth, trained: Any) -> tuple[Any, float]:
    """The clean stage's cleaning (clean_splats, its default options) and where the splats lie against the truth;
    the cleaned splats and the cleaning's seconds."""
    from fusion.clean import clean_splats
    from fusion.clean_options import CleanOptions

    t0 = time.perf_counter()
    cleaned = clean_splats(trained, inputs.cameras, truth_in.masks, CleanOptions())
    seconds = time.perf_counter() - t0
    print(f"clean: {cleaned.counts} in {seconds:.1f} s")
    tau = 3 * truth.gsd
    g_before = splat_geometry(trained, truth, tau)
    g_after = splat_geometry(cleaned.splats, truth, tau)
    print(f"splats outside the true region (nearest truth collaborative or > {tau * 1000:.1f} mm): "
          f"{g_before['outside_true_region']} of {len(trained)} before cleaning, "
          f"{g_after['outside_true_region']} of {len(cleaned.splats)} after")  # fmt: skip
    for m, v in g_after["per_material"].items():
        print(f"   material {m}: {v['n']} splats, opacity-weighted mean C2C {1000 * v['c2c_weighted_mean_m']:.2f} mm, "
              f"median {1000 * v['c2c_median_m']:.2f} mm")  # fmt: skip
    return cleaned.splats, seconds


def merge_hybrid_products(
    inputs: ProjectInputs, truth_in: TruthInputs, truth: SceneTruth, cleaned: Any, out: Path
) -> Any:
    """The merge stage's products of the cleaned splats, their per-material geometry (OUT/geometry.json)."""
    products = merge_products(inputs, truth_in, cleaned)
    c = products.counts
    print(
        f"survey points from splats: {c['point_splats']} (trusted MVS spacing {c['trusted_spacing_m'] * 1000:.2f} mm)"
    )
    print(f"survey points from needs_splats MVS points: {c.get('point_needs_mvs')}")
    print(f"needs_splats MVS points kept by class: {c['point_needs_mvs_classes']}; "
          f"mesh-surface splats: {c.get('surface_splats')}")  # fmt: skip
    tau = 3 * truth.gsd
    measure = truth_geometry(truth, tau)
    geo = {
        "MVS-only": measure(inputs.fused.world_positions),
        "splat centres (α-w)": measure(cleaned.world_means, cleaned.opacities),
        "merged, every splat": measure(products.gaussians.world_means),
        "merged points": measure(products.points.world_means),
    }
    print_geometry(geo, truth.names, tau)
    write_geometry(out / "geometry.json", geo)
    return products


def bench_tabletop(args: argparse.Namespace) -> None:
    from core.io.gaussian_ply import write_gaussian_ply
    from hybridsplat.layout import ProjectLayout

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    truth = read_truth(args.scene)
    inputs = read_project(args.project, images=True)
    truth_in = truth_inputs(truth, inputs.cameras, inputs.mvs)
    held = held_out_views(truth, out, args.lpips, lpips_required=False)
    print(f"scene {args.scene}: {len(inputs.images)} training views, {len(inputs.fused)} fused points, "
          f"{int(truth_in.needs.sum())} need splats, {sum(int(m.sum()) for m in truth_in.masks.values())} mask "
          f"pixels; {load()}")  # fmt: skip
    results: dict[str, Any] = {}
    if args.only == "baseline":
        return bench_baseline(args, inputs, held, out, results)
    trained, t_train = train_hybrid(args, inputs, truth_in)
    cleaned, t_clean = clean_hybrid(inputs, truth_in, truth, trained.splats)
    merged = merge_hybrid_products(inputs, truth_in, truth, cleaned, out).gaussians
    products = ProjectLayout(out)  # the bench's products where a project keeps them
    products.export_dir.mkdir(exist_ok=True)
    products.splats_dir.mkdir(exist_ok=True)
    write_gaussian_ply(products.merged_ply, merged, extra_fields=True)
    write_gaussian_ply(products.trained_splats, trained.splats, extra_fields=True)
    results["merged"] = evaluate("merged", merged, held, out)
    results["mvs"] = evaluate("mvs", inputs.mvs, held, out)
    results["splats_only"] = evaluate("splats", cleaned, held, out)
    print(f"hybrid time (init + train + clean, MVS excluded): {t_train + t_clean:.1f} s")
    if args.only == "both":
        return bench_baseline(args, inputs, held, out, results)
    report(results, out)


def bench_baseline(args, inputs: ProjectInputs, held: HeldOut, out: Path, results: dict[str, Any]) -> None:
    """The baseline stage's whole-scene 3DGS (train_whole_scene): same trainer, mask = whole image, no context,
    SfM init, same cap."""
    from core.io.gaussian_ply import write_gaussian_ply
    from fusion.train.masked import train_whole_scene
    from hybridsplat.layout import ProjectLayout

    opts = baseline_options(args)
    sfm = inputs.sfm
    sfm_points = (sfm.world_positions - inputs.cameras.origin, sfm.colors if len(sfm) else None)
    base, downscale = train_whole_scene(inputs.cameras, inputs.images, sfm_points, opts, args.seed)
    print(f"baseline training: {base.iterations} it in {base.seconds:.1f} s "
          f"({base.seconds / base.iterations:.3f} s/it), {len(base.splats)} splats, downscale {downscale}; "
          f"{load()}")  # fmt: skip
    for c in base.history:
        print(f"   step {c.step:5d}  loss {c.loss:.4f}  hold-out PSNR {c.holdout_psnr:6.2f}  n {c.gaussians}  "
              f"{c.seconds:6.1f} s")  # fmt: skip
    path = ProjectLayout(out).baseline_splats
    path.parent.mkdir(parents=True, exist_ok=True)
    write_gaussian_ply(path, base.splats)
    results["baseline"] = evaluate("baseline", base.splats, held, out)
    report(results, out)


def bench_score(args: argparse.Namespace) -> None:
    """Held-out metrics of saved products: MVS-only, merged (cleaned / uncleaned splats) and baseline PLYs."""
    from core.io.gaussian_ply import read_gaussian_ply

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    truth = read_truth(args.scene)
    inputs = read_project(args.project, images=False)
    truth_in = truth_inputs(truth, inputs.cameras, inputs.mvs)
    held = held_out_views(truth, out, args.lpips, lpips_required=True)
    products = {"mvs": inputs.mvs}
    for spec in args.ply:
        name, _, path = spec.partition("=")
        gs = read_gaussian_ply(path)
        if name.startswith("merged_from_"):  # raw trained splats: merged with the MVS Gaussians first
            gs = merge_products(inputs, truth_in, gs).gaussians
        products[name] = gs
    results = {}
    for name, gs in products.items():
        results[name] = evaluate(name, gs, held, out)
        print(f"  {name:22s} ({len(gs)} Gaussians) masked: {fmt_scores(results[name].masked)} | "
              f"whole: {fmt_scores(results[name].full)}; {load()}", flush=True)  # fmt: skip
    report(results, out)


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
    t.add_argument("--baseline-iterations", type=int, default=0, help="0: the baseline stage's default")
    t.add_argument("--downscale", type=int, default=1, help="at least this (see --max-image-size)")
    t.add_argument("--max-image-size", type=int, default=None, help="default: the train stage's (0: no limit)")
    t.add_argument("--cap", type=int, default=60_000)
    t.add_argument("--splats-per-mask-pixel", type=float, default=None, help="default: the train stage's")
    t.add_argument("--rays", type=int, default=400)
    t.add_argument("--refine-start", type=int, default=300)
    t.add_argument("--refine-every", type=int, default=100)
    t.add_argument("--reset-every", type=int, default=3000)
    t.add_argument("--sh-degree", type=int, default=3)
    t.add_argument("--lr-sh-dc", type=float, default=2.5e-3)
    t.add_argument("--patience", type=int, default=3)
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
