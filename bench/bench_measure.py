"""Measurement accuracy on a data_synth scene: multi-ray triangulation with the project's own SfM cameras.

Needs a scene (``hybridsplat synth``) and a project made from it with full SfM (``hybridsplat run SCENE --out P
--full-sfm``; the SfM model is aligned to the scene's frame, so its coordinates compare with the truth). E.g.::

    hybridsplat synth --out /tmp/tt --preset tabletop --views 24 --test-views 2 --width 320 --height 240
    hybridsplat run /tmp/tt --out /tmp/tt_proj --full-sfm
    python bench/bench_measure.py --scene /tmp/tt --project /tmp/tt_proj --screenshot /tmp/tt_view.png

Ground truth: N points on collaborative (textured) surfaces of the true mesh, each seen (ray-cast visibility)
in 3–5 training views. Then, for every point:

(a) picks = true projections (true cameras) + Gaussian noise of σ = 0.5 px, triangulated with the project's SfM
    cameras (not the true ones) and σ = 0.5 px; the control (a0) triangulates the same picks with the true cameras;
(b) picks refined by matching a patch of the photo (around the true projection) inside the merged product
    rendered at the SfM camera (``fusion.render``), NCC with a parabolic sub-pixel peak; triangulated with the SfM
    cameras, σ = 0.5 px as well.

Printed: 3D RMSE against the truth, per-axis RMSE, the share of truths inside the χ²₃ 95 % ellipsoid, the mean
predicted σ3D, and for (b) the RMS pick error in pixels; ``--out`` writes the same as JSON. ``--screenshot`` opens
the project in the viewer in headless chromium, measures the first point by two clicks and saves the page.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from core.cameras import Cameras  # noqa: E402
from core.errors import DataError  # noqa: E402
from core.io.colmap import read_model  # noqa: E402
from core.io.images import read_image  # noqa: E402
from eval.measure import CHI2_3_95, MeasuredPoint, Pick, triangulate  # noqa: E402
from hybridsplat.layout import ProjectLayout  # noqa: E402

SIGMA_PX = 0.5


@dataclass(frozen=True)
class Truth:
    """A ground-truth point (scene local frame, metres) and the training images that see it."""

    xyz: np.ndarray
    images: tuple[str, ...]


def load_mesh(path: Path):
    """open3d ray-casting scene of the true mesh, and the per-face material ids."""
    import open3d as o3d
    import plyfile

    ply = plyfile.PlyData.read(str(path))
    v = np.stack([ply["vertex"][k] for k in "xyz"], axis=1).astype(np.float64)
    faces = np.stack(ply["face"]["vertex_indices"]).astype(np.int32)
    material = np.asarray(ply["face"]["material"], np.int32)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    return scene, material


def cast(scene, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hit distances along unit rays (inf when none) and face ids (n,)."""
    import open3d as o3d

    rays = o3d.core.Tensor(np.concatenate([origins, dirs], axis=1).astype(np.float32))
    out = scene.cast_rays(rays)
    return out["t_hit"].numpy().astype(np.float64), out["primitive_ids"].numpy().astype(np.int64)


def sample_truth(
    scene_dir: Path, true_cams: Cameras, sfm_names: set[str], n: int, seed: int, margin: int = 16
) -> list[Truth]:
    """N points on collaborative, textured surfaces, each visible in 3–5 training views registered by SfM."""
    meta = json.loads((scene_dir / "scene.json").read_text())
    collaborative = {int(m["id"]) for m in meta["materials"] if m.get("collaborative", True)}
    mesh, material = load_mesh(scene_dir / "gt" / "mesh.ply")
    rng = np.random.default_rng(seed)
    views = [v for v in true_cams if v.name in sfm_names]
    photos: dict[str, np.ndarray] = {}
    out: list[Truth] = []
    tries = 0
    while len(out) < n and tries < 20000:
        tries += 1
        view = views[rng.integers(len(views))]
        cam = true_cams.camera_of(view)
        pixel = rng.uniform([margin, margin], [cam.width - margin, cam.height - margin])
        d = view.rotation.T @ cam.unproject(pixel[None])[0]
        d /= np.linalg.norm(d)
        t, face = cast(mesh, view.center[None], d[None])
        if not np.isfinite(t[0]) or int(material[face[0]]) not in collaborative:
            continue
        x = view.center + t[0] * d
        seen = []
        for other in views:
            ocam = true_cams.camera_of(other)
            uv, z = true_cams.project(other, x[None])
            u, v = uv[0]
            if z[0] <= 0 or not (margin <= u <= ocam.width - margin and margin <= v <= ocam.height - margin):
                continue
            dist = float(np.linalg.norm(x - other.center))
            th, _ = cast(mesh, other.center[None], ((x - other.center) / dist)[None])
            if abs(th[0] - dist) < 1e-3:
                seen.append(other.name)
        if len(seen) < 3:
            continue
        k = int(rng.integers(3, 6))
        chosen = tuple(sorted(rng.choice(seen, size=min(k, len(seen)), replace=False)))
        photo = photos.setdefault(chosen[0], _gray(scene_dir / "images" / chosen[0]))
        uv, _ = true_cams.project(true_cams.by_name(chosen[0]), x[None])
        c, r = int(uv[0, 0]), int(uv[0, 1])
        if photo[r - 5 : r + 6, c - 5 : c + 6].std() < 6.0:  # too little texture to match a patch
            continue
        out.append(Truth(x, chosen))
    if len(out) < n:
        raise DataError(f"found only {len(out)} of {n} ground-truth points after {tries} tries")
    return out


def _gray(path: Path) -> np.ndarray:
    return read_image(path, grayscale=True).astype(np.float32)


def true_pixel(cams: Cameras, name: str, x: np.ndarray) -> np.ndarray:
    uv, _ = cams.project(cams.by_name(name), x[None])
    return uv[0]


def measure(picks: list[Pick], name: str) -> MeasuredPoint | None:
    try:
        return triangulate(picks, name=name)
    except DataError as err:
        print(f"  {name}: not measured: {err}")
        return None


@dataclass(frozen=True)
class Summary:
    method: str
    measured: int
    rmse_mm: float
    rmse_xyz_mm: tuple[float, float, float]
    median_mm: float
    max_mm: float
    inside_95: float
    mean_sigma3d_mm: float
    median_sigma0: float

    def line(self) -> str:
        x, y, z = self.rmse_xyz_mm
        return (
            f"{self.method:<34} {self.measured:>3}  {self.rmse_mm:8.3f}  ({x:6.3f} {y:6.3f} {z:6.3f})  "
            f"{self.median_mm:7.3f} {self.max_mm:7.3f}  {100 * self.inside_95:6.1f} %  {self.mean_sigma3d_mm:7.3f}  "
            f"{self.median_sigma0:6.2f}"
        )


def summarise(method: str, points: list[MeasuredPoint | None], truths: list[Truth]) -> Summary:
    pairs = [(p, t) for p, t in zip(points, truths, strict=True) if p is not None]
    err = np.stack([p.local - t.xyz for p, t in pairs])
    norm = np.linalg.norm(err, axis=1)
    inside = np.mean([p.mahalanobis2(t.xyz) <= CHI2_3_95 for p, t in pairs])
    return Summary(
        method,
        len(pairs),
        float(1000 * np.sqrt(np.mean(norm**2))),
        tuple(float(v) for v in 1000 * np.sqrt(np.mean(err**2, axis=0))),  # type: ignore[arg-type]
        float(1000 * np.median(norm)),
        float(1000 * norm.max()),
        float(inside),
        float(1000 * np.mean([p.sigma_3d for p, _ in pairs])),
        float(np.median([p.sigma0 for p, _ in pairs])),
    )


def render_views(project: Path, sfm: Cameras, names: set[str], product: str = "merged") -> dict[str, np.ndarray]:
    """Grey renders (H, W) float32 0–255 of the merged product at the SfM cameras (pinhole part); ``product``
    "merged_unrefined": the control with every layer as before the appearance stage."""
    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.render import render_gaussian_set

    layout = ProjectLayout(project)
    gs = read_gaussian_ply(layout.merged_ply)
    if product == "merged_unrefined":
        from hybridsplat.project_io import unrefined_layers

        gs = unrefined_layers(layout, gs)
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name in sorted(names):
            view = sfm.by_name(name)
            img = render_gaussian_set(
                gs, sfm.camera_of(view), view, cameras_origin=sfm.origin, backend="cpu", ignore_distortion=True
            ).to_numpy()
            rgb = np.clip(img.colour, 0, 1) * 255.0
            out[name] = (0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]).astype(np.float32)
    return out


def match_patch(
    photo: np.ndarray, render: np.ndarray, at: np.ndarray, start: np.ndarray, radius: int = 7, search: int = 4
) -> np.ndarray:
    """Where the photo's patch around ``at`` lies in the render, searched within ±``search`` px of ``start``.

    at, start: COLMAP pixels (the feature in the photo; the operator's rough pick in the render). NCC
    (``cv2.TM_CCOEFF_NORMED``) of a (2·radius+1)² patch, peak refined by a parabola per axis.
    """
    import cv2

    size = 2 * radius + 1
    templ = cv2.getRectSubPix(photo, (size, size), (float(at[0] - 0.5), float(at[1] - 0.5)))
    cx, cy = int(round(start[0] - 0.5)), int(round(start[1] - 0.5))
    x0, y0 = cx - radius - search, cy - radius - search
    window = render[max(y0, 0) : y0 + size + 2 * search, max(x0, 0) : x0 + size + 2 * search]
    if window.shape != (size + 2 * search, size + 2 * search):
        raise DataError("patch search window leaves the image")
    score = cv2.matchTemplate(window, templ, cv2.TM_CCOEFF_NORMED)
    iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)

    def vertex(a: float, b: float, c: float) -> float:
        den = a - 2 * b + c
        return 0.0 if abs(den) < 1e-12 else float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))

    dx = vertex(*score[iy, ix - 1 : ix + 2]) if 0 < ix < score.shape[1] - 1 else 0.0
    dy = vertex(*score[iy - 1 : iy + 2, ix]) if 0 < iy < score.shape[0] - 1 else 0.0
    return np.array([x0 + ix + dx + radius + 0.5, y0 + iy + dy + radius + 0.5])


def screenshot(project: Path, truth: Truth, sfm: Cameras, path: Path, exaggeration: float) -> None:
    """Measure ``truth`` in the viewer by two clicks in headless chromium; save a screenshot of the page."""
    from playwright.sync_api import sync_playwright

    from hybridsplat.viewer.app import ViewerApp, ViewerOptions
    from hybridsplat.viewer.browser import (
        CHROMIUM,
        FLAGS,
        browser_missing,
        jump_and_settle,
        screen_position,
        track_camera_reports,
        wait_for,
    )
    from hybridsplat.viewer.project import open_project
    from hybridsplat.viewer.scene import load_project

    reason = browser_missing()
    if reason:
        print(f"screenshot skipped: {reason}")
        return
    app = ViewerApp(
        load_project(project),
        ViewerOptions(port=0, pick_sigma_px=SIGMA_PX, exaggeration=exaggeration),
        open_project(project),
    )
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=list(FLAGS))
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.set_default_timeout(60_000)
            tracked = track_camera_reports(app.server)
            page.goto(f"http://127.0.0.1:{app.port}/")
            page.wait_for_selector("canvas")
            client = wait_for(lambda: next(iter(app.server.get_clients().values()), None), 60, "the page")
            reports = wait_for(lambda: tracked.get(client.client_id), 30, "camera tracking")
            box = page.locator("canvas").first.bounding_box()
            for name in truth.images[:2]:
                view = sfm.by_name(name)
                jump_and_settle(app, client, view, reports)
                page.mouse.click(*screen_position(client, truth.xyz, box))
                try:
                    wait_for(lambda v=view: any(p.image == v.name for p in app.session.current), 30, "the click")
                except TimeoutError:
                    raise TimeoutError(f"click in {name} not taken; viewer said: {app.messages[-3:]}") from None
            page.get_by_role("button", name="Finish point").click()
            point = wait_for(lambda: app.session.points[0] if app.session.points else None, 30, "the point")
            # Step back along the last camera's axis so that the measured point and its ellipsoid are in view.
            view = sfm.by_name(truth.images[2] if len(truth.images) > 2 else truth.images[0])
            app.jump_to(client, view)
            time.sleep(4.0)
            page.screenshot(path=str(path))
            browser.close()
        err = np.linalg.norm(point.local - truth.xyz) * 1000
        print(
            f"screenshot: {path} (viewer measured P1 {err:.2f} mm from the truth, σ3D {point.sigma_3d * 1000:.2f} mm)"
        )
    finally:
        app.stop()


def _picks(cams: Cameras, pixels: dict[str, np.ndarray]) -> list[Pick]:
    """One pick (σ = ``SIGMA_PX``) per image name → pixel, with the camera and view of ``cams``."""
    return [Pick(cams.camera_of(cams.by_name(n)), cams.by_name(n), px, SIGMA_PX) for n, px in pixels.items()]


def _refine_in_renders(
    scene: Path,
    project: Path,
    sfm: Cameras,
    true_cams: Cameras,
    truths: list[Truth],
    noisy: list[dict],
    product: str = "merged",
) -> tuple[list[MeasuredPoint | None], list[np.ndarray]]:
    """Method (b): per truth, the picks found by patch matching in the merged product rendered at the SfM cameras,
    triangulated (None with fewer than 2 picks); and every pick's error against the true projection (pixels)."""
    renders = render_views(project, sfm, {n for t in truths for n in t.images}, product)
    photos = {n: _gray(scene / "images" / n) for n in renders}
    refined, pick_err = [], []
    for i, t in enumerate(truths):
        pixels = {}
        for n in t.images:
            cam = sfm.camera_of(sfm.by_name(n))
            try:
                found = match_patch(photos[n], renders[n], true_pixel(true_cams, n, t.xyz), noisy[i][n])
            except DataError:
                continue
            # The render is the pinhole part of the SfM camera: back to its (distorted) pixel coordinates.
            pixels[n] = cam.distort_pixels(found[None])[0] if cam.model.has_distortion else found
            pick_err.append(pixels[n] - true_pixel(true_cams, n, t.xyz))
        refined.append(measure(_picks(sfm, pixels), f"T{i}") if len(pixels) >= 2 else None)
    return refined, pick_err


def _parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, required=True)
    ap.add_argument("--project", type=Path, required=True)
    ap.add_argument("--points", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="JSON with every figure")
    ap.add_argument(
        "--product",
        choices=("merged", "merged_unrefined"),
        default="merged",
        help="what (b) matches in: the merged product, or the control with every layer as before the appearance stage",
    )
    ap.add_argument("--screenshot", type=Path, default=None, help="PNG of the viewer with a measurement")
    ap.add_argument("--exaggeration", type=float, default=20.0, help="ellipsoid scale in the screenshot")
    ap.add_argument("--picks-out", type=Path, default=None, help="PICKS.json of the (a) picks, for hybridsplat measure")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = _parse_args(argv)
    t0 = time.perf_counter()
    true_cams, _ = read_model(args.scene / "sparse" / "0")
    sfm, _ = read_model(ProjectLayout(args.project).sparse)
    sfm_names = {v.name for v in sfm}
    truths = sample_truth(args.scene, true_cams, sfm_names, args.points, args.seed)
    rng = np.random.default_rng(args.seed + 1)
    noisy = [{n: true_pixel(true_cams, n, t.xyz) + rng.normal(0.0, SIGMA_PX, 2) for n in t.images} for t in truths]

    a0 = [measure(_picks(true_cams, px), f"T{i}") for i, px in enumerate(noisy)]
    a = [measure(_picks(sfm, px), f"T{i}") for i, px in enumerate(noisy)]
    refined, pick_err = _refine_in_renders(args.scene, args.project, sfm, true_cams, truths, noisy, args.product)

    meta = json.loads((args.scene / "scene.json").read_text())
    gsd_mm = 1000 * float(meta.get("gsd_m") or float("nan"))
    rows = [
        summarise("(a0) true cameras, true px + 0.5 px", a0, truths),
        summarise("(a) SfM cameras, true px + 0.5 px", a, truths),
        summarise("(b) SfM cameras, patch match in render", refined, truths),
    ]
    pick_norm = np.linalg.norm(np.asarray(pick_err), axis=1) if pick_err else np.full(1, np.nan)
    pick_rms = float(np.sqrt(np.mean(pick_norm**2)))
    _print_table(args, meta, gsd_mm, truths, rows, pick_norm, pick_rms, len(pick_err))
    print(f"total {time.perf_counter() - t0:.1f} s")
    if args.out:
        args.out.write_text(
            json.dumps(
                {
                    "scene": str(args.scene),
                    "project": str(args.project),
                    "gsd_mm": gsd_mm,
                    "views_per_point": [len(t.images) for t in truths],
                    "rows": [r.__dict__ for r in rows],
                    "b_pick_rms_px": pick_rms,
                },
                indent=2,
            )
        )
    if args.picks_out:
        _write_picks(args.picks_out, noisy, args.project)
    if args.screenshot:
        truth = min(truths, key=lambda t: _off_centre(true_cams, t))
        screenshot(args.project, truth, sfm, args.screenshot, args.exaggeration)


def _print_table(
    args: argparse.Namespace,
    meta: dict,
    gsd_mm: float,
    truths: list[Truth],
    rows: list[Summary],
    pick_norm: np.ndarray,
    pick_rms: float,
    n_picks: int,
) -> None:
    print(f"scene {args.scene} ({meta.get('preset')}), project {args.project}; GSD {gsd_mm:.3f} mm")
    print(f"{len(truths)} points, views per point: {[len(t.images) for t in truths]}")
    print(f"{'method':<34} {'n':>3}  {'RMSE mm':>8}  {'(x, y, z) mm':^22}  {'median':>7} {'max':>7}  {'in 95%':>8}  "
          f"{'σ3D mm':>7}  {'σ0':>6}")  # fmt: skip
    for r in rows:
        print(r.line())
    print(
        f"(b) pick error against the true projection: RMS {pick_rms:.3f} px, median {np.median(pick_norm):.3f} px, "
        f"> 2 px: {100 * np.mean(pick_norm > 2):.0f} % (over {n_picks} picks)"
    )


def _write_picks(path: Path, noisy: list[dict], project: Path) -> None:
    """The (a) picks as a PICKS.json for ``hybridsplat measure`` (consecutive points paired as distances)."""
    from eval.measure.picks import ImagePick, PicksFile, PointPicks, write_picks

    points = tuple(
        PointPicks(f"T{i}", tuple(ImagePick(n, float(px[0]), float(px[1]), SIGMA_PX) for n, px in p.items()))
        for i, p in enumerate(noisy)
    )
    write_picks(path, PicksFile(points, tuple((f"T{i}", f"T{i + 1}") for i in range(len(points) - 1))))
    print(f"wrote {path}: run `hybridsplat measure {path} --project {project}`")


def _off_centre(true_cams: Cameras, t: Truth) -> float:
    """How far from the image centre (share of the image size) the first two projections of ``t`` are, at worst:
    the screenshot measures the most central point (clear of notifications at the corners)."""
    worst = 0.0
    for n in t.images[:2]:
        cam = true_cams.camera_of(true_cams.by_name(n))
        u, v = true_pixel(true_cams, n, t.xyz)
        worst = max(worst, abs(u / cam.width - 0.5), abs(v / cam.height - 0.5))
    return worst


if __name__ == "__main__":
    main()
