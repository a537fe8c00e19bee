"""The splat trainer: trainable Gaussians fitted to photos inside masks, next to frozen context Gaussians.

:func:`train_splats` is a short loop over parts that are each usable and testable alone:

- :class:`fusion.train.state.TrainScene` / :class:`fusion.train.state.TrainState` — the fixed inputs (views,
  context projections, training frame) and the mutable state (parameters, Adam, strategy state, generators);
- :class:`fusion.train.sampler.ViewSampler` — the view of each step (a seeded permutation per epoch);
- :func:`fusion.train.step.train_step` — one step: render trainable + frozen Gaussians (:mod:`fusion.train.render`),
  loss = 0.8 · L1 + 0.2 · (1 − SSIM) over the view's loss pixels (:mod:`fusion.train.loss`) + regularisers,
  backward (only the trainable tensors have gradients), Adam step; then the densification strategy's refinement
  (:mod:`fusion.train.strategy`, :func:`fusion.train.step.refine_after_step`);
- :class:`fusion.train.schedule.TrainSchedule` — learning rates (means: ``lr_means`` × scene scale decaying
  exponentially to ``lr_means_final`` of it), SH degree (one more every ``sh_degree_interval`` steps), evaluation
  windows, snapshots and the end of densification;
- :class:`fusion.train.early_stop.EvalWindow` / :class:`fusion.train.early_stop.EarlyStop` — early stop: a seeded
  ``holdout_fraction`` of each view's mask pixels never enters the loss; the PSNR on them is accumulated over whole
  epochs, and training stops when it has not improved by ``min_improvement_db`` for ``patience`` evaluation windows
  (never before ``min_iterations`` nor while the strategy still densifies).

The whole-scene 3DGS baseline is the same trainer with ``masks=None``, no context and SfM points as ``init``.

Frames: everything is trained in the cameras' local frame shifted by the mean camera centre (float64 shift, then
float32); results come back as :class:`core.GaussianSet` in the cameras' local frame and origin.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
import torch

from core.cameras import Cameras
from core.errors import ConfigError, DataError
from core.gaussians import GaussianSet
from fusion.render.projection import quat_to_rotmat
from fusion.train.early_stop import Checkpoint, EarlyStop, EvalWindow
from fusion.train.options import TrainOptions
from fusion.train.params import clamp_to_viewer_range, set_from_tensors
from fusion.train.schedule import TrainSchedule
from fusion.train.state import TrainScene, TrainState, initial_state, prepare_scene, scene_scale
from fusion.train.step import StepOutcome, refine_after_step, train_step
from fusion.train.strategy import RefineCounts

__all__ = [
    "Checkpoint",
    "StepInfo",
    "TrainOptions",
    "TrainResult",
    "scene_scale",
    "splat_normals",
    "train_splats",
]


@dataclass
class TrainResult:
    """What :func:`train_splats` produced: the trained splats (cameras' local frame and origin; fields ``nx``,
    ``ny``, ``nz`` = unit normal along each splat's smallest axis), snapshots by step, the evaluation history and
    the counts of what was used and culled."""

    splats: GaussianSet
    snapshots: dict[int, GaussianSet]
    history: list[Checkpoint]
    iterations: int
    stopped_early: bool
    views_used: int
    views_without_mask: int
    mask_pixels: int
    context_total: int
    context_culled: int
    initial_gaussians: int
    refine: RefineCounts
    seconds: float
    scene_scale: float
    resolution: tuple[int, int]
    view_steps: tuple[int, ...] = ()  # steps spent on each view (views sorted by name)
    snapshot_seconds: dict[int, float] = field(default_factory=dict)  # per snapshot step, seconds since the start

    @property
    def final_holdout_psnr(self) -> float:
        return self.history[-1].holdout_psnr if self.history else float("nan")


@dataclass(frozen=True)
class StepInfo:
    """Passed to the progress callback after every step."""

    step: int
    iterations: int
    loss: float
    holdout_psnr: float
    gaussians: int


def splat_normals(gs: GaussianSet) -> np.ndarray:
    """(N, 3) float32 unit vectors along each Gaussian's smallest scale axis (the surface normal of a flat splat)."""
    if len(gs) == 0:
        return np.zeros((0, 3), np.float32)
    R = quat_to_rotmat(torch.from_numpy(gs.quats.astype(np.float64))).numpy()
    axis = np.argmin(gs.log_scales, axis=1)
    return R[np.arange(len(gs)), :, axis].astype(np.float32)


def _with_normals(gs: GaussianSet) -> GaussianSet:
    n = splat_normals(gs)
    gs.fields = dict(gs.fields) | {"nx": n[:, 0], "ny": n[:, 1], "nz": n[:, 2]}
    return gs


def _trained_set(state: TrainState, scene: TrainScene) -> GaussianSet:
    """The trainable splats now, in the cameras' local frame and origin, with normals."""
    return _with_normals(set_from_tensors(state.params, scene.centre, scene.origin))


def _record(window: EvalWindow, state: TrainState, scene: TrainScene, outcome: StepOutcome) -> None:
    """Fold a finished step into the evaluation window."""
    window.add_holdout(outcome.render.colour, scene.views[outcome.view])
    window.add_loss(outcome.loss)


def _log_scale_bounds(max_scales: np.ndarray | None, init: GaussianSet, schedule: TrainSchedule) -> torch.Tensor | None:
    """log(``max_scales``) as an (N, 1) float32 tensor, checked against what the run may do to the set."""
    if max_scales is None:
        return None
    bounds = np.asarray(max_scales, np.float64).reshape(-1)
    if len(bounds) != len(init) or np.isnan(bounds).any() or not (bounds > 0).all():
        raise ConfigError(f"max_scales needs one σ > 0 (metres; inf: unbounded) per initial Gaussian ({len(init)}), "
                          f"got {len(bounds)} values")  # fmt: skip
    if len(init) > schedule.strategy.cap or schedule.densifying_until > 0:
        raise ConfigError("max_scales needs a fixed set: the strategy must not densify (refine_start >= the end of "
                          "densification) and the cap must hold every initial Gaussian")  # fmt: skip
    return torch.from_numpy(np.log(bounds).astype(np.float32))[:, None]


def _clamp_log_scales(state: TrainState, bounds: torch.Tensor) -> None:
    with torch.no_grad():
        state.params["log_scales"].copy_(torch.minimum(state.params["log_scales"], bounds))


def train_splats(
    cameras: Cameras,
    images: Mapping[str, np.ndarray],
    masks: Mapping[str, np.ndarray] | None,
    init: GaussianSet,
    context: GaussianSet | None = None,
    options: TrainOptions | None = None,
    progress: Callable[[StepInfo], None] | None = None,
    max_scales: np.ndarray | None = None,
) -> TrainResult:
    """Train ``init`` (any origin) against ``images`` inside ``masks``, with ``context`` frozen beside it.

    images: name → (H, W, 3) photo at its camera's size (uint8 or float in [0, 1]); only names with a camera and,
    with masks, a non-empty mask are used. masks: name → (H, W) bool, or None for whole images. Returns a
    :class:`TrainResult`; deterministic for a given seed on the CPU.
    max_scales: (N,) per Gaussian of ``init``, metres (inf: no bound): after every step each σ is clamped to at
    most it (a projection onto the bound, as the appearance refinement of the survey layer needs); the set must keep
    its count and order, so the strategy must not densify and ``init`` must fit its cap.
    """
    opts = options or TrainOptions()
    t0 = time.perf_counter()
    if len(init) == 0:
        raise DataError("no initial splats to train (the regions got no seeds)")
    scene = prepare_scene(cameras, images, masks, context, opts)
    schedule = TrainSchedule.from_options(opts, scene.scale, len(scene.views))
    bounds = _log_scale_bounds(max_scales, init, schedule)
    state = initial_state(init, scene, schedule, opts)
    early_stop = EarlyStop.from_options(opts, schedule.densifying_until)
    window, history, stopped = EvalWindow(), [], False
    snapshots: dict[int, GaussianSet] = {}
    snapshot_seconds: dict[int, float] = {}
    while state.step < opts.iterations:
        index = state.sampler.next(state.step)
        outcome = train_step(state, scene, schedule, opts, index)
        refine_after_step(state, scene, schedule)
        clamp_to_viewer_range(state.params)
        if bounds is not None:
            _clamp_log_scales(state, bounds)
        _record(window, state, scene, outcome)
        step = state.step
        if schedule.snapshot_after(step):
            snapshot_seconds[step] = time.perf_counter() - t0
            snapshots[step] = _trained_set(state, scene)
        if schedule.evaluate_after(step):
            history.append(window.checkpoint(step, state.gaussians, time.perf_counter() - t0))
            window, state.holdout_psnr = EvalWindow(), history[-1].holdout_psnr
            if early_stop.update(state.holdout_psnr, step):
                stopped = True
                break
        if progress is not None:
            progress(StepInfo(step, opts.iterations, outcome.loss, state.holdout_psnr, state.gaussians))
    return TrainResult(
        splats=_trained_set(state, scene),
        snapshots=snapshots,
        history=history,
        iterations=state.step,
        stopped_early=stopped,
        views_used=len(scene.views),
        views_without_mask=len(images) - len(scene.views),
        mask_pixels=int(sum(v.mask_pixels for v in scene.views)),
        context_total=scene.context_total,
        context_culled=scene.context_culled,
        initial_gaussians=state.initial_gaussians,
        refine=state.strategy_state.totals,
        seconds=time.perf_counter() - t0,
        scene_scale=scene.scale,
        resolution=(scene.views[0].width, scene.views[0].height),
        view_steps=tuple(int(c) for c in state.sampler.counts),
        snapshot_seconds=snapshot_seconds,
    )
