"""One optimisation step of the trainer: render, loss, backward, Adam step; then the strategy's refinement.

:func:`step_loss` is the loss of one render (pure given its inputs): the photometric term over the view's loss
pixels (0.8 · L1 + 0.2 · (1 − SSIM), :mod:`fusion.train.loss`),
then the scale regulariser (relative to the scene scale) and the strategy's own regulariser.
:func:`train_step` takes step ``state.step`` on one view: sets the means' learning rate, renders trainable + frozen
Gaussians (:mod:`fusion.train.render`), backpropagates (only the trainable
tensors have gradients), hands the screen-space gradients to the strategy, steps Adam and counts the step.
:func:`refine_after_step` then lets the strategy densify, prune or reset (:mod:`fusion.train.strategy`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from fusion.train.loss import LossTerms, masked_photometric_loss
from fusion.train.options import TrainOptions
from fusion.train.render import StepRender, render_step
from fusion.train.schedule import TrainSchedule
from fusion.train.state import TrainScene, TrainState
from fusion.train.strategy import RefineCounts, Strategy
from fusion.train.views import TrainView


@dataclass(frozen=True)
class StepLoss:
    """The loss of one step: ``total`` (0-d, with its graph) and the photometric ``terms`` inside it."""

    total: torch.Tensor
    terms: LossTerms


@dataclass(frozen=True)
class StepOutcome:
    """What one step did: the view index, its render and the photometric loss (float)."""

    view: int
    render: StepRender
    loss: float


def photometric_terms(colour: torch.Tensor, view: TrainView, options: TrainOptions) -> LossTerms:
    """The photometric loss of a render (H, W, 3, [0, 1]) against ``view``'s photo over its loss pixels."""
    return masked_photometric_loss(colour, view.image, view.loss_mask, options.ssim_lambda)


def step_loss(
    params: dict[str, torch.Tensor],
    view: TrainView,
    render: StepRender,
    options: TrainOptions,
    scene_scale: float,
    strategy: Strategy,
) -> StepLoss:
    """The loss of ``render`` of ``params`` (training frame) on ``view`` (see the module docstring).

    scene_scale: metres (the regularisers are σ / scene scale).
    """
    terms = photometric_terms(render.colour, view, options)
    loss = terms.loss
    if options.scale_reg > 0:
        loss = loss + options.scale_reg * params["log_scales"].exp().mean() / scene_scale
    loss = loss + strategy.regularisation(params)
    return StepLoss(loss, terms)


def set_learning_rate(optimizer: torch.optim.Optimizer, group: str, lr: float) -> None:
    """Set the learning rate of the parameter group named ``group``."""
    for g in optimizer.param_groups:
        if g["name"] == group:
            g["lr"] = lr


def train_step(
    state: TrainState,
    scene: TrainScene,
    schedule: TrainSchedule,
    options: TrainOptions,
    index: int,
) -> StepOutcome:
    """Take step ``state.step`` on view ``index`` of ``scene`` and count it (``state.step`` + 1 on return)."""
    step, view = state.step, scene.views[index]
    set_learning_rate(state.optimizer, "means", schedule.lr_means(step))
    render = render_step(state.params, view, scene.caches[index], schedule.sh_degree_at(step), scene.background,
                         options.backend, loss_pixels_only=True)  # fmt: skip
    loss = step_loss(state.params, view, render, options, scene.scale, schedule.strategy)
    loss.total.backward()
    schedule.strategy.after_backward(state.strategy_state, render.means2d, view.width, view.height, step)
    state.optimizer.step()
    state.optimizer.zero_grad(set_to_none=True)
    state.step += 1
    return StepOutcome(index, render, float(loss.terms.loss.detach()))


def refine_after_step(state: TrainState, scene: TrainScene, schedule: TrainSchedule) -> RefineCounts:
    """The strategy's refinement after ``state.step`` finished steps."""
    return schedule.strategy.refine(
        state.strategy_state, state.params, state.optimizer, state.step, schedule.iterations, scene.scale,
        state.generator,
    )  # fmt: skip
