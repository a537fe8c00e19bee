"""Materials of the synthetic scenes: a fixed legend (ids stable across presets) and their shading parameters.

Each material has a *kind* (what it means for photogrammetry: textured, textureless, metal, mirror, glass,
thin) and a *shading* model (how the ray tracer lights it). ``collaborative`` says whether multi-view stereo
can be expected to reconstruct it: only view-independent, textured, not-too-thin surfaces are.
Albedos are linear RGB in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from core.errors import ConfigError


class MaterialKind(str, Enum):
    """What a surface means for multi-view stereo."""

    TEXTURED = "textured"
    TEXTURELESS = "textureless"
    METAL = "metal"
    MIRROR = "mirror"
    GLASS = "glass"
    THIN = "thin"


class Shading(str, Enum):
    """How the ray tracer lights a surface."""

    LAMBERT = "lambert"  # diffuse only
    GLOSSY = "glossy"  # Lambert + Blinn-Phong highlight + Fresnel-weighted traced reflection
    MIRROR = "mirror"  # perfect specular reflection, traced
    GLASS = "glass"  # Fresnel mix of traced reflection and refraction


class Texture(str, Enum):
    """Procedural albedo patterns (see :mod:`data_synth.textures`)."""

    NONE = "none"
    NOISE = "noise"
    BRICKS = "bricks"
    TEXT = "text"
    WOOD = "wood"


BACKGROUND_LABEL = 255
"""Label of pixels that see no surface (sky/environment)."""

# ASPRS LAS classification codes used for the simulated LiDAR.
LAS_UNCLASSIFIED, LAS_GROUND, LAS_BUILDING, LAS_WIRE, LAS_TOWER, LAS_OTHER = 1, 2, 6, 14, 15, 19


@dataclass(frozen=True)
class Material:
    """One material of the legend.

    Attributes
    ----------
    id: label written to meshes, clouds and label maps (0..254).
    name: short unique name.
    kind: meaning for MVS (:class:`MaterialKind`).
    shading: lighting model (:class:`Shading`).
    albedo: linear RGB base colour, each in [0, 1].
    albedo2: second colour of the procedural texture (mortar, ink, grain...).
    texture: procedural pattern of the albedo.
    texture_scale_m: characteristic size of the pattern at scale 1 (metres; presets rescale it).
    specular: Blinn-Phong highlight weight (glossy), mirror tint (mirror), unused otherwise.
    shininess: Blinn-Phong exponent.
    reflectance: Fresnel reflectance at normal incidence (glossy and glass), 0..1.
    ior: index of refraction (glass).
    las_class: ASPRS classification code for the LiDAR export.
    why: one sentence on why MVS does or does not cope with it.
    """

    id: int
    name: str
    kind: MaterialKind
    shading: Shading
    albedo: tuple[float, float, float]
    albedo2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    texture: Texture = Texture.NONE
    texture_scale_m: float = 0.02
    specular: float = 0.0
    shininess: float = 64.0
    reflectance: float = 0.04
    ior: float = 1.5
    las_class: int = LAS_UNCLASSIFIED
    why: str = ""

    @property
    def collaborative(self) -> bool:
        """True where MVS can be trusted: textured, view-independent, thick surfaces."""
        return self.kind is MaterialKind.TEXTURED

    def legend_entry(self) -> dict[str, object]:
        """The ``scene.json`` entry ``{id, name, kind, collaborative, why}`` (plus shading and LAS class)."""
        return {
            "id": self.id,
            "name": self.name,
            "kind": self.kind.value,
            "collaborative": self.collaborative,
            "why": self.why,
            "shading": self.shading.value,
            "las_class": self.las_class,
        }


_K, _S, _T = MaterialKind, Shading, Texture
_WHY_TEXTURED = "textured Lambertian: view-independent colour with dense features, MVS photo-consistency holds"

MATERIALS: tuple[Material, ...] = (
    Material(0, "ground_noise", _K.TEXTURED, _S.LAMBERT, (0.45, 0.38, 0.28), (0.12, 0.10, 0.08), _T.NOISE, 0.02,
             las_class=LAS_GROUND, why=_WHY_TEXTURED),
    Material(1, "bricks", _K.TEXTURED, _S.LAMBERT, (0.55, 0.22, 0.13), (0.75, 0.72, 0.65), _T.BRICKS, 0.03,
             las_class=LAS_BUILDING, why=_WHY_TEXTURED),
    Material(2, "text_label", _K.TEXTURED, _S.LAMBERT, (0.80, 0.78, 0.70), (0.05, 0.05, 0.08), _T.TEXT, 0.012,
             las_class=LAS_OTHER, why=_WHY_TEXTURED),
    Material(3, "wood", _K.TEXTURED, _S.LAMBERT, (0.55, 0.36, 0.18), (0.30, 0.17, 0.07), _T.WOOD, 0.02,
             las_class=LAS_OTHER, why=_WHY_TEXTURED),
    Material(4, "stone_noise", _K.TEXTURED, _S.LAMBERT, (0.50, 0.50, 0.47), (0.15, 0.16, 0.18), _T.NOISE, 0.01,
             las_class=LAS_OTHER, why=_WHY_TEXTURED),
    Material(5, "textureless_paint", _K.TEXTURELESS, _S.LAMBERT, (0.62, 0.64, 0.66),
             las_class=LAS_OTHER,
             why="uniform albedo: no image gradients, so matching costs are flat and depth is ambiguous"),
    Material(6, "polished_metal", _K.METAL, _S.GLOSSY, (0.30, 0.30, 0.32), specular=0.8, shininess=200.0,
             reflectance=0.6, las_class=LAS_OTHER,
             why="glossy metal: highlights and reflections move with the viewpoint, photo-consistency breaks"),
    Material(7, "mirror", _K.MIRROR, _S.MIRROR, (0.0, 0.0, 0.0), specular=0.92, las_class=LAS_OTHER,
             why="mirror: shows the reflected scene, MVS triangulates virtual images behind the surface"),
    Material(8, "glass", _K.GLASS, _S.GLASS, (0.92, 0.97, 0.95), reflectance=0.04, ior=1.5, las_class=LAS_OTHER,
             why="glass: Fresnel reflection plus refracted background, no stable surface texture"),
    Material(9, "wire", _K.THIN, _S.GLOSSY, (0.60, 0.35, 0.20), specular=0.6, shininess=120.0, reflectance=0.5,
             las_class=LAS_WIRE, why="thin shiny members: one or two pixels wide, below the MVS patch size"),
    Material(10, "grass", _K.TEXTURED, _S.LAMBERT, (0.12, 0.26, 0.07), (0.42, 0.42, 0.18), _T.NOISE, 0.6,
             las_class=LAS_GROUND, why=_WHY_TEXTURED),
    Material(11, "roof_tiles", _K.TEXTURED, _S.LAMBERT, (0.40, 0.15, 0.10), (0.20, 0.08, 0.06), _T.BRICKS, 0.6,
             las_class=LAS_BUILDING, why=_WHY_TEXTURED),
    Material(12, "gravel", _K.TEXTURED, _S.LAMBERT, (0.45, 0.44, 0.42), (0.20, 0.20, 0.21), _T.NOISE, 0.3,
             las_class=LAS_GROUND, why=_WHY_TEXTURED),
    Material(13, "steel_lattice", _K.THIN, _S.GLOSSY, (0.45, 0.46, 0.48), specular=0.7, shininess=80.0,
             reflectance=0.5, las_class=LAS_TOWER,
             why="thin galvanised lattice members: sub-pixel to few-pixel wide and shiny"),
    Material(14, "cable", _K.THIN, _S.GLOSSY, (0.25, 0.25, 0.26), specular=0.5, shininess=60.0, reflectance=0.3,
             las_class=LAS_WIRE, why="cables: thinner than a pixel at flying height, no matchable texture"),
    Material(15, "cabinet_metal", _K.METAL, _S.GLOSSY, (0.55, 0.57, 0.58), specular=0.7, shininess=150.0,
             reflectance=0.5, las_class=LAS_OTHER,
             why="smooth painted metal: broad highlights and sky reflections change with viewpoint"),
    Material(16, "concrete_textureless", _K.TEXTURELESS, _S.LAMBERT, (0.58, 0.58, 0.56), las_class=LAS_BUILDING,
             why="uniform concrete slab: no texture to match"),
    Material(17, "glass_roof", _K.GLASS, _S.GLASS, (0.85, 0.92, 0.95), reflectance=0.05, ior=1.5,
             las_class=LAS_BUILDING, why="glass roof: reflects the sky and shows the interior"),
    Material(18, "survey_target", _K.TEXTURED, _S.LAMBERT, (0.85, 0.85, 0.85), (0.03, 0.03, 0.03), _T.NONE,
             las_class=LAS_GROUND,
             why="coded survey target: a black and white marker, sharp corners (its pattern: data_synth.targets)"),
)  # fmt: skip

TARGET_MATERIAL_ID = 18
"""Material of the coded survey targets (:mod:`data_synth.targets`); the ray tracer reads their marker bitmaps."""

_BY_NAME = {m.name: m for m in MATERIALS}
_BY_ID = {m.id: m for m in MATERIALS}


def material(name: str) -> Material:
    """The material called ``name``; raises :class:`ConfigError` listing the known names otherwise."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise ConfigError(f"unknown material {name!r}; known: {', '.join(sorted(_BY_NAME))}") from None


def material_by_id(material_id: int) -> Material:
    """The material with label ``material_id``."""
    try:
        return _BY_ID[int(material_id)]
    except KeyError:
        raise ConfigError(f"unknown material id {material_id}; known: {sorted(_BY_ID)}") from None
