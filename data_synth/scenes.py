"""Scene layouts: which objects, where, made of what. Each builder takes a seeded generator (small jitters of
positions and orientations; the whole layout for the procedural families ``random_object`` and ``random_aerial``)
and returns a :class:`SceneMesh` in the local frame (metres, z up)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import trimesh

from data_synth.geometry import MeshBuilder, SceneMesh, box, cylinder, heightfield, plane, polyline_rods, rod, sphere
from data_synth.materials import material
from data_synth.textures import NoiseTable


def _mid(name: str) -> int:
    return material(name).id


def _jitter(rng: np.random.Generator, x: float, y: float, amount: float) -> tuple[float, float]:
    dx, dy = rng.uniform(-amount, amount, 2)
    return x + float(dx), y + float(dy)


def wire_cage(center: np.ndarray, size: float, height: float, radius: float) -> list[trimesh.Trimesh]:
    """A small lattice tower: 4 legs, horizontal rings and X-bracing (thin rods)."""
    c = np.asarray(center, dtype=np.float64)
    levels = 4
    parts = []
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64) * size / 2
    prev: list[np.ndarray] = []
    for lv in range(levels + 1):
        shrink = 1.0 - 0.35 * lv / levels
        z = height * lv / levels
        ring = [c + np.array([x * shrink, y * shrink, z]) for x, y in corners]
        if prev:
            for k in range(4):
                parts.append(rod(prev[k], ring[k], radius))
                parts.append(rod(prev[k], ring[(k + 1) % 4], radius * 0.7))
        for k in range(4):
            parts.append(rod(ring[k], ring[(k + 1) % 4], radius * 0.8))
        prev = ring
    return parts


def build_tiny(rng: np.random.Generator) -> SceneMesh:
    """A 0.8 m ground patch with a brick block, a text box, a noise ball, a mirror ball and a blank panel."""
    b = MeshBuilder()
    b.add(plane((0.8, 0.8)), _mid("ground_noise"))
    x, y = _jitter(rng, -0.12, 0.10, 0.01)
    b.add(box((0.14, 0.14, 0.12), (x, y, 0.06), float(rng.uniform(0, 30))), _mid("bricks"))
    x, y = _jitter(rng, 0.12, 0.12, 0.01)
    b.add(box((0.16, 0.07, 0.10), (x, y, 0.05), float(rng.uniform(-20, 20))), _mid("text_label"))
    x, y = _jitter(rng, 0.13, -0.10, 0.01)
    b.add(sphere(0.06, (x, y, 0.06), 3), _mid("stone_noise"))
    x, y = _jitter(rng, -0.10, -0.12, 0.01)
    b.add(sphere(0.07, (x, y, 0.07), 3), _mid("mirror"))
    x, y = _jitter(rng, 0.0, 0.0, 0.01)
    b.add(box((0.02, 0.16, 0.14), (x, y, 0.07), float(rng.uniform(-10, 10))), _mid("textureless_paint"))
    return b.build()


# The textured material standing in for each non-collaborative one in ``build_tabletop(collaborative_only=True)``.
TEXTURED_STAND_INS = {"polished_metal": "bricks", "mirror": "stone_noise", "glass": "text_label",
                      "textureless_paint": "bricks"}  # fmt: skip


def build_tabletop(rng: np.random.Generator, collaborative_only: bool = False) -> SceneMesh:
    """A 1 m wooden table with textured objects, polished metal, a mirror ball, glass, a blank panel and a wire cage.

    collaborative_only: the same objects, every one textured (:data:`TEXTURED_STAND_INS`), and no wire cage (thin);
    a scene where MVS suffices and nothing needs splats.
    """

    def _mid(name: str) -> int:
        return material(TEXTURED_STAND_INS.get(name, name) if collaborative_only else name).id

    b = MeshBuilder()
    b.add(plane((1.0, 1.0)), _mid("wood"))
    x, y = _jitter(rng, -0.16, 0.12, 0.01)
    b.add(box((0.12, 0.12, 0.10), (x, y, 0.05), float(rng.uniform(0, 40))), _mid("bricks"))
    x, y = _jitter(rng, 0.02, 0.20, 0.01)
    b.add(box((0.16, 0.11, 0.035), (x, y, 0.0175), float(rng.uniform(-25, 25))), _mid("text_label"))
    x, y = _jitter(rng, 0.20, 0.14, 0.01)
    b.add(sphere(0.05, (x, y, 0.05), 4), _mid("stone_noise"))
    x, y = _jitter(rng, 0.18, -0.04, 0.01)
    b.add(cylinder(0.035, 0.14, (x, y, 0.07), 48), _mid("polished_metal"))
    x, y = _jitter(rng, -0.02, -0.02, 0.01)
    b.add(sphere(0.055, (x, y, 0.055), 4), _mid("mirror"))
    x, y = _jitter(rng, -0.18, -0.12, 0.01)
    b.add(box((0.09, 0.07, 0.07), (x, y, 0.035), float(rng.uniform(0, 40))), _mid("glass"))
    x, y = _jitter(rng, 0.05, -0.20, 0.01)
    gem = sphere(0.03, (0.0, 0.0, 0.0), 1)
    gem.apply_scale((1.0, 1.0, 0.8))
    gem.apply_translation((x, y, 0.024))
    b.add(gem, _mid("glass"))
    x, y = _jitter(rng, -0.24, 0.0, 0.01)
    b.add(box((0.012, 0.16, 0.13), (x, y, 0.065), float(rng.uniform(-15, 15))), _mid("textureless_paint"))
    x, y = _jitter(rng, 0.24, -0.20, 0.01)
    if not collaborative_only:
        for part in wire_cage(np.array([x, y, 0.0]), 0.09, 0.14, 0.0012):
            b.add(part, _mid("wire"))
    return b.build()


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def build_aerial(rng: np.random.Generator) -> SceneMesh:
    """A 200 m terrain with a flattened switchgear yard: lattice pylon, cables, cabinets, buildings, glass roof."""
    b = MeshBuilder()
    size, cells = 200.0, 100
    table = NoiseTable(int(rng.integers(0, 2**31)))

    def terrain(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        pts = np.stack([np.ravel(x) / 40.0, np.ravel(y) / 40.0, np.zeros(np.size(x))], axis=1)
        hills = (table.fbm(pts, octaves=4) - 0.5) * 12.0
        yard = np.maximum(np.abs(np.ravel(x)) - 32.0, 0.0) + np.maximum(np.abs(np.ravel(y)) - 27.0, 0.0)
        return (hills * _smoothstep(0.0, 15.0, yard)).reshape(np.shape(x))  # flat (z = 0) inside the yard

    xs = np.linspace(-size / 2, size / 2, cells + 1)
    gx, gy = np.meshgrid(xs, xs)
    b.add(heightfield((size, size), (cells, cells), terrain(gx, gy)), _mid("grass"))

    # The yard's gravel slab, slightly above the flattened ground.
    slab = plane((60.0, 50.0), z=0.05)
    b.add(slab, _mid("gravel"))

    # Lattice pylon at the yard centre.
    pylon = wire_cage(np.array([0.0, 0.0, 0.05]), 7.0, 28.0, 0.15)
    for part in pylon:
        b.add(part, _mid("steel_lattice"))
    arm_z = 0.05 + 28.0 * 0.8
    arm_ends = [np.array([0.0, s * 8.0, arm_z]) for s in (-1, 1)]
    b.add(rod(arm_ends[0], arm_ends[1], 0.2), _mid("steel_lattice"))

    # Cables from the arm ends to a gantry at x = -26 and across the yard to x = +26 (sagging catenaries).
    for end in arm_ends:
        for xg in (-26.0, 26.0):
            far = np.array([xg, end[1], 9.0])
            s = np.linspace(0.0, 1.0, 16)
            line = end[None, :] * (1 - s[:, None]) + far[None, :] * s[:, None]
            line[:, 2] -= 2.5 * 4 * s * (1 - s)
            for part in polyline_rods(line, 0.03):
                b.add(part, _mid("cable"))
            b.add(rod(np.array([xg, end[1], 0.05]), np.array([xg, end[1], 9.2]), 0.25), _mid("steel_lattice"))

    # Metal cabinets in two rows.
    for row, y0 in enumerate((-15.0, 15.0)):
        for k in range(4):
            x, y = _jitter(rng, -15.0 + 10.0 * k, y0, 0.3)
            b.add(box((2.4, 1.2, 2.0), (x, y, 1.05), 90.0 * row), _mid("cabinet_metal"))
    # Transformer tanks: polished cylinders.
    for x0 in (-12.0, 12.0):
        b.add(cylinder(1.6, 3.0, (x0, 0.0, 1.55), 48), _mid("polished_metal"))

    # Buildings outside the yard, sunk into the terrain so no gap shows on slopes.
    for cx, cy, w, d, h, yaw in ((-60.0, 45.0, 16.0, 10.0, 7.0, 15.0), (55.0, -50.0, 20.0, 12.0, 9.0, -10.0)):
        x, y = _jitter(rng, cx, cy, 2.0)
        r = 0.5 * np.hypot(w, d)
        around = terrain(x + r * np.array([-1, 1, 1, -1, 0.0]), y + r * np.array([-1, -1, 1, 1, 0.0]))
        base = float(around.max())
        sink = base - float(around.min()) + 1.0  # walls reach below the lowest terrain around the footprint
        b.add(box((w, d, h + sink), (x, y, base + (h - sink) / 2), yaw), _mid("bricks"))
        b.add(box((w + 0.8, d + 0.8, 0.5), (x, y, base + h + 0.25), yaw), _mid("roof_tiles"))
    # Control building in the yard: textureless concrete with a glass roof light.
    x, y = _jitter(rng, 23.0, -19.0, 0.5)
    b.add(box((10.0, 6.0, 5.0), (x, y, 2.55), 0.0), _mid("concrete_textureless"))
    b.add(box((4.0, 2.5, 0.5), (x, y, 5.35), 0.0), _mid("glass_roof"))
    return b.build()


def build_procedural(rng: np.random.Generator, family: str) -> SceneMesh:
    """A layout drawn from ``rng`` by the procedural family ``family`` (:mod:`data_synth.procedural`)."""
    from data_synth.procedural import build_layout_mesh  # imported here: it builds on this module's wire_cage

    return build_layout_mesh(family, rng)


LAYOUTS: dict[str, Callable[[np.random.Generator], SceneMesh]] = {
    "tiny": build_tiny,
    "tabletop": build_tabletop,
    "aerial": build_aerial,
    "tabletop_textured": lambda rng: build_tabletop(rng, collaborative_only=True),
    "random_object": lambda rng: build_procedural(rng, "random_object"),
    "random_aerial": lambda rng: build_procedural(rng, "random_aerial"),
}
