"""Scene presets (frozen dataclasses) and their overrides.

Fixed layouts (a new seed only jitters the same objects by about a centimetre and reseeds the textures):

- ``tiny``: unit-test scene, 10 training + 2 test views at 96×72, seconds to generate.
- ``tabletop``: artefact scale (~0.5 m of objects on a 1 m table), 72 training views at 640×480 on three rings.
- ``demo``: ``tabletop`` reduced to the size of the built-in demo (every material; 24 training + 4 test views at
  320×240 on two rings; a coarser LiDAR scan).
- ``textured``: ``demo`` with every object textured and no wire cage, seen from farther away: only
  collaborative materials and (almost) no MVS holes, nothing needs splats (the pipeline should skip training).
- ``aerial``: UAV scale (200 m terrain, switchgear yard with a 28 m pylon), nadir grid at 40 m + obliques at 60 m.

Procedural families (:mod:`data_synth.procedural`): the seed draws the whole layout, for scoring how classifiers
and pipeline defaults generalise to scenes they never saw:

- ``random-object``: 4–10 objects (boxes, cylinders upright or lying, spheres, panels, rods, wire cages, mounds,
  model buildings; from 1 mm thin members to 20 cm) on a 0.9–1.2 m table of wood, noise or stone texture, inside
  a disc of 0.22–0.39 m radius (an object that finds no free place is left out); an orbit rig of 2 or 3 rings
  between 15° and 70° elevation at 2.6–3.4 times the objects' extent (72 training views in all, 8 test views,
  640×480), four terrestrial LiDAR stations around it.
- ``random-aerial``: 5–14 objects (buildings 8–22 m with a roof, cabinets, tanks, spherical tanks, walls, poles,
  lattice towers 10–25 m high, spoil mounds) on a 52–84 × 44–68 m yard slab (gravel or blank concrete) in hilly
  grass terrain (220 m); a nadir grid at 35–55 m (at least 12 m above the tallest object), 60–80 % forward and
  50–70 % side overlap (so the number of views follows the seed), four oblique passes at 1.2–1.6 times the nadir
  height tilted 35–50°, airborne LiDAR lines covering the block.

For both, the seed also draws the objects' materials from the whole legend (:mod:`data_synth.materials`): thin
members get the thin materials, every other object a collaborative (textured at the scale its pattern suits) or a
non-collaborative one (textureless, metal, mirror, glass), with at least one of each per layout; and the sun
(azimuth 0–360°, elevation 25–70°). The rig's ranges belong to the preset (:attr:`Preset.rig_ranges`), the objects'
to the layout (:data:`data_synth.procedural.FAMILIES`). ``scene.json`` records the drawn layout under ``layout``
(support, and per object its shape, sizes, pose, materials and bounding box) and the drawn rig under ``rig``.

Seed convention for the procedural families: seeds 0–99 (:data:`TUNING_SEEDS`) are for choosing defaults and
training (classifiers, thresholds, pipeline options); seeds 100–199 (:data:`SCORING_SEEDS`) are reserved for
scoring: a figure that reports generalisation is measured on them, and nothing it compares may have been chosen
or trained on them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from core.errors import ConfigError
from data_synth.lidar import AirborneScan, RangeNoise, TerrestrialScan
from data_synth.lighting import Environment
from data_synth.procedural import AerialRigRanges, OrbitRigRanges, draw_layout, draw_rig, nadir_overlap
from data_synth.raytrace import RenderSettings
from data_synth.rig import AerialRig, OrbitRig

GEOREF_ORIGIN = (500000.0, 5000000.0, 300.0)
"""A UTM-like origin (easting, northing, height) used by ``georef=True``."""

TUNING_SEEDS = range(0, 100)
"""Seeds of the procedural presets for choosing defaults and training (see the module docstring)."""
SCORING_SEEDS = range(100, 200)
"""Seeds of the procedural presets reserved for scoring generalisation: never tune or train on them."""


@dataclass(frozen=True)
class Preset:
    """Everything that defines a scene except the seed.

    layout: name of the scene builder in :data:`data_synth.scenes.LAYOUTS`.
    width, height: image size in pixels. rig: camera rig. lidar: scanner geometry; noise: its range noise.
    render: supersampling and bounce depth. environment: sun and sky. texture_scale: multiplies every
    material's pattern size. origin: world coordinates of the local origin (metres).
    stats_points: surface samples per material for the cross-view colour statistics.
    rig_ranges: set for a procedural preset (``layout`` is then a family of :mod:`data_synth.procedural`): the
    seed draws the rig, the LiDAR scan and the sun from these ranges (:func:`preset_for_seed`); ``rig``, ``lidar``
    and ``environment`` are the bases they start from (views, test views, field of view, scan step, sky).
    targets: coded survey targets laid on the ground or support (:mod:`data_synth.targets`), 0 for none.
    """

    name: str
    layout: str
    width: int
    height: int
    rig: OrbitRig | AerialRig
    lidar: TerrestrialScan | AirborneScan
    noise: RangeNoise
    render: RenderSettings
    environment: Environment
    texture_scale: float = 1.0
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    stats_points: int = 300
    rig_ranges: OrbitRigRanges | AerialRigRanges | None = None
    targets: int = 0

    @property
    def n_train(self) -> int:
        if isinstance(self.rig, OrbitRig):
            return self.rig.views_per_ring * len(self.rig.elevations_deg)
        return self.rig.grid[0] * self.rig.grid[1] + 4 * self.rig.oblique_per_side


PRESETS: dict[str, Preset] = {
    "tiny": Preset(
        name="tiny",
        layout="tiny",
        width=96,
        height=72,
        rig=OrbitRig(radius_m=0.9, elevations_deg=(45.0,), views_per_ring=10, azimuth_start_deg=-70.0,
                     azimuth_span_deg=90.0, n_test=2, hfov_deg=50.0),
        lidar=TerrestrialScan(stations=((0.6, -0.3, 0.3), (0.5, 0.45, 0.35)), step_deg=0.5,
                              azimuth_half_deg=40.0, elevation_deg=(-50.0, 10.0)),
        noise=RangeNoise(sigma_m=0.0005, sigma_rel=0.0),
        render=RenderSettings(supersample=2, max_depth=3),
        environment=Environment(sun_azimuth_deg=20.0, sun_elevation_deg=55.0),
        texture_scale=1.5,
        stats_points=150,
    ),
    "tabletop": Preset(
        name="tabletop",
        layout="tabletop",
        width=640,
        height=480,
        rig=OrbitRig(radius_m=0.85, elevations_deg=(20.0, 38.0, 58.0), views_per_ring=24, n_test=8,
                     target=(0.0, 0.0, 0.03), hfov_deg=48.0),
        lidar=TerrestrialScan(stations=((0.7, 0.0, 0.35), (0.0, 0.7, 0.4), (-0.7, 0.0, 0.35), (0.0, -0.7, 0.4)),
                              step_deg=0.12, azimuth_half_deg=35.0, elevation_deg=(-45.0, 10.0)),
        noise=RangeNoise(sigma_m=0.0003, sigma_rel=0.0),
        render=RenderSettings(supersample=2, max_depth=4),
        environment=Environment(sun_azimuth_deg=35.0, sun_elevation_deg=50.0, ground_tile=0.3),
        texture_scale=1.0,
        targets=8,
    ),
    "aerial": Preset(
        name="aerial",
        layout="aerial",
        width=640,
        height=480,
        rig=AerialRig(area_m=(100.0, 80.0), grid=(7, 6), nadir_height_m=40.0, oblique_height_m=60.0,
                      oblique_tilt_deg=45.0, oblique_per_side=4, n_test=4, hfov_deg=70.0),
        lidar=AirborneScan(line_y_m=(-50.0, 0.0, 50.0), x_range_m=(-90.0, 90.0), altitude_m=80.0,
                           line_spacing_m=0.4, half_angle_deg=35.0, pulses_per_line=400),
        noise=RangeNoise(sigma_m=0.02, sigma_rel=0.0001),
        render=RenderSettings(supersample=2, max_depth=3),
        environment=Environment(sun_azimuth_deg=140.0, sun_elevation_deg=55.0, ground_tile=20.0),
        texture_scale=1.0,
        targets=12,
    ),
    "demo": Preset(
        name="demo",
        layout="tabletop",
        width=320,
        height=240,
        rig=OrbitRig(radius_m=0.85, elevations_deg=(28.0, 50.0), views_per_ring=12, n_test=4,
                     target=(0.0, 0.0, 0.03), hfov_deg=48.0),
        lidar=TerrestrialScan(stations=((0.7, 0.0, 0.35), (0.0, 0.7, 0.4), (-0.7, 0.0, 0.35), (0.0, -0.7, 0.4)),
                              step_deg=0.2, azimuth_half_deg=35.0, elevation_deg=(-45.0, 10.0)),
        noise=RangeNoise(sigma_m=0.0003, sigma_rel=0.0),
        render=RenderSettings(supersample=2, max_depth=4),
        environment=Environment(sun_azimuth_deg=35.0, sun_elevation_deg=50.0, ground_tile=0.3),
        texture_scale=1.0,
        targets=8,
    ),
}  # fmt: skip
# The demo scene with every object textured, seen from farther and higher (1.4 m, 40° and 60°): every part of the
# table is in at least 10 of the 24 photos. From the demo's rig (0.85 m, 28° and 50°) its corners are in 4, at
# grazing angles, and 7.9 % of the training pixels were unreconstructed table (holes, which need splats); from
# this one 0.26 % (seed 1, CPU MVS; docs/experiments/2026-11-26-classify.md).
PRESETS["textured"] = replace(
    PRESETS["demo"],
    name="textured",
    layout="tabletop_textured",
    targets=0,
    rig=replace(PRESETS["demo"].rig, radius_m=1.4, elevations_deg=(40.0, 60.0)),
)

PRESETS["random-object"] = replace(
    PRESETS["tabletop"],
    name="random-object",
    layout="random_object",
    rig_ranges=OrbitRigRanges(),
    targets=0,
)
PRESETS["random-aerial"] = replace(
    PRESETS["aerial"],
    name="random-aerial",
    layout="random_aerial",
    rig_ranges=AerialRigRanges(),
)

OVERRIDES = (
    "views", "test_views", "width", "height", "supersample", "max_depth", "noise", "georef", "origin", "targets",
)  # fmt: skip


def get_preset(name: str) -> Preset:
    """The preset called ``name``; :class:`ConfigError` lists the known ones otherwise."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ConfigError(f"unknown preset {name!r}; choose one of: {', '.join(PRESETS)}") from None


def preset_for_seed(
    preset: Preset, layout_rng: np.random.Generator, rig_rng: np.random.Generator
) -> tuple[Preset, dict[str, object] | None]:
    """The preset a seed makes of ``preset``, and the description of its drawn layout.

    A fixed preset is returned as it is, with ``None``. A procedural one (``rig_ranges`` set) gets the rig, the
    LiDAR scan and the sun drawn from ``rig_rng`` around the layout that ``layout_rng`` draws (the same layout
    as ``LAYOUTS[preset.layout](layout_rng)`` builds), and the description is ``scene.json``'s ``layout``.
    """
    if preset.rig_ranges is None:
        return preset, None
    layout = draw_layout(preset.layout, layout_rng)
    rig, lidar, environment = draw_rig(
        preset.rig_ranges, layout, preset.rig, preset.lidar, preset.environment, preset.width / preset.height, rig_rng
    )
    return replace(preset, rig=rig, lidar=lidar, environment=environment), layout.describe()


def apply_overrides(preset: Preset, **overrides: object) -> Preset:
    """A copy of ``preset`` with user overrides (``None`` values are ignored).

    views: training views (orbit: per ring = ceil(views / rings); aerial: nadir grid nearest to
    views − obliques, kept at the preset's aspect). test_views: held-out views. width, height: pixels (focal
    length follows the field of view). supersample: S of S×S. max_depth: bounces. noise: False/0 disables the
    LiDAR range noise, a float sets its constant sigma (metres). georef: True sets the UTM-like origin
    :data:`GEOREF_ORIGIN`. origin: explicit (x, y, z) local origin. targets: coded targets to lay (0 = none).
    """
    given = {k: v for k, v in overrides.items() if v is not None}
    unknown = set(given) - set(OVERRIDES)
    if unknown:
        raise ConfigError(f"unknown preset override(s) {sorted(unknown)}; allowed: {', '.join(OVERRIDES)}")
    p = preset
    for key in ("views", "test_views", "width", "height", "supersample", "targets"):
        least = 0 if key in ("test_views", "targets") else 1
        if key in given and (not isinstance(given[key], int) or given[key] < least):
            raise ConfigError(f"{key} must be a positive integer, got {given[key]!r}")
    if "width" in given or "height" in given:
        p = replace(p, width=int(given.get("width", p.width)), height=int(given.get("height", p.height)))
    if "views" in given:
        n = int(given["views"])  # type: ignore[arg-type]
        if isinstance(p.rig, OrbitRig):
            per_ring = max(2, math.ceil(n / len(p.rig.elevations_deg)))
            p = replace(p, rig=replace(p.rig, views_per_ring=per_ring))
        else:
            nadir = max(4, n - 4 * p.rig.oblique_per_side)
            aspect = p.rig.grid[0] / p.rig.grid[1]
            ny = max(2, round(math.sqrt(nadir / aspect)))
            nx = max(2, round(nadir / ny))
            p = replace(p, rig=replace(p.rig, grid=(nx, ny)))
    if "test_views" in given:
        p = replace(p, rig=replace(p.rig, n_test=int(given["test_views"])))  # type: ignore[arg-type]
    if "supersample" in given or "max_depth" in given:
        render = replace(
            p.render,
            supersample=int(given.get("supersample", p.render.supersample)),  # type: ignore[arg-type]
            max_depth=int(given.get("max_depth", p.render.max_depth)),  # type: ignore[arg-type]
        )
        if render.max_depth < 0:
            raise ConfigError(f"max_depth must be >= 0, got {render.max_depth}")
        p = replace(p, render=render)
    if "noise" in given:
        value = given["noise"]
        if value is False or value == 0:
            p = replace(p, noise=RangeNoise(0.0, 0.0))
        elif value is not True:
            sigma = float(value)  # type: ignore[arg-type]
            if not (sigma >= 0 and math.isfinite(sigma)):
                raise ConfigError(f"noise must be a non-negative sigma in metres, got {value!r}")
            p = replace(p, noise=RangeNoise(sigma, p.noise.sigma_rel))
    if "targets" in given:
        p = replace(p, targets=int(given["targets"]))  # type: ignore[arg-type]
    if given.get("georef"):
        p = replace(p, origin=GEOREF_ORIGIN)
    if "origin" in given:
        o = tuple(float(v) for v in given["origin"])  # type: ignore[union-attr]
        if len(o) != 3 or not all(math.isfinite(v) for v in o):
            raise ConfigError(f"origin must be three finite numbers, got {given['origin']!r}")
        p = replace(p, origin=o)  # type: ignore[arg-type]
    return p


def preset_summary(preset: Preset) -> dict[str, object]:
    """A JSON-ready description of the preset's rig and settings (for ``scene.json``); a procedural preset adds
    its ``rig_ranges`` and, for an aerial block, the ``nadir_overlap`` (forward, side) of the final grid."""

    def as_dict(obj: object) -> dict[str, object]:
        out: dict[str, object] = {"type": type(obj).__name__}
        for f in fields(obj):  # type: ignore[arg-type]
            if f.name == "table":
                continue
            v = getattr(obj, f.name)
            out[f.name] = [list(x) if isinstance(x, tuple) else x for x in v] if isinstance(v, tuple) else v
        return out

    procedural: dict[str, object] = {}
    if preset.rig_ranges is not None:
        procedural["rig_ranges"] = as_dict(preset.rig_ranges)
        if isinstance(preset.rig, AerialRig):
            forward, side = nadir_overlap(preset.rig, preset.width, preset.height)
            procedural["nadir_overlap"] = {"forward": round(forward, 4), "side": round(side, 4)}
    return {
        "rig": as_dict(preset.rig),
        "lidar": as_dict(preset.lidar),
        "lidar_noise": as_dict(preset.noise),
        "render": as_dict(preset.render),
        "environment": as_dict(preset.environment),
        "texture_scale": preset.texture_scale,
        **procedural,
    }
