"""One optimisation step of the trainer: render, loss, backward, Adam step; then the strategy's refinement.

:func:`step_loss` is the loss of one render (pure given its inputs): the photometric term over the view's loss
pixels (0.8 · L1 + 0.2 · (1 − SSIM), :mod:`fusion.train.loss`, or SmoothL1 + MS-SSIM, :mod:`fusion.train.msssim`),
then, added one after the other in this order, the LPIPS term (:mod:`fusion.train.perceptual`), the scale
regulariser (relative to the scene scale) and the strategy's own regulariser.
:func:`train_step` takes step ``state.step`` on one view: sets the means' learning rate, renders trainable + frozen
Gaussians (:mod:`fusion.train.render`), backpropagates (only the trainable
tensors have gradients), hands the screen-space gradients to the strategy, steps Adam and counts the step.
:func:`refine_after_step` then lets the strategy densify, prune or reset (:mod:`fusion.train.strategy`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from core.errors import ConfigError
from fusion.train.loss import LossTerms, masked_photometric_loss
from fusion.train.msssim import smoothl1_msssim_loss
from fusion.train.options import TrainOptions
from fusion.train.perceptual import PerceptualCrop, PerceptualNetwork, perceptual_loss
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
    if options.photometric == "l1_ssim":
        return masked_photometric_loss(colour, view.image, view.loss_mask, options.ssim_lambda)
    return smoothl1_msssim_loss(colour, view.image, view.loss_mask, options.ssim_lambda, options.smoothl1_beta)


def step_loss(
    params: dict[str, torch.Tensor],
    view: TrainView,
    render: StepRender,
    options: TrainOptions,
    scene_scale: float,
    strategy: Strategy,
    lpips: tuple[PerceptualCrop, PerceptualNetwork] | None = None,
) -> StepLoss:
    """The loss of ``render`` of ``params`` (training frame) on ``view`` (see the module docstring).

    scene_scale: metres (the regularisers are σ / scene scale). lpips: the view's crop and the network when the
    LPIPS term is on.
    """
    terms = photometric_terms(render.colour, view, options)
    loss = terms.loss
    if lpips is not None:
        loss = loss + options.lpips_weight * perceptual_loss(render.colour, lpips[0], lpips[1])
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
    lpips: PerceptualNetwork | None = None,
) -> StepOutcome:
    """Take step ``state.step`` on view ``index`` of ``scene`` and count it (``state.step`` + 1 on return).

    lpips: the frozen LPIPS network, called only from ``schedule.lpips_from`` on."""
    step, view = state.step, scene.views[index]
    set_learning_rate(state.optimizer, "means", schedule.lr_means(step))
    loss_pixels_only = options.photometric == "l1_ssim" and not schedule.lpips_on(step)
    render = render_step(state.params, view, scene.caches[index], schedule.sh_degree_at(step), scene.background,
                         options.backend, loss_pixels_only)  # fmt: skip
    crop = state.lpips_crop(index, view, options.lpips_margin) if schedule.lpips_on(step) else None
    if crop is not None and lpips is None:
        raise ConfigError("lpips_weight > 0 needs the LPIPS network (eval.lpips.LPIPS with its weights file)")
    perceptual = (crop, lpips) if crop is not None and lpips is not None else None
    loss = step_loss(state.params, view, render, options, scene.scale, schedule.strategy, perceptual)
    loss.total.backward()
    schedule.strategy.after_backward(state.strategy_state, render.means2d, view.width, view.height, step)
    state.optimizer.step()
    state.optimizer.zero_grad(set_to_none=True)
    state.step += 1
    return StepOutcome(index, render, float(loss.terms.loss.detach()))


def refine_after_step(state: TrainState, scene: TrainScene, schedule: TrainSchedule) -> RefineCounts:
    """The strategy's refinement after ``state.step`` finished steps (with the learning rate of the step taken)."""
    return schedule.strategy.refine(
        state.strategy_state, state.params, state.optimizer, state.step, schedule.iterations, scene.scale,
        state.generator, lr_means=schedule.lr_means(state.step - 1),
    )  # fmt: skip
