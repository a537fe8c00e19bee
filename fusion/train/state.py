"""What a training run works on: the fixed :class:`TrainScene` and the mutable :class:`TrainState`.

:class:`TrainScene` (built once by :func:`prepare_scene`) holds what never changes during a run: the training views
(:mod:`fusion.train.views`), the frozen context's per-view projections (:mod:`fusion.train.render`), the training
frame (the cameras' local frame shifted by the mean camera centre, float64, then float32) and the scene scale.
:class:`TrainState` (built by :func:`initial_state`) holds what each step changes: the trainable parameters and
their Adam optimiser, the strategy's state, the seeded generators (torch for the strategy, NumPy inside the view
sampler), the step counter and the last hold-out PSNR.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch

from core.cameras import Cameras
from core.errors import DataError
from core.gaussians import GaussianSet
from fusion.train.options import TrainOptions
from fusion.train.params import context_from_set, make_optimizer, make_parameters, tensors_from_set
from fusion.train.render import ContextProjection, project_context
from fusion.train.sampler import ViewSampler
from fusion.train.schedule import TrainSchedule, initial_learning_rates
from fusion.train.strategy import StrategyState
from fusion.train.views import TrainView, prepare_views


def scene_scale(cameras: Cameras) -> float:
    """1.1 × the largest distance of a camera centre from the centres' mean (3DGS), metres (≥ 1e-6)."""
    centres = np.array([v.center for v in cameras])
    if len(centres) == 0:
        raise DataError("no cameras: cannot train")
    return max(1.1 * float(np.linalg.norm(centres - centres.mean(0), axis=1).max()), 1e-6)


@dataclass(frozen=True)
class TrainScene:
    """The fixed inputs of a run, in the training frame.

    views: the training views (sorted by name). caches: per view, the frozen context's projection (None: no
    context). origin: (3,) float64 the cameras'
    origin; centre: (3,) float64 the training frame's offset from it (metres, cameras' local frame). scale: the
    scene scale (metres, :func:`scene_scale`). background: (3,) float32 colour in [0, 1]. context_total /
    context_culled: frozen Gaussians given / in no view's active tiles.
    """

    views: list[TrainView]
    caches: list[ContextProjection | None]
    origin: np.ndarray
    centre: np.ndarray
    scale: float
    background: torch.Tensor
    context_total: int
    context_culled: int


def prepare_scene(
    cameras: Cameras,
    images: Mapping[str, np.ndarray],
    masks: Mapping[str, np.ndarray] | None,
    context: GaussianSet | None,
    options: TrainOptions,
) -> TrainScene:
    """The :class:`TrainScene` of a run (arguments as in :func:`fusion.train.train_splats`).

    Raises :class:`DataError` when no view has a mask pixel (or there is no camera)."""
    origin = cameras.origin
    centres = np.array([v.center for v in cameras])
    centre = centres.mean(axis=0)
    scale = scene_scale(cameras)
    views = prepare_views(
        cameras, images, masks, centre, downscale=options.downscale, holdout_fraction=options.holdout_fraction,
        seed=options.seed,
    )  # fmt: skip
    if not views:
        raise DataError("no training view has mask pixels: nothing to train")
    frozen = context_from_set(context.with_origin(origin), centre, 0) if context is not None and len(context) else None
    caches = [project_context(frozen, v) for v in views]
    context_total = len(frozen) if frozen is not None else 0
    context_culled = 0
    if frozen is not None:
        used = torch.zeros(context_total, dtype=torch.bool)
        for cache in caches:
            if cache is not None:
                used[cache.index] = True
        context_culled = int((~used).sum())
    background = torch.tensor(options.background, dtype=torch.float32)
    return TrainScene(views, caches, origin, centre, scale, background, context_total, context_culled)


@dataclass
class TrainState:
    """The mutable state of a run.

    params: the trainable tensors (:mod:`fusion.train.params`, training frame; replaced by densification, the dict
    object stays). optimizer: Adam with one group per name. strategy_state: the strategy's running state.
    generator: the seeded torch generator the strategy draws from. sampler: the view sampler (owns the NumPy
    generator). initial_gaussians: the trainable count at the start (after the cap). step: finished steps.
    holdout_psnr: the last closed window's hold-out PSNR (dB; NaN before the first).
    """

    params: dict[str, torch.nn.Parameter]
    optimizer: torch.optim.Adam
    strategy_state: StrategyState
    generator: torch.Generator
    sampler: ViewSampler
    initial_gaussians: int
    step: int = 0
    holdout_psnr: float = float("nan")

    @property
    def gaussians(self) -> int:
        """The current trainable count."""
        return int(self.params["means"].shape[0])


def initial_state(init: GaussianSet, scene: TrainScene, schedule: TrainSchedule, options: TrainOptions) -> TrainState:
    """The state before the first step: ``init`` (any origin) in the training frame, subsampled (seeded) to the
    strategy's cap, as Adam parameters with the schedule's step-0 learning rates; generators seeded with
    ``options.seed``."""
    generator = torch.Generator().manual_seed(options.seed)
    rng = np.random.default_rng(options.seed)
    init = init.with_origin(scene.origin)
    if len(init) > options.strategy.cap:
        init = init.subset(np.sort(rng.choice(len(init), options.strategy.cap, replace=False)))
    params = make_parameters(tensors_from_set(init, scene.centre, options.sh_degree))
    optimizer = make_optimizer(params, initial_learning_rates(options, scene.scale))
    return TrainState(
        params=params,
        optimizer=optimizer,
        strategy_state=schedule.strategy.initial_state(len(init)),
        generator=generator,
        sampler=ViewSampler.start(len(scene.views), rng),
        initial_gaussians=len(init),
    )
