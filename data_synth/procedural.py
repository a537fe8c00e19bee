"""Procedural scene families: layouts drawn from a seed, at object (tabletop) and aerial (yard) scale.

A family (:data:`FAMILIES`) is a set of ranges; :func:`draw_layout` draws one :class:`ProceduralLayout` from a
seeded generator: the support (a table, or a yard slab in hilly terrain), how many objects, their shapes
(:class:`Shape`), sizes, placements, orientations and materials. :func:`draw_rig` then draws the camera rig, the
LiDAR stations or flight lines and the sun from a preset's ranges (:class:`OrbitRigRanges`,
:class:`AerialRigRanges`), fitted to the layout's extent. Presets ``random-object`` and ``random-aerial``
(:mod:`data_synth.presets`) tie the two together.

Conventions: metres, local frame, z up. An object's ``position_m`` is the centre of its footprint (x, y) and the
height of the support surface it rests on (z); its lowest point touches that surface exactly (mounds are the
exception: their rim is on the surface, a skirt below it hides the seam). ``yaw_deg`` turns an object about
+z, counter-clockwise seen from above. Drawn lengths are rounded to 10 µm and angles to 0.01°, so the
description in ``scene.json`` rebuilds the mesh exactly.

Materials: rods and cages (thin members) are made of the thin materials; every other shape of any non-thin
material, collaborative (textured) or not (textureless, metal, mirror, glass). A textured material is used only at
the scale its pattern suits (:attr:`FamilySpec.texture_m`: pattern size between 5 mm and 10 cm on a table, at
least 10 cm in a yard), so that "collaborative" stays true of it in the photos. Every layout has at least one
object of a collaborative and one of a non-collaborative material.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np
import trimesh

from core.errors import ConfigError
from data_synth.geometry import MeshBuilder, SceneMesh, box, cylinder, heightfield, plane, rod, sphere
from data_synth.lidar import AirborneScan, TerrestrialScan
from data_synth.lighting import Environment
from data_synth.materials import MATERIALS, MaterialKind, material
from data_synth.rig import AerialRig, OrbitRig
from data_synth.scenes import wire_cage
from data_synth.textures import NoiseTable

GENERATOR_VERSION = 1
"""Bumped whenever the same seed would draw a different layout; recorded in ``scene.json``."""


class Shape(str, Enum):
    """Object shapes (sizes in :attr:`PlacedObject.size_m`, metres)."""

    BOX = "box"  # x, y, z: edge lengths
    CYLINDER = "cylinder"  # radius, length (upright, or lying with its axis along the yawed x axis)
    SPHERE = "sphere"  # radius
    PANEL = "panel"  # thickness, width, height: an upright slab
    ROD = "rod"  # radius, length: a thin post (upright) or bar (lying)
    CAGE = "cage"  # width, height, member_radius: a tapering lattice tower of thin rods
    MOUND = "mound"  # radius, height: a heightfield dome
    BUILDING = "building"  # x, y, height, roof_thickness, overhang: walls plus a roof slab


THIN_SHAPES = frozenset({Shape.ROD, Shape.CAGE})
"""Shapes built from thin members: they take the thin materials only."""


@dataclass(frozen=True)
class TableRanges:
    """A square table at z = 0; objects stand inside a disc around its centre.

    side_m: table edge length range. region_fraction: placement disc radius over half the side.
    materials: candidate table materials (collaborative).
    """

    side_m: tuple[float, float] = (0.9, 1.2)
    region_fraction: tuple[float, float] = (0.5, 0.65)
    materials: tuple[str, ...] = ("wood", "ground_noise", "stone_noise")


@dataclass(frozen=True)
class YardRanges:
    """A flat rectangular yard slab in hilly terrain; objects stand inside the slab's placement rectangle.

    half_extent_m: ranges of the placement rectangle's half sizes (x, y). margin_m: slab beyond the rectangle.
    slab_height_m: slab surface above the flattened ground. slab_materials / slab_weights: the slab's material.
    terrain_size_m, terrain_cells: the square terrain heightfield. hill_amplitude_m, hill_wavelength_m: ranges
    of the hills' height span and noise wavelength; blend_m: width of the ramp from the flat yard to the hills.
    """

    half_extent_m: tuple[tuple[float, float], tuple[float, float]] = ((22.0, 38.0), (18.0, 30.0))
    margin_m: float = 4.0
    slab_height_m: float = 0.05
    slab_materials: tuple[str, ...] = ("gravel", "concrete_textureless")
    slab_weights: tuple[float, ...] = (0.75, 0.25)
    terrain_material: str = "grass"
    terrain_size_m: float = 220.0
    terrain_cells: int = 110
    hill_amplitude_m: tuple[float, float] = (4.0, 14.0)
    hill_wavelength_m: tuple[float, float] = (30.0, 50.0)
    blend_m: float = 15.0


@dataclass(frozen=True)
class FamilySpec:
    """The layout ranges of one family (lengths in metres).

    count: (min, max) objects drawn (fewer are kept when one finds no free place in ``max_tries`` tries).
    shape_weights: relative frequency of each shape. sizes: per shape, per size name, the (min, max) range.
    lying_probability: chance that a cylinder or rod lies on its side. clearance_m: minimum gap between the
    objects' bounding boxes. non_collaborative_probability: chance that a non-thin object gets a
    non-collaborative material. texture_m: pattern sizes (``Material.texture_scale_m``) of the textured
    materials used at this scale. sphere_subdivisions, sections: tessellation.
    """

    name: str
    support: TableRanges | YardRanges
    count: tuple[int, int]
    shape_weights: Mapping[Shape, float]
    sizes: Mapping[Shape, Mapping[str, tuple[float, float]]]
    lying_probability: float
    clearance_m: float
    non_collaborative_probability: float = 0.45
    texture_m: tuple[float, float] = (0.0, math.inf)
    sphere_subdivisions: int = 3
    sections: int = 48
    max_tries: int = 60


OBJECT_FAMILY = FamilySpec(
    name="random_object",
    support=TableRanges(),
    count=(4, 10),
    shape_weights={Shape.BOX: 3.0, Shape.CYLINDER: 2.0, Shape.SPHERE: 2.0, Shape.PANEL: 1.2, Shape.ROD: 1.0,
                   Shape.CAGE: 1.0, Shape.MOUND: 0.6, Shape.BUILDING: 0.6},
    sizes={
        Shape.BOX: {"x": (0.04, 0.16), "y": (0.04, 0.16), "z": (0.03, 0.15)},
        Shape.CYLINDER: {"radius": (0.02, 0.06), "length": (0.05, 0.18)},
        Shape.SPHERE: {"radius": (0.025, 0.07)},
        Shape.PANEL: {"thickness": (0.008, 0.016), "width": (0.08, 0.18), "height": (0.08, 0.16)},
        Shape.ROD: {"radius": (0.001, 0.0025), "length": (0.08, 0.2)},
        Shape.CAGE: {"width": (0.06, 0.11), "height": (0.08, 0.18), "member_radius": (0.0008, 0.0015)},
        Shape.MOUND: {"radius": (0.05, 0.1), "height": (0.015, 0.05)},
        Shape.BUILDING: {"x": (0.06, 0.14), "y": (0.06, 0.12), "height": (0.05, 0.12),
                         "roof_thickness": (0.006, 0.012), "overhang": (0.003, 0.01)},
    },
    lying_probability=0.3,
    clearance_m=0.015,
    texture_m=(0.005, 0.1),
    sphere_subdivisions=4,
)  # fmt: skip

AERIAL_FAMILY = FamilySpec(
    name="random_aerial",
    support=YardRanges(),
    count=(5, 14),
    shape_weights={Shape.BOX: 2.5, Shape.CYLINDER: 2.0, Shape.SPHERE: 0.6, Shape.PANEL: 1.0, Shape.ROD: 1.5,
                   Shape.CAGE: 1.0, Shape.MOUND: 1.0, Shape.BUILDING: 3.0},
    sizes={
        Shape.BOX: {"x": (1.5, 6.0), "y": (1.0, 3.0), "z": (1.5, 3.0)},
        Shape.CYLINDER: {"radius": (1.0, 3.5), "length": (2.0, 8.0)},
        Shape.SPHERE: {"radius": (1.5, 4.0)},
        Shape.PANEL: {"thickness": (0.2, 0.4), "width": (6.0, 16.0), "height": (2.0, 4.0)},
        Shape.ROD: {"radius": (0.08, 0.2), "length": (6.0, 14.0)},
        Shape.CAGE: {"width": (3.0, 7.0), "height": (10.0, 25.0), "member_radius": (0.08, 0.15)},
        Shape.MOUND: {"radius": (4.0, 10.0), "height": (1.0, 4.0)},
        Shape.BUILDING: {"x": (8.0, 22.0), "y": (6.0, 16.0), "height": (4.0, 14.0),
                         "roof_thickness": (0.3, 0.6), "overhang": (0.2, 0.6)},
    },
    lying_probability=0.25,
    clearance_m=1.5,
    texture_m=(0.1, math.inf),
)  # fmt: skip

FAMILIES: dict[str, FamilySpec] = {f.name: f for f in (OBJECT_FAMILY, AERIAL_FAMILY)}
"""Layout name (as in :data:`data_synth.scenes.LAYOUTS`) -> family."""


def _length(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return round(float(rng.uniform(*bounds)), 5)


def _angle(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return round(float(rng.uniform(*bounds)), 2)


def _pick(
    rng: np.random.Generator, names: tuple[str, ...] | list[str], weights: tuple[float, ...] | None = None
) -> str:
    p = None if weights is None else np.asarray(weights, np.float64) / float(np.sum(weights))
    return str(names[int(rng.choice(len(names), p=p))])


# -- materials ------------------------------------------------------------------------------------------------


def material_pools(family: FamilySpec) -> dict[str, tuple[str, ...]]:
    """Candidate material names by role: ``collaborative`` (textured at the family's scale), ``non_collaborative``
    (textureless, metal, mirror, glass) and ``thin``."""
    lo, hi = family.texture_m
    return {
        "collaborative": tuple(
            m.name for m in MATERIALS if m.kind is MaterialKind.TEXTURED and lo <= m.texture_scale_m <= hi
        ),
        "non_collaborative": tuple(
            m.name for m in MATERIALS if not m.collaborative and m.kind is not MaterialKind.THIN
        ),
        "thin": tuple(m.name for m in MATERIALS if m.kind is MaterialKind.THIN),
    }


# -- objects --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlacedObject:
    """One object of a layout.

    shape: :class:`Shape`. size_m: named sizes in metres (see :class:`Shape`). position_m: footprint centre
    (x, y) and support height (z). yaw_deg: rotation about +z. lying: cylinders and rods on their side.
    materials: material names, one per part (a building: walls, roof; every other shape: one).
    """

    shape: Shape
    size_m: Mapping[str, float]
    position_m: tuple[float, float, float]
    yaw_deg: float
    lying: bool
    materials: tuple[str, ...]

    def parts(self, family: FamilySpec) -> list[tuple[trimesh.Trimesh, str]]:
        """The object's meshes in the local frame, each with its material name."""
        meshes = _shape_parts(self.shape, self.size_m, self.yaw_deg, self.lying, family)
        offset = np.asarray(self.position_m, np.float64)
        out = []
        for k, mesh in enumerate(meshes):
            mesh.apply_translation(offset)
            out.append((mesh, self.materials[min(k, len(self.materials) - 1)]))
        return out

    def describe(self, family: FamilySpec) -> dict[str, object]:
        """JSON-ready: shape, size_m, position_m, yaw_deg, lying, materials, bounds_m (min and max corner)."""
        verts = np.concatenate([np.asarray(m.vertices) for m, _ in self.parts(family)])
        return {
            "shape": self.shape.value,
            "size_m": dict(self.size_m),
            "position_m": list(self.position_m),
            "yaw_deg": self.yaw_deg,
            "lying": self.lying,
            "materials": list(self.materials),
            "bounds_m": [
                [round(float(v), 6) for v in verts.min(axis=0)],
                [round(float(v), 6) for v in verts.max(axis=0)],
            ],
        }


def _rest(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Shift ``mesh`` up or down so that its lowest vertex is at z = 0."""
    mesh.apply_translation((0.0, 0.0, -float(np.asarray(mesh.vertices)[:, 2].min())))
    return mesh


def _yawed(mesh: trimesh.Trimesh, yaw_deg: float) -> trimesh.Trimesh:
    mesh.apply_transform(trimesh.transformations.rotation_matrix(math.radians(yaw_deg), (0, 0, 1)))
    return mesh


def _axis_mesh(radius: float, length: float, lying: bool, sections: int) -> trimesh.Trimesh:
    """A capped cylinder: upright from z = 0, or lying along x centred on the origin."""
    if lying:
        return rod(np.array([-length / 2, 0.0, radius]), np.array([length / 2, 0.0, radius]), radius, sections)
    return rod(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, length]), radius, sections)


def _mound(radius: float, height: float) -> trimesh.Trimesh:
    """A dome ``height * (1 - (r / radius)^2)`` on a square grid; outside the rim the grid dips below z = 0."""
    cells = 16
    half = radius * (1.0 + 1.5 / cells)  # one grid line just beyond the rim
    xs = np.linspace(-half, half, cells + 1)
    gx, gy = np.meshgrid(xs, xs)
    r2 = (gx**2 + gy**2) / radius**2
    z = np.where(r2 <= 1.0, height * (1.0 - r2), -0.1 * height)
    return heightfield((2 * half, 2 * half), (cells, cells), z)


def _shape_parts(
    shape: Shape, s: Mapping[str, float], yaw_deg: float, lying: bool, family: FamilySpec
) -> list[trimesh.Trimesh]:
    """Meshes of a shape with its footprint centred on the origin, resting on z = 0, turned by ``yaw_deg``."""
    if shape is Shape.BOX:
        parts = [box((s["x"], s["y"], s["z"]), (0.0, 0.0, s["z"] / 2))]
    elif shape is Shape.CYLINDER:
        if lying:
            parts = [_rest(_axis_mesh(s["radius"], s["length"], True, family.sections))]
        else:
            parts = [cylinder(s["radius"], s["length"], (0.0, 0.0, s["length"] / 2), family.sections)]
    elif shape is Shape.SPHERE:
        parts = [_rest(sphere(s["radius"], (0.0, 0.0, 0.0), family.sphere_subdivisions))]
    elif shape is Shape.PANEL:
        parts = [box((s["thickness"], s["width"], s["height"]), (0.0, 0.0, s["height"] / 2))]
    elif shape is Shape.ROD:
        parts = [_rest(_axis_mesh(s["radius"], s["length"], lying, 8))]
    elif shape is Shape.CAGE:
        members = wire_cage(np.zeros(3), s["width"], s["height"], s["member_radius"])
        low = min(float(np.asarray(m.vertices)[:, 2].min()) for m in members)
        parts = [m.apply_translation((0.0, 0.0, -low)) for m in members]
    elif shape is Shape.MOUND:
        parts = [_mound(s["radius"], s["height"])]
    elif shape is Shape.BUILDING:
        x, y, h, roof, over = s["x"], s["y"], s["height"], s["roof_thickness"], s["overhang"]
        parts = [box((x, y, h), (0.0, 0.0, h / 2)), box((x + 2 * over, y + 2 * over, roof), (0.0, 0.0, h + roof / 2))]
    else:  # pragma: no cover - the enum is exhaustive
        raise ConfigError(f"unknown shape {shape!r}")
    return [_yawed(p, yaw_deg) for p in parts]


def _draw_shape(rng: np.random.Generator, family: FamilySpec) -> tuple[Shape, dict[str, float], float, bool]:
    shapes = list(family.shape_weights)
    weights = np.array([family.shape_weights[s] for s in shapes], np.float64)
    shape = shapes[int(rng.choice(len(shapes), p=weights / weights.sum()))]
    sizes = {name: _length(rng, bounds) for name, bounds in family.sizes[shape].items()}
    yaw = _angle(rng, (0.0, 360.0)) if shape is not Shape.SPHERE else 0.0
    lying = shape in (Shape.CYLINDER, Shape.ROD) and bool(rng.random() < family.lying_probability)
    return shape, sizes, yaw, lying


def _footprint(shape: Shape, sizes: Mapping[str, float], yaw: float, lying: bool, family: FamilySpec) -> np.ndarray:
    """(2, 2) xy bounding box (min, max) of a shape at the origin."""
    verts = np.concatenate([np.asarray(m.vertices)[:, :2] for m in _shape_parts(shape, sizes, yaw, lying, family)])
    return np.stack([verts.min(axis=0), verts.max(axis=0)])


# -- support --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Terrain:
    """Hilly ground around a flat yard: heights ``amplitude_m * (fbm - 0.5)`` of value noise of wavelength
    ``wavelength_m``, blended to 0 over ``blend_m`` towards the flat rectangle of half sizes ``flat_half_m``."""

    size_m: float
    cells: int
    amplitude_m: float
    wavelength_m: float
    flat_half_m: tuple[float, float]
    blend_m: float
    noise_seed: int
    material: str

    def heights(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Terrain height (metres) at arrays ``x``, ``y`` (same shape)."""
        table = NoiseTable(self.noise_seed)
        pts = np.stack([np.ravel(x), np.ravel(y), np.zeros(np.size(x))], axis=1) / self.wavelength_m
        hills = (table.fbm(pts, octaves=4) - 0.5) * self.amplitude_m
        out = np.maximum(np.abs(np.ravel(x)) - self.flat_half_m[0], 0.0)
        out = out + np.maximum(np.abs(np.ravel(y)) - self.flat_half_m[1], 0.0)
        t = np.clip(out / self.blend_m, 0.0, 1.0)
        return (hills * t * t * (3 - 2 * t)).reshape(np.shape(x))


@dataclass(frozen=True)
class Support:
    """What the objects rest on.

    kind: ``table`` or ``yard``. size_m: (x, y) of the table or the yard slab. surface_z_m: height of its top.
    material: its material name. region_radius_m (table) / region_half_m (yard): objects' footprints stay
    inside this disc / rectangle around the origin. terrain: the hills around a yard.
    """

    kind: str
    size_m: tuple[float, float]
    surface_z_m: float
    material: str
    region_radius_m: float | None = None
    region_half_m: tuple[float, float] | None = None
    terrain: Terrain | None = None

    def parts(self) -> list[tuple[trimesh.Trimesh, str]]:
        """The support's meshes with material names."""
        out = [(plane(self.size_m, z=self.surface_z_m), self.material)]
        if self.terrain is not None:
            t = self.terrain
            xs = np.linspace(-t.size_m / 2, t.size_m / 2, t.cells + 1)
            gx, gy = np.meshgrid(xs, xs)
            out.insert(0, (heightfield((t.size_m, t.size_m), (t.cells, t.cells), t.heights(gx, gy)), t.material))
        return out

    def contains(self, box_xy: np.ndarray) -> bool:
        """Whether an xy bounding box (2, 2) lies inside the placement region."""
        if self.region_radius_m is not None:
            corners = np.array([[box_xy[i, 0], box_xy[j, 1]] for i in (0, 1) for j in (0, 1)])
            return bool(np.hypot(corners[:, 0], corners[:, 1]).max() <= self.region_radius_m)
        half = np.asarray(self.region_half_m)
        return bool(np.all(box_xy[0] >= -half) and np.all(box_xy[1] <= half))

    def describe(self) -> dict[str, object]:
        out: dict[str, object] = {
            "kind": self.kind,
            "size_m": list(self.size_m),
            "surface_z_m": self.surface_z_m,
            "material": self.material,
        }
        if self.region_radius_m is not None:
            out["region_radius_m"] = self.region_radius_m
        if self.region_half_m is not None:
            out["region_half_m"] = list(self.region_half_m)
        if self.terrain is not None:
            t = self.terrain
            out["terrain"] = {"size_m": t.size_m, "cells": t.cells, "amplitude_m": t.amplitude_m,
                              "wavelength_m": t.wavelength_m, "flat_half_m": list(t.flat_half_m),
                              "blend_m": t.blend_m, "noise_seed": t.noise_seed, "material": t.material}  # fmt: skip
        return out


def _draw_support(rng: np.random.Generator, ranges: TableRanges | YardRanges) -> Support:
    if isinstance(ranges, TableRanges):
        side = _length(rng, ranges.side_m)
        radius = round(side / 2 * float(rng.uniform(*ranges.region_fraction)), 5)
        return Support("table", (side, side), 0.0, _pick(rng, ranges.materials), region_radius_m=radius)
    half = (_length(rng, ranges.half_extent_m[0]), _length(rng, ranges.half_extent_m[1]))
    slab = (round(2 * (half[0] + ranges.margin_m), 5), round(2 * (half[1] + ranges.margin_m), 5))
    terrain = Terrain(
        size_m=ranges.terrain_size_m,
        cells=ranges.terrain_cells,
        amplitude_m=_length(rng, ranges.hill_amplitude_m),
        wavelength_m=_length(rng, ranges.hill_wavelength_m),
        flat_half_m=(round(slab[0] / 2 + 2.0, 5), round(slab[1] / 2 + 2.0, 5)),
        blend_m=ranges.blend_m,
        noise_seed=int(rng.integers(0, 2**31)),
        material=ranges.terrain_material,
    )
    material_name = _pick(rng, ranges.slab_materials, ranges.slab_weights)
    return Support("yard", slab, ranges.slab_height_m, material_name, region_half_m=half, terrain=terrain)


# -- layouts --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ProceduralLayout:
    """A drawn layout: the family, the support and the objects (in placement order)."""

    family: FamilySpec
    support: Support
    objects: tuple[PlacedObject, ...] = field(default_factory=tuple)

    def object_bounds(self) -> np.ndarray:
        """(N, 2, 3) float64 axis-aligned bounding box (min, max corner) of each object, metres."""
        out = []
        for obj in self.objects:
            verts = np.concatenate([np.asarray(m.vertices) for m, _ in obj.parts(self.family)])
            out.append(np.stack([verts.min(axis=0), verts.max(axis=0)]))
        return np.asarray(out, np.float64).reshape(-1, 2, 3)

    def extent_m(self) -> float:
        """Largest horizontal distance (metres) from the origin to a corner of an object's bounding box."""
        b = self.object_bounds()
        if not len(b):
            return 0.0
        far_x = np.abs(b[:, :, 0]).max(axis=1)
        far_y = np.abs(b[:, :, 1]).max(axis=1)
        return float(np.hypot(far_x, far_y).max())

    def top_m(self) -> float:
        """Height of the highest object point (metres), the support surface when there is no object."""
        b = self.object_bounds()
        return float(b[:, 1, 2].max()) if len(b) else self.support.surface_z_m

    def mesh(self) -> SceneMesh:
        """The ground-truth mesh: support, then the objects, with per-face material ids."""
        builder = MeshBuilder()
        for mesh, name in self.support.parts():
            builder.add(mesh, material(name).id)
        for obj in self.objects:
            for mesh, name in obj.parts(self.family):
                builder.add(mesh, material(name).id)
        return builder.build()

    def material_names(self) -> list[str]:
        """Names of every material in the layout (support and objects), in first-use order."""
        names = [name for _, name in self.support.parts()]
        names += [name for obj in self.objects for name in obj.materials]
        return list(dict.fromkeys(names))

    def describe(self) -> dict[str, object]:
        """JSON-ready description (``scene.json`` key ``layout``): family, generator version, support, objects."""
        return {
            "family": self.family.name,
            "generator_version": GENERATOR_VERSION,
            "support": self.support.describe(),
            "objects": [obj.describe(self.family) for obj in self.objects],
        }


def _overlaps(box_xy: np.ndarray, others: list[np.ndarray], gap: float) -> bool:
    return any(bool(np.all(box_xy[0] < o[1] + gap) and np.all(o[0] < box_xy[1] + gap)) for o in others)


def _place(
    rng: np.random.Generator, family: FamilySpec, support: Support
) -> list[tuple[Shape, dict[str, float], float, bool, tuple[float, float, float]]]:
    """Draw the objects' shapes and poses and place each at a free random spot (up to ``max_tries`` tries, else it is
    left out): the largest non-thin object first, then the others from the largest footprint down."""
    n = int(rng.integers(family.count[0], family.count[1] + 1))
    drawn = [_draw_shape(rng, family) for _ in range(n)]
    if all(d[0] in THIN_SHAPES for d in drawn):  # a non-thin object is needed for the material mix
        k = int(rng.integers(n))
        drawn[k] = (Shape.BOX, {k2: _length(rng, b) for k2, b in family.sizes[Shape.BOX].items()}, drawn[k][2], False)
    feet = [_footprint(*d, family) for d in drawn]
    order = sorted(range(n), key=lambda i: -float(np.prod(feet[i][1] - feet[i][0])))
    first_thick = next(i for i in order if drawn[i][0] not in THIN_SHAPES)
    order.remove(first_thick)
    order.insert(0, first_thick)  # placed first, in an empty region: the layout keeps a non-thin object
    if support.region_radius_m is not None:
        reach = np.array([support.region_radius_m] * 2)
    else:
        reach = np.asarray(support.region_half_m, np.float64)
    placed, taken = [], []
    for i in order:
        for _ in range(family.max_tries):
            xy = np.round(rng.uniform(-reach, reach), 5)
            box_xy = feet[i] + xy
            if support.contains(box_xy) and not _overlaps(box_xy, taken, family.clearance_m):
                shape, sizes, yaw, lying = drawn[i]
                placed.append((shape, sizes, yaw, lying, (float(xy[0]), float(xy[1]), support.surface_z_m)))
                taken.append(box_xy)
                break
    return placed


def _assign_materials(rng: np.random.Generator, family: FamilySpec, shapes: list[Shape]) -> list[tuple[str, ...]]:
    """One material per part (thin materials on rods and cages); then, if every object is of one class, a random
    non-thin object is switched, so that a layout of two objects or more has both classes."""
    pools = material_pools(family)
    out: list[tuple[str, ...]] = []
    for shape in shapes:
        if shape in THIN_SHAPES:
            out.append((_pick(rng, pools["thin"]),))
            continue
        names = []
        for _ in range(2 if shape is Shape.BUILDING else 1):
            kind = "non_collaborative" if rng.random() < family.non_collaborative_probability else "collaborative"
            names.append(_pick(rng, pools[kind]))
        out.append(tuple(names))
    thick = [k for k, s in enumerate(shapes) if s not in THIN_SHAPES]

    def has(collaborative: bool) -> bool:
        return any(material(n).collaborative == collaborative for names in out for n in names)

    if thick and not has(True):
        k = thick.pop(int(rng.integers(len(thick))))
        out[k] = (_pick(rng, pools["collaborative"]),) * len(out[k])
    if thick and not has(False):  # every object is collaborative (so there is no thin one)
        k = thick[int(rng.integers(len(thick)))]
        if sum(material(n).collaborative for names in out for n in names) > len(out[k]):
            out[k] = (_pick(rng, pools["non_collaborative"]),) * len(out[k])
    return out


def draw_layout(layout: str, rng: np.random.Generator) -> ProceduralLayout:
    """Draw the layout of family ``layout`` (``random_object`` or ``random_aerial``) from ``rng``.

    The same generator state gives the same layout. :class:`ConfigError` names the known families otherwise.
    """
    try:
        family = FAMILIES[layout]
    except KeyError:
        raise ConfigError(f"unknown procedural layout {layout!r}; choose one of: {', '.join(FAMILIES)}") from None
    support = _draw_support(rng, family.support)
    placed = _place(rng, family, support)
    materials = _assign_materials(rng, family, [p[0] for p in placed])
    objects = tuple(
        PlacedObject(shape, sizes, pos, yaw, lying, mats)
        for (shape, sizes, yaw, lying, pos), mats in zip(placed, materials, strict=True)
    )
    return ProceduralLayout(family, support, objects)


def build_layout_mesh(layout: str, rng: np.random.Generator) -> SceneMesh:
    """The mesh of :func:`draw_layout` (the scene builder registered in :data:`data_synth.scenes.LAYOUTS`)."""
    return draw_layout(layout, rng).mesh()


# -- rigs -----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class OrbitRigRanges:
    """How a seed draws an orbit rig, terrestrial LiDAR stations and the sun around an object layout.

    radius_factor: rig radius over the layout's extent (:meth:`ProceduralLayout.extent_m`, at least
    ``min_extent_fraction`` of the placement disc). rings: (min, max) number of elevation rings, each drawn in
    its own band of ``elevation_deg`` with at least ``min_ring_gap_deg`` between rings. target_height_fraction:
    aim height over the tallest object. lidar_distance_fraction: station distance over the rig radius;
    lidar_height_fraction: station height over its distance. sun_azimuth_deg, sun_elevation_deg: the sun.
    """

    radius_factor: tuple[float, float] = (2.6, 3.4)
    min_extent_fraction: float = 0.6
    rings: tuple[int, int] = (2, 3)
    elevation_deg: tuple[float, float] = (15.0, 70.0)
    min_ring_gap_deg: float = 12.0
    target_height_fraction: tuple[float, float] = (0.15, 0.4)
    lidar_distance_fraction: float = 0.82
    lidar_height_fraction: tuple[float, float] = (0.4, 0.6)
    sun_azimuth_deg: tuple[float, float] = (0.0, 360.0)
    sun_elevation_deg: tuple[float, float] = (25.0, 70.0)


@dataclass(frozen=True)
class AerialRigRanges:
    """How a seed draws a UAV block, airborne LiDAR lines and the sun over a yard layout.

    nadir_height_m: flying height of the nadir grid, at least ``min_clearance_m`` above the tallest object.
    forward_overlap (along y, image height) and side_overlap (along x, image width): overlap of neighbouring
    nadir footprints, which sets the grid spacing; the grid covers ``coverage`` times the yard's placement
    rectangle, at most ``max_grid`` stations a side. oblique_height_factor: oblique height over the nadir height;
    oblique_tilt_deg: their tilt from nadir. lidar_swath_overlap: overlap of neighbouring LiDAR swaths.
    """

    nadir_height_m: tuple[float, float] = (35.0, 55.0)
    min_clearance_m: float = 12.0
    forward_overlap: tuple[float, float] = (0.6, 0.8)
    side_overlap: tuple[float, float] = (0.5, 0.7)
    coverage: float = 1.15
    max_grid: int = 12
    oblique_height_factor: tuple[float, float] = (1.2, 1.6)
    oblique_tilt_deg: tuple[float, float] = (35.0, 50.0)
    lidar_swath_overlap: float = 0.3
    sun_azimuth_deg: tuple[float, float] = (0.0, 360.0)
    sun_elevation_deg: tuple[float, float] = (25.0, 70.0)


RigParts = tuple[OrbitRig | AerialRig, TerrestrialScan | AirborneScan, Environment]


def _sun(rng: np.random.Generator, ranges: OrbitRigRanges | AerialRigRanges, base: Environment) -> Environment:
    return replace(
        base,
        sun_azimuth_deg=_angle(rng, ranges.sun_azimuth_deg),
        sun_elevation_deg=_angle(rng, ranges.sun_elevation_deg),
        seed=int(rng.integers(0, 2**31)),
    )


def _draw_orbit(
    ranges: OrbitRigRanges,
    layout: ProceduralLayout,
    base: OrbitRig,
    lidar: TerrestrialScan,
    rng: np.random.Generator,
) -> tuple[OrbitRig, TerrestrialScan]:
    region = layout.support.region_radius_m or layout.extent_m()
    extent = max(layout.extent_m(), ranges.min_extent_fraction * region)
    radius = round(extent * float(rng.uniform(*ranges.radius_factor)), 5)
    rings = int(rng.integers(ranges.rings[0], ranges.rings[1] + 1))
    lo, hi = ranges.elevation_deg
    band = (hi - lo) / rings
    slack = max(band - ranges.min_ring_gap_deg, 0.0) / 2  # ring k stays within band k, +- slack around its middle
    elevations = tuple(
        _angle(rng, (lo + (k + 0.5) * band - slack, lo + (k + 0.5) * band + slack)) for k in range(rings)
    )
    top = layout.top_m() - layout.support.surface_z_m
    target = (0.0, 0.0, round(layout.support.surface_z_m + top * float(rng.uniform(*ranges.target_height_fraction)), 5))
    per_ring = max(2, math.ceil(len(base.elevations_deg) * base.views_per_ring / rings))
    rig = replace(base, radius_m=radius, elevations_deg=elevations, views_per_ring=per_ring, target=target,
                  azimuth_start_deg=_angle(rng, (0.0, 360.0)), azimuth_span_deg=360.0)  # fmt: skip

    distance = ranges.lidar_distance_fraction * radius
    az0 = math.radians(_angle(rng, (0.0, 90.0)))
    stations = []
    for k in range(4):
        a = az0 + k * math.pi / 2
        z = distance * float(rng.uniform(*ranges.lidar_height_fraction))
        stations.append((round(distance * math.cos(a), 5), round(distance * math.sin(a), 5), round(z, 5)))
    high = max(s[2] for s in stations)
    half = min(math.degrees(math.atan2(1.15 * extent, distance)) + 5.0, 60.0)
    down = min(math.degrees(math.atan2(high, max(distance - 1.15 * extent, 0.1 * distance))) + 5.0, 80.0)
    scan = replace(lidar, stations=tuple(stations), target=target, azimuth_half_deg=round(half, 2),
                   elevation_deg=(round(-down, 2), lidar.elevation_deg[1]))  # fmt: skip
    return rig, scan


def _draw_aerial(
    ranges: AerialRigRanges,
    layout: ProceduralLayout,
    base: AerialRig,
    lidar: AirborneScan,
    aspect: float,
    rng: np.random.Generator,
) -> tuple[AerialRig, AirborneScan]:
    top = layout.top_m()
    height = max(_length(rng, ranges.nadir_height_m), round(top + ranges.min_clearance_m, 5))
    forward, side = float(rng.uniform(*ranges.forward_overlap)), float(rng.uniform(*ranges.side_overlap))
    foot_x = 2 * height * math.tan(math.radians(base.hfov_deg) / 2)
    foot_y = foot_x / aspect
    spacing = (foot_x * (1 - side), foot_y * (1 - forward))
    half = layout.support.region_half_m or (layout.extent_m(), layout.extent_m())
    grid = tuple(
        int(min(max(math.ceil(2 * ranges.coverage * h / s) + 1, 2), ranges.max_grid))
        for h, s in zip(half, spacing, strict=True)
    )
    area = tuple(round((n - 1) * s, 5) for n, s in zip(grid, spacing, strict=True))
    rig = replace(
        base,
        area_m=area,
        grid=grid,
        nadir_height_m=height,
        oblique_height_m=round(height * float(rng.uniform(*ranges.oblique_height_factor)), 5),
        oblique_tilt_deg=_angle(rng, ranges.oblique_tilt_deg),
    )
    altitude = max(lidar.altitude_m, round(top + 40.0, 5))
    swath = 2 * altitude * math.tan(math.radians(lidar.half_angle_deg))
    reach_y = 0.5 * max(area[1], 2 * half[1]) + 10.0
    n_lines = max(2, math.ceil(2 * reach_y / (swath * (1 - ranges.lidar_swath_overlap))) + 1)
    lines = tuple(round(float(v), 5) for v in np.linspace(-reach_y, reach_y, n_lines))
    reach_x = round(0.5 * max(area[0], 2 * half[0]) + 30.0, 5)
    scan = replace(lidar, line_y_m=lines, x_range_m=(-reach_x, reach_x), altitude_m=altitude)
    return rig, scan


def draw_rig(
    ranges: OrbitRigRanges | AerialRigRanges,
    layout: ProceduralLayout,
    rig: OrbitRig | AerialRig,
    lidar: TerrestrialScan | AirborneScan,
    environment: Environment,
    aspect: float,
    rng: np.random.Generator,
) -> RigParts:
    """Draw the camera rig, the LiDAR scan and the sun for ``layout`` from ``ranges``.

    rig, lidar, environment: the preset's bases (views, test views, field of view, scan step and sky are kept;
    positions are drawn). aspect: image width over height (the nadir footprint's shape).
    """
    if isinstance(ranges, OrbitRigRanges):
        if not isinstance(rig, OrbitRig) or not isinstance(lidar, TerrestrialScan):
            raise ConfigError("orbit rig ranges need an OrbitRig and a TerrestrialScan in the preset")
        orbit, scan = _draw_orbit(ranges, layout, rig, lidar, rng)
        return orbit, scan, _sun(rng, ranges, environment)
    if not isinstance(rig, AerialRig) or not isinstance(lidar, AirborneScan):
        raise ConfigError("aerial rig ranges need an AerialRig and an AirborneScan in the preset")
    block, scan = _draw_aerial(ranges, layout, rig, lidar, aspect, rng)
    return block, scan, _sun(rng, ranges, environment)


def nadir_overlap(rig: AerialRig, width: int, height: int) -> tuple[float, float]:
    """Forward (along y) and side (along x) overlap, 0..1, of neighbouring nadir images of ``rig`` at an image
    size (negative: gaps between footprints; 1.0 along an axis with one station)."""
    foot_x = 2 * rig.nadir_height_m * math.tan(math.radians(rig.hfov_deg) / 2)
    foot = (foot_x, foot_x * height / width)
    spacing = [a / (n - 1) if n > 1 else 0.0 for a, n in zip(rig.area_m, rig.grid, strict=True)]
    return 1.0 - spacing[1] / foot[1], 1.0 - spacing[0] / foot[0]
