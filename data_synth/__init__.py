"""Synthetic survey scenes with exact ground truth.

``generate_scene("tiny", out_dir, seed=0)`` ray-traces a preset (tiny, tabletop, aerial, demo, textured, or the
procedural random-object / random-aerial, whose layout and rig the seed draws) on the CPU and writes photos,
held-out photos, true COLMAP cameras, the GT mesh with material ids, a simulated LiDAR cloud, depth and label maps
and ``scene.json`` (layout in :mod:`data_synth.layout`); ``load_scene(dir)`` reads it back.
"""

from data_synth.generate import generate_scene
from data_synth.layout import SceneLayout
from data_synth.materials import MATERIALS, Material, MaterialKind
from data_synth.presets import PRESETS, Preset, apply_overrides, get_preset
from data_synth.scene import MaterialInfo, Scene, load_scene, read_mesh

__all__ = [
    "MATERIALS",
    "PRESETS",
    "Material",
    "MaterialInfo",
    "MaterialKind",
    "Preset",
    "Scene",
    "SceneLayout",
    "apply_overrides",
    "generate_scene",
    "get_preset",
    "load_scene",
    "read_mesh",
]
