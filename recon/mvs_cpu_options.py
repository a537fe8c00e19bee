"""Options of the CPU MVS (:mod:`recon.mvs_cpu`), in a module of their own that does not import torch.

``recon.mvs.MvsOptions`` (and through it the pipeline's ``mvs`` stage options) holds a :class:`CpuMvsOptions`;
keeping it apart lets the configuration be read and checked before torch is loaded.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CpuMvsOptions:
    """Options of the CPU MVS (defaults tuned on synthetic scenes at 320–800 px)."""

    num_sources: int = 5  # source views per reference (view selection order)
    best_k: int = 2  # robust aggregation: mean of the k best source costs
    window_radius: int = 3  # NCC window (2r+1)², pixels at the finest level
    coarse_size: int = 160  # longer side of the coarsest level, pixels
    num_planes: int = 64  # planes of the coarse sweep (uniform in inverse depth)
    refine_steps: int = 1  # perturbations ±k·step, k = 1..refine_steps, per refinement round
    median_radius: int = 2  # median filter of the coarse sweep result, pixels
    refine_rounds: int = 3  # PatchMatch-style rounds per level (propagation + perturbation, step halves each round)
    max_cost: float = 0.6  # 1 − NCC above this is invalid (NCC < 0.4)
    min_texture_std: float = 0.012  # intensity std (0–1 scale) in the window below this is textureless
    geom_max_reproj_px: float = 1.0
    geom_max_rel_depth: float = 0.01
    geom_min_consistent: int = 2
    normal_radius: int = 2  # plane-fit window radius for normals, pixels
    batch_hypotheses: int = 8  # hypotheses evaluated at once (bounds memory: ~batch × sources × H × W × 40 B)
