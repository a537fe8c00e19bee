"""Options of the CPU MVS (:mod:`recon.mvs_cpu`), in a module of their own that does not import torch.

``recon.mvs.MvsOptions`` (and through it the pipeline's ``mvs`` stage options) holds a :class:`CpuMvsOptions`;
keeping it apart lets the configuration be read and checked before torch is loaded.

Effort and resolution are two controls: ``MvsOptions.max_image_size`` (``--max-image-size``) sets the pixels, the
``quality`` preset (``--mvs-quality``) sets the hypotheses tried per pixel (sweep planes, refinement rounds, far
propagation), so the time per view is about the pixels times the preset's cost per pixel; halving the image side
quarters the time at any preset. ``fast``: previews and checks of a capture; ``balanced`` (the default): the effort of
the torch MVS before issue 32; ``high``: 96 planes, 4 rounds a level. Seconds per view and accuracy of each preset:
docs/experiments/2026-11-27-pipeline-defaults.md ("CPU MVS quality presets"); measure them with
``bench/bench_mvs.py --quality Q`` (demo) and ``bench/bench_mvs_profile.py --quality Q`` (photos).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from enum import Enum
from typing import ClassVar

from core.constraints import Choice, Constrained, Constraints


class MvsQuality(str, Enum):
    """Effort presets of the CPU MVS (the ``quality`` option, ``--mvs-quality``)."""

    FAST = "fast"
    BALANCED = "balanced"
    HIGH = "high"


@dataclass(frozen=True)
class MvsEffort:
    """The hypotheses a quality preset tries per pixel."""

    num_planes: int  # planes of the coarse sweep (uniform in inverse depth)
    refine_rounds: int  # PatchMatch-style rounds per level (propagation + perturbation, step halves each round)
    finest_rounds: int  # rounds at the finest level (where most of the pixels are)
    far_propagation: bool  # also try the hypotheses of the neighbours 4 px away in each round


EFFORT = {
    MvsQuality.FAST: MvsEffort(num_planes=32, refine_rounds=2, finest_rounds=1, far_propagation=True),
    MvsQuality.BALANCED: MvsEffort(num_planes=64, refine_rounds=3, finest_rounds=3, far_propagation=True),
    MvsQuality.HIGH: MvsEffort(num_planes=96, refine_rounds=4, finest_rounds=4, far_propagation=True),
}
"""The effort of each preset (``high``: the torch MVS's effort before issue 32)."""


@dataclass(frozen=True)
class CpuMvsOptions(Constrained):
    """Options of the CPU MVS (defaults tuned on synthetic scenes at 320–800 px).

    quality: the effort preset (:data:`EFFORT`); the effort fields below left at None take its value, a value given
    overrides it.
    """

    quality: MvsQuality = MvsQuality.BALANCED
    num_planes: int | None = None  # planes of the coarse sweep (None: from quality)
    refine_rounds: int | None = None  # rounds per level but the finest (None: from quality)
    finest_rounds: int | None = None  # rounds at the finest level (None: from quality)
    far_propagation: bool | None = None  # neighbours 4 px away tried too (None: from quality)
    num_sources: int = 5  # source views per reference (view selection order)
    best_k: int = 2  # robust aggregation: mean of the k best source costs
    window_radius: int = 3  # NCC window (2r+1)², pixels at the finest level
    coarse_size: int = 160  # longer side of the coarsest level, pixels
    refine_steps: int = 1  # perturbations ±k·step, k = 1..refine_steps, per refinement round
    median_radius: int = 2  # median filter of the coarse sweep result, pixels
    max_cost: float = 0.6  # 1 − NCC above this is invalid (NCC < 0.4)
    min_texture_std: float = 0.012  # intensity std (0–1 scale) in the window below this is textureless
    geom_max_reproj_px: float = 1.0
    geom_max_rel_depth: float = 0.01
    geom_min_consistent: int = 2
    normal_radius: int = 2  # plane-fit window radius for normals, pixels
    batch_hypotheses: int = 8  # hypotheses evaluated per kernel call (bounds memory: ~batch × H × W × 8 B)

    constraints: ClassVar[Constraints] = {"quality": Choice(MvsQuality)}

    def effort(self) -> MvsEffort:
        """The quality preset's effort with the fields given here (not None) in its place."""
        given = {f.name: getattr(self, f.name) for f in fields(MvsEffort) if getattr(self, f.name) is not None}
        return replace(EFFORT[self.quality], **given)
