"""The splat trainer: trainable Gaussians fitted to photos inside masks, next to frozen context Gaussians.

One step: pick a view (a seeded permutation per epoch), render trainable + frozen Gaussians together
(:mod:`fusion.train.render`), loss = 0.8 · L1 + 0.2 · (1 − SSIM) averaged over the view's loss pixels
(:mod:`fusion.train.loss`) + regularisers, backward (only the trainable tensors have gradients), Adam step with the
3DGS learning rates (means: ``lr_means`` × scene scale decaying exponentially to ``lr_means_final`` of it), then the
densification strategy's bookkeeping and refinement (:mod:`fusion.train.strategy`). SH degree rises by one every
``sh_degree_interval`` steps.

Early stop: a seeded ``holdout_fraction`` of each view's mask pixels never enters the loss; the PSNR on them is
accumulated over whole epochs, and training stops when it has not improved by ``min_improvement_db`` for
``patience`` evaluation windows (never before ``min_iterations`` nor while the strategy still densifies). The
whole-scene 3DGS baseline is the same trainer with ``masks=None``, no context and SfM points as ``init``.

Frames: everything is trained in the cameras' local frame shifted by the mean camera centre (float64 shift, then
float32); results come back as :class:`core.GaussianSet` in the cameras' local frame and origin.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from core.cameras import Cameras
from core.errors import ConfigError, DataError
from core.gaussians import GaussianSet
from fusion.render.projection import quat_to_rotmat
from fusion.train.loss import masked_photometric_loss
from fusion.train.msssim import smoothl1_msssim_loss
from fusion.train.params import (
    context_from_set,
    make_optimizer,
    make_parameters,
    set_from_tensors,
    tensors_from_set,
)
from fusion.train.perceptual import MIN_SIZE, PerceptualCrop, PerceptualNetwork, perceptual_loss, prepare_crop
from fusion.train.priors import PriorOptions, prior_loss, view_priors
from fusion.train.render import project_context, render_step
from fusion.train.strategy import DefaultStrategy, MCMCStrategy, RefineCounts
from fusion.train.views import prepare_views


@dataclass(frozen=True)
class HardViewOptions:
    """Hard-view mining (as in the industrial digital-twin 3DGS study): between ``start`` and ``stop`` (shares of
    ``iterations``) each step's view is drawn with probability ``(1 − uniform_mix) · L_v^power / Σ L^power +
    uniform_mix / V``, L_v the view's running loss (exponential average with weight ``ema`` on the newest value;
    views not yet seen count with the mean), so the views the model fits worst are seen more often while every view
    keeps a floor. Outside the window, seeded per-epoch permutations as without mining."""

    start: float = 0.3
    stop: float = 0.8
    power: float = 1.0
    uniform_mix: float = 0.3
    ema: float = 0.5

    def __post_init__(self) -> None:
        if not 0.0 <= self.start <= self.stop <= 1.0:
            raise ConfigError(f"need 0 <= start <= stop <= 1, got {self.start}, {self.stop}")
        if not (self.power >= 0 and 0.0 <= self.uniform_mix <= 1.0 and 0.0 < self.ema <= 1.0):
            raise ConfigError("need power >= 0, uniform_mix in [0, 1] and ema in (0, 1]")

    def probabilities(self, running: np.ndarray) -> np.ndarray:
        """(V,) sampling probabilities from the views' running losses (V,) (NaN = not seen yet)."""
        seen = np.isfinite(running)
        fill = float(running[seen].mean()) if seen.any() else 1.0
        loss = np.maximum(np.where(seen, running, fill), 1e-12) ** self.power
        return (1.0 - self.uniform_mix) * loss / loss.sum() + self.uniform_mix / len(loss)


@dataclass(frozen=True)
class TrainOptions:
    """Options of :func:`train_splats` (learning rates per step as in 3DGS / gsplat; lengths in metres).

    iterations: maximum number of steps. downscale: integer factor for photos, masks and intrinsics (2 on a CPU:
    a quarter of the pixels). sh_degree: highest SH degree, reached one degree per ``sh_degree_interval`` steps.
    scale_reg: weight of mean(σ) / scene scale (keeps splats small). flat: surface-aligned splats, the smallest σ
    of each driven towards zero with weight ``flat_reg`` (mean smallest σ / scene scale); normals = that axis.
    holdout_fraction / eval_every / patience / min_improvement_db / min_iterations: early stopping (see module).
    refine_until: share of ``iterations`` after which the strategy no longer densifies (its ``refine_stop`` is
    lowered to it; 3DGS: 15 000 of 30 000 steps). Gaussians added late are never fitted: a split at the last step
    replaces each Gaussian by two unfitted halves. Early stopping waits for the end of densification too.
    snapshot_iterations: steps after which a copy of the trainable set is kept. backend: ``cpu`` or ``reference``.
    hard_views: hard-view mining (:class:`HardViewOptions`), None = every view once per epoch throughout.
    photometric: ``l1_ssim`` (3DGS: 0.8 · L1 + 0.2 · (1 − SSIM)) or ``smoothl1_msssim`` ((1 − λ) · SmoothL1 with
    ``smoothl1_beta`` + λ · (1 − MS-SSIM), :mod:`fusion.train.msssim`; needs > 160 px on the shorter side).
    lpips_weight: weight of an LPIPS term on the loss pixels (:mod:`fusion.train.perceptual`; needs the
    ``lpips`` network argument of :func:`train_splats`) from step ``ceil(lpips_start × iterations)`` on; 0 = off.
    lpips_margin: context pixels around the loss pixels' bounding box.
    priors: depth / normal priors from the frozen context (the trusted MVS surface) at the mask borders
    (:mod:`fusion.train.priors`); None = off (the whole-scene baseline has no context and never uses them).
    """

    iterations: int = 2000
    downscale: int = 1
    seed: int = 0
    sh_degree: int = 3
    sh_degree_interval: int = 500
    ssim_lambda: float = 0.2
    lr_means: float = 1.6e-4
    lr_means_final: float = 0.01
    lr_log_scales: float = 5e-3
    lr_quats: float = 1e-3
    lr_opacities: float = 5e-2
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20
    scale_reg: float = 0.0
    flat: bool = False
    flat_reg: float = 10.0
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    holdout_fraction: float = 0.05
    eval_every: int = 100
    patience: int = 3
    min_improvement_db: float = 0.05
    min_iterations: int = 600
    refine_until: float = 0.5
    snapshot_iterations: tuple[int, ...] = ()
    backend: str = "cpu"
    priors: PriorOptions | None = None
    hard_views: HardViewOptions | None = None
    photometric: str = "l1_ssim"
    smoothl1_beta: float = 0.05
    lpips_weight: float = 0.0
    lpips_start: float = 0.8
    lpips_margin: int = 16
    strategy: DefaultStrategy | MCMCStrategy = field(default_factory=DefaultStrategy)

    def __post_init__(self) -> None:
        if self.iterations < 1:
            raise ConfigError(f"iterations must be >= 1, got {self.iterations}")
        if not 0 <= self.sh_degree <= 3:
            raise ConfigError(f"sh_degree must be 0..3, got {self.sh_degree}")
        if self.sh_degree_interval < 1 or self.eval_every < 1 or self.patience < 1:
            raise ConfigError("sh_degree_interval, eval_every and patience must be >= 1")
        if not 0.0 < self.refine_until <= 1.0:
            raise ConfigError(f"refine_until must lie in (0, 1], got {self.refine_until}")
        if not 0.0 <= self.ssim_lambda <= 1.0:
            raise ConfigError(f"ssim_lambda must lie in [0, 1], got {self.ssim_lambda}")
        if self.photometric not in ("l1_ssim", "smoothl1_msssim") or not self.smoothl1_beta > 0:
            raise ConfigError(
                f"photometric must be 'l1_ssim' or 'smoothl1_msssim' (beta > 0), got {self.photometric!r}"
            )
        if self.backend not in ("cpu", "reference"):
            raise ConfigError(f"backend must be 'cpu' or 'reference', got {self.backend!r}")
        if not (self.lpips_weight >= 0 and 0.0 <= self.lpips_start <= 1.0 and self.lpips_margin >= 0):
            raise ConfigError(
                f"need lpips_weight >= 0, lpips_start in [0, 1] and lpips_margin >= 0, got {self.lpips_weight}, "
                f"{self.lpips_start}, {self.lpips_margin}"
            )


@dataclass(frozen=True)
class Checkpoint:
    """Training state at the end of an evaluation window: step, mean loss over the window, hold-out PSNR (dB) of
    the window's renders, trainable count, seconds since the start."""

    step: int
    loss: float
    holdout_psnr: float
    gaussians: int
    seconds: float
    prior_depth: float = float("nan")  # window mean of the weighted |log z − log z_prior| (NaN: no prior)
    prior_normal: float = float("nan")  # window mean of the weighted 1 − |n · n_prior|


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
    prior_views: int = 0  # views with a depth / normal prior
    prior_pixels: int = 0  # their pixels with a prior weight > 0
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


def scene_scale(cameras: Cameras) -> float:
    """1.1 × the largest distance of a camera centre from the centres' mean (3DGS), metres (≥ 1e-6)."""
    centres = np.array([v.center for v in cameras])
    if len(centres) == 0:
        raise DataError("no cameras: cannot train")
    return max(1.1 * float(np.linalg.norm(centres - centres.mean(0), axis=1).max()), 1e-6)


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


def train_splats(
    cameras: Cameras,
    images: Mapping[str, np.ndarray],
    masks: Mapping[str, np.ndarray] | None,
    init: GaussianSet,
    context: GaussianSet | None = None,
    options: TrainOptions | None = None,
    progress: Callable[[StepInfo], None] | None = None,
    lpips: PerceptualNetwork | None = None,
) -> TrainResult:
    """Train ``init`` (any origin) against ``images`` inside ``masks``, with ``context`` frozen beside it.

    images: name → (H, W, 3) photo at its camera's size (uint8 or float in [0, 1]); only names with a camera and,
    with masks, a non-empty mask are used. masks: name → (H, W) bool, or None for whole images. Returns a
    :class:`TrainResult`; deterministic for a given seed on the CPU.
    lpips: the frozen LPIPS network (an :class:`eval.lpips.LPIPS`), needed when ``options.lpips_weight`` > 0 and
    never called otherwise.
    """
    opts = options or TrainOptions()
    t0 = time.perf_counter()
    if opts.lpips_weight > 0 and lpips is None:
        raise ConfigError("lpips_weight > 0 needs the LPIPS network (eval.lpips.LPIPS with its weights file)")
    if len(init) == 0:
        raise DataError("no initial splats to train (the regions got no seeds)")
    origin = cameras.origin
    centres = np.array([v.center for v in cameras])
    centre = centres.mean(axis=0)
    scale = scene_scale(cameras)
    views = prepare_views(
        cameras, images, masks, centre, downscale=opts.downscale, holdout_fraction=opts.holdout_fraction,
        seed=opts.seed,
    )  # fmt: skip
    if not views:
        raise DataError("no training view has mask pixels: nothing to train")
    lpips_from = math.ceil(opts.lpips_start * opts.iterations) if opts.lpips_weight > 0 else opts.iterations + 1
    lpips_crops: dict[int, PerceptualCrop | None] = {}
    if lpips_from <= opts.iterations and min(min(v.width, v.height) for v in views) < MIN_SIZE:
        raise ConfigError(f"the LPIPS term needs training images of at least {MIN_SIZE}×{MIN_SIZE} pixels")
    gen = torch.Generator().manual_seed(opts.seed)
    rng = np.random.default_rng(opts.seed)

    init = init.with_origin(origin)
    if len(init) > opts.strategy.cap:
        init = init.subset(np.sort(rng.choice(len(init), opts.strategy.cap, replace=False)))
    params = make_parameters(tensors_from_set(init, centre, opts.sh_degree))
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
    priors = None
    if opts.priors is not None and opts.priors.active and frozen is not None:
        priors = view_priors(views, frozen.means.numpy(), opts.priors)

    lrs = {
        "means": opts.lr_means * scale,
        "quats": opts.lr_quats,
        "log_scales": opts.lr_log_scales,
        "logit_opacities": opts.lr_opacities,
        "sh_dc": opts.lr_sh_dc,
        "sh_rest": opts.lr_sh_rest,
    }
    optimizer = make_optimizer(params, lrs)
    strategy = opts.strategy
    last_refine = int(opts.refine_until * opts.iterations)
    if strategy.refine_stop > last_refine:
        strategy = replace(strategy, refine_stop=max(strategy.refine_start, last_refine))
    densifying_until = strategy.refine_stop if strategy.refine_start < strategy.refine_stop else 0
    state = strategy.initial_state(len(init))
    background = torch.tensor(opts.background, dtype=torch.float32)
    decay = opts.lr_means_final ** (1.0 / max(1, opts.iterations))

    window = len(views) * math.ceil(opts.eval_every / len(views))  # whole epochs, so windows are comparable
    history: list[Checkpoint] = []
    snapshots: dict[int, GaussianSet] = {}
    snapshot_seconds: dict[int, float] = {}
    best, stale, stopped = -math.inf, 0, False
    sq_err, n_err, loss_sum, n_loss = 0.0, 0, 0.0, 0
    prior_sums = [0.0, 0.0, 0]  # depth, normal, steps with a prior term
    order = rng.permutation(len(views))
    running = np.full(len(views), np.nan)  # per-view running loss (hard-view mining)
    hard = opts.hard_views
    mining = (
        (int(hard.start * opts.iterations), int(hard.stop * opts.iterations)) if hard is not None else (0, 0)
    )  # fmt: skip
    view_counts = np.zeros(len(views), np.int64)
    step = 0
    psnr = float("nan")
    while step < opts.iterations:
        if hard is not None and mining[0] <= step < mining[1]:
            vi = int(rng.choice(len(views), p=hard.probabilities(running)))
        else:
            pos = step % len(views)
            if pos == 0 and step > 0:
                order = rng.permutation(len(views))
            vi = int(order[pos])
        view_counts[vi] += 1
        view = views[vi]
        degree = min(opts.sh_degree, step // opts.sh_degree_interval)
        for group in optimizer.param_groups:
            if group["name"] == "means":
                group["lr"] = lrs["means"] * decay**step

        only_loss_pixels = opts.photometric == "l1_ssim" and step < lpips_from
        out = render_step(params, view, caches[vi], degree, background, opts.backend, only_loss_pixels)
        if opts.photometric == "l1_ssim":
            terms = masked_photometric_loss(out.colour, view.image, view.loss_mask, opts.ssim_lambda)
        else:
            terms = smoothl1_msssim_loss(out.colour, view.image, view.loss_mask, opts.ssim_lambda, opts.smoothl1_beta)
        loss = terms.loss
        if step >= lpips_from:
            if vi not in lpips_crops:
                lpips_crops[vi] = prepare_crop(view, opts.lpips_margin)
            if lpips_crops[vi] is not None:
                loss = loss + opts.lpips_weight * perceptual_loss(out.colour, lpips_crops[vi], lpips)
        if opts.scale_reg > 0:
            loss = loss + opts.scale_reg * params["log_scales"].exp().mean() / scale
        if opts.flat:
            loss = loss + opts.flat_reg * params["log_scales"].exp().amin(dim=1).mean() / scale
        loss = loss + strategy.regularisation(params)
        if priors is not None:
            p_terms = prior_loss(params, view, priors[vi], opts.priors)
            if p_terms.splats:
                loss = loss + p_terms.loss
                prior_sums[0] += float(p_terms.depth)
                prior_sums[1] += float(p_terms.normal)
                prior_sums[2] += 1
        loss.backward()
        strategy.after_backward(state, out.means2d, view.width, view.height, step)
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)
        step += 1
        lr_now = lrs["means"] * decay ** (step - 1)
        strategy.refine(state, params, optimizer, step, opts.iterations, scale, gen, lr_means=lr_now)

        with torch.no_grad():
            hold = view.holdout_mask
            if bool(hold.any()):
                diff = (out.colour.detach().clamp(0, 1) - view.image)[hold]
                sq_err += float((diff * diff).sum())
                n_err += int(diff.numel())
        loss_now = float(terms.loss.detach())
        loss_sum += loss_now
        n_loss += 1
        if hard is not None:
            ema = hard.ema
            running[vi] = loss_now if not np.isfinite(running[vi]) else (1 - ema) * running[vi] + ema * loss_now
        if step in opts.snapshot_iterations:
            snapshot_seconds[step] = time.perf_counter() - t0
            snapshots[step] = _with_normals(set_from_tensors(params, centre, origin))
        if step % window == 0 or step == opts.iterations:
            psnr = -10.0 * math.log10(max(sq_err / max(n_err, 1), 1e-10)) if n_err else float("nan")
            n_now = int(params["means"].shape[0])
            pd, pn = (
                (prior_sums[0] / prior_sums[2], prior_sums[1] / prior_sums[2]) if prior_sums[2] else (math.nan,) * 2
            )
            history.append(Checkpoint(step, loss_sum / max(n_loss, 1), psnr, n_now, time.perf_counter() - t0, pd, pn))
            sq_err, n_err, loss_sum, n_loss = 0.0, 0, 0.0, 0
            prior_sums = [0.0, 0.0, 0]
            if psnr > best + opts.min_improvement_db:
                best, stale = psnr, 0
            else:
                stale += 1
            if stale >= opts.patience and step >= max(opts.min_iterations, densifying_until) and step < opts.iterations:
                stopped = True
                break
        if progress is not None:
            progress(StepInfo(step, opts.iterations, float(terms.loss.detach()), psnr, int(params["means"].shape[0])))

    splats = _with_normals(set_from_tensors(params, centre, origin))
    return TrainResult(
        splats=splats,
        snapshots=snapshots,
        history=history,
        iterations=step,
        stopped_early=stopped,
        views_used=len(views),
        views_without_mask=len(images) - len(views),
        mask_pixels=int(sum(v.mask_pixels for v in views)),
        context_total=context_total,
        context_culled=context_culled,
        initial_gaussians=len(init),
        refine=state.totals,
        seconds=time.perf_counter() - t0,
        scene_scale=scale,
        resolution=(views[0].width, views[0].height),
        view_steps=tuple(int(c) for c in view_counts),
        prior_views=sum(p is not None for p in priors) if priors is not None else 0,
        prior_pixels=sum(p.pixels for p in priors if p is not None) if priors is not None else 0,
        snapshot_seconds=snapshot_seconds,
    )
