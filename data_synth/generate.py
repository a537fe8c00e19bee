"""Entry point: build, render, scan and write one synthetic scene.

Random streams are derived from the seed per purpose (layout, each view's jitter, LiDAR noise, statistics),
so the output does not depend on the order in which views are rendered. The scene is written into a
temporary sibling folder and renamed into place at the end: an interrupted run leaves no half scene.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from core.cameras import Cameras
from core.errors import ConfigError
from data_synth import writer
from data_synth.layout import SceneLayout
from data_synth.lidar import simulate_lidar
from data_synth.materials import MATERIALS, Material, material_by_id
from data_synth.presets import Preset, apply_overrides, get_preset, preset_for_seed, preset_summary
from data_synth.raytrace import RayTracer
from data_synth.rig import build_cameras
from data_synth.scenes import LAYOUTS
from data_synth.stats import ColorSpread, GradientStats, color_spread, gradient_by_material
from data_synth.targets import TargetSet, place_targets, with_targets
from data_synth.textures import TextureField

ProgressFn = Callable[[str, int, int], None]
"""``progress(stage, done, total)``: called as work advances (stage names: render, lidar, stats, write)."""

_STREAM = {"layout": 1, "train": 2, "test": 3, "lidar": 4, "stats": 5, "rig": 6, "targets": 7}


def _rng(seed: int, purpose: str, index: int = 0) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, _STREAM[purpose], index]))


def generate_scene(
    preset: str,
    out_dir: str | os.PathLike[str],
    seed: int = 0,
    progress: ProgressFn | None = None,
    overwrite: bool = False,
    **overrides: object,
) -> Path:
    """Generate the scene ``preset`` (tiny, tabletop, aerial, demo, textured, random-object, random-aerial) into
    ``out_dir`` and return its path.

    ``overrides`` are preset overrides (see :func:`data_synth.presets.apply_overrides`: views, test_views,
    width, height, supersample, max_depth, noise, georef, origin, targets). An existing non-empty ``out_dir`` is
    refused unless ``overwrite``. Same preset, overrides and seed give byte-identical files.
    """
    if not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    seeded, layout_info = preset_for_seed(get_preset(preset), _rng(seed, "layout"), _rng(seed, "rig"))
    p = apply_overrides(seeded, **overrides)
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not overwrite:
        raise ConfigError("output folder exists and is not empty; choose another or pass overwrite", out)
    report = progress or (lambda stage, done, total: None)

    origin = np.asarray(p.origin, dtype=np.float64)
    mesh = LAYOUTS[p.layout](_rng(seed, "layout"))
    train, test = build_cameras(p.rig, p.width, p.height, origin)
    legend = {m.id: m for m in MATERIALS}
    tracer = RayTracer(mesh, legend, TextureField(seed, p.texture_scale), p.environment, p.render)
    targets = TargetSet()
    if p.targets > 0:
        placed = place_targets(tracer, train, p.targets, _rng(seed, "targets"))
        mesh, targets = with_targets(mesh, placed)
        tracer = RayTracer(mesh, legend, tracer.textures, p.environment, p.render, targets=targets)
    used = [material_by_id(i) for i in np.unique(mesh.face_material).tolist()]

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp_root = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        layout = SceneLayout(tmp_root)
        views = _render_views(layout, tracer, train, test, seed, report)

        report("lidar", 0, 1)
        cloud = simulate_lidar(tracer, p.lidar, p.noise, tracer.materials, _rng(seed, "lidar"), origin)
        report("lidar", 1, 1)

        report("stats", 0, 1)
        spread = color_spread(tracer, train, views.images, used, _rng(seed, "stats"), p.stats_points)
        gradients = gradient_by_material(list(views.images.values()), views.labels, used)
        report("stats", 1, 1)

        report("write", 0, 1)
        writer.write_cameras(layout, train, test)
        writer.write_mesh(layout.mesh, mesh, origin)
        writer.write_cloud(layout, cloud)
        info = _scene_info(p, seed, origin, train, test, used, views.depths, spread, gradients, len(cloud))
        if layout_info is not None:  # a procedural preset: what the seed drew
            info["layout"] = layout_info
        if targets.targets:
            info["targets"] = targets.describe(origin)
            writer.write_gcp(layout, targets, origin)
        writer.write_scene_json(layout, info)
        report("write", 1, 1)
        _move_into_place(tmp_root, out)
    except BaseException:
        shutil.rmtree(tmp_root, ignore_errors=True)
        raise
    return out


@dataclass
class _TrainViews:
    """What the statistics need from the rendered training views, in rendering order."""

    images: dict[str, np.ndarray] = field(default_factory=dict)
    """Image name -> (H, W, 3) rendered photo."""
    labels: list[np.ndarray] = field(default_factory=list)
    """(H, W) material id per pixel."""
    depths: list[np.ndarray] = field(default_factory=list)
    """(H, W) depth in metres (0 where no surface)."""


def _render_views(
    layout: SceneLayout, tracer: RayTracer, train: Cameras, test: Cameras, seed: int, report: ProgressFn
) -> _TrainViews:
    """Render and write every training then test view (each with its own random stream); keep the training ones."""
    total = len(train) + len(test)
    done = 0
    kept = _TrainViews()
    for split, cams in (("train", train), ("test", test)):
        for view in cams:
            r = tracer.render_view(cams.camera_of(view), view, _rng(seed, split, view.image_id))
            writer.write_view(layout, split, view.name, r.image, r.depth, r.labels)
            if split == "train":
                kept.images[view.name] = r.image
                kept.labels.append(r.labels)
                kept.depths.append(r.depth)
            done += 1
            report("render", done, total)
    return kept


def _scene_info(
    p: Preset,
    seed: int,
    origin: np.ndarray,
    train: Cameras,
    test: Cameras,
    used: list[Material],
    depths: list[np.ndarray],
    spread: ColorSpread,
    gradients: GradientStats,
    lidar_points: int,
) -> dict[str, object]:
    """The content of scene.json; ``gsd_m`` is the median training depth over the focal length (metres/pixel)."""
    fx = train.cameras[1].focal[0]
    gsd = float(np.median([np.median(d[d > 0]) for d in depths if (d > 0).any()]) / fx)
    return {
        "preset": p.name,
        "seed": seed,
        "units": "m",
        "origin": [float(v) for v in origin],
        "gsd_m": gsd,
        "image_size": {"width": p.width, "height": p.height},
        "camera": {"model": "PINHOLE", "params": [float(v) for v in train.cameras[1].params]},
        "rig": preset_summary(p),
        "materials": [m.legend_entry() for m in used],
        "cross_view_color_std": spread.exact,
        "cross_view_color_std_image": spread.image,
        "cross_view_color_points": spread.points,
        "image_gradient": gradients.mean,
        "image_gradient_median": gradients.median,
        "lidar_points": lidar_points,
        "views": {"train": [v.name for v in train], "test": [v.name for v in test]},
        "frames": {"poses": "COLMAP world-to-camera, OpenCV axes, local frame", "up": "+z"},
    }


def _move_into_place(tmp_root: Path, out: Path) -> None:
    if out.exists():
        old = out.with_name(f".{out.name}.old-{os.getpid()}")
        out.rename(old)
        tmp_root.rename(out)
        shutil.rmtree(old, ignore_errors=True)
    else:
        tmp_root.rename(out)
