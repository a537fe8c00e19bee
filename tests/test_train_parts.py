"""The parts the trainer is composed of, each alone: the schedule, early stopping, the view sampler, one step, and
the strategy interface as the loop drives it."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest
import torch
from test_train_trainer import blob_set, perturbed, render_all, ring_cameras

from fusion.train import DefaultStrategy, TrainOptions, train_splats
from fusion.train.early_stop import EarlyStop, EvalWindow
from fusion.train.render import render_step
from fusion.train.sampler import ViewSampler
from fusion.train.schedule import TrainSchedule, clip_refinement
from fusion.train.state import initial_state, prepare_scene
from fusion.train.step import photometric_terms, refine_after_step, step_loss, train_step
from fusion.train.strategy import RefineCounts


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    """Small images: one thread avoids OpenMP spinning on shared cores (results do not depend on it)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# -- schedule -----------------------------------------------------------------------------------------------------
def test_means_learning_rate_follows_the_closed_form_exponential_decay() -> None:
    opts = TrainOptions(iterations=1000, lr_means=1.6e-4, lr_means_final=0.01)
    s = TrainSchedule.from_options(opts, scene_scale=2.5, n_views=7)
    start = 1.6e-4 * 2.5
    for step in (0, 1, 250, 500, 999, 1000):
        # lr(t) = lr0 · final^(t / T): a straight line in log space from lr0 to final · lr0
        assert s.lr_means(step) == pytest.approx(start * 0.01 ** (step / 1000), rel=1e-12)
    assert s.lr_means(0) == start and s.lr_means(1000) == pytest.approx(0.01 * start, rel=1e-12)


def test_sh_degree_evaluation_windows_and_snapshots() -> None:
    opts = TrainOptions(
        iterations=100, sh_degree=2, sh_degree_interval=30, eval_every=10, snapshot_iterations=(40, 100)
    )
    s = TrainSchedule.from_options(opts, 1.0, n_views=4)
    assert [s.sh_degree_at(t) for t in (0, 29, 30, 59, 60, 99)] == [0, 0, 1, 1, 2, 2]
    assert s.eval_window == 12  # eval_every 10 rounded up to whole epochs of 4 views
    assert [d for d in range(1, 101) if s.evaluate_after(d)] == [*range(12, 100, 12), 100]
    assert [d for d in range(1, 101) if s.snapshot_after(d)] == [40, 100]


def test_refinement_window_is_clipped_to_refine_until() -> None:
    strategy = DefaultStrategy(refine_start=100, refine_stop=15_000)
    assert clip_refinement(strategy, 0.5, 1000).refine_stop == 500
    assert clip_refinement(strategy, 0.5, 100_000) is strategy  # already stops earlier
    assert clip_refinement(strategy, 0.01, 1000).refine_stop == 100  # never below its start
    s = TrainSchedule.from_options(TrainOptions(iterations=1000, strategy=strategy), 1.0, 3)
    assert s.strategy.refine_stop == 500 and s.densifying_until == 500
    never = TrainOptions(iterations=1000, strategy=DefaultStrategy(refine_start=10_000))
    assert TrainSchedule.from_options(never, 1.0, 3).densifying_until == 0


# -- early stop ---------------------------------------------------------------------------------------------------
def test_early_stop_detects_a_plateau_of_the_holdout_psnr() -> None:
    stop = EarlyStop(min_improvement_db=0.1, patience=3, min_step=0, last_step=10_000)
    psnr = [20.0, 22.0, 23.0, 23.5, 23.55, 23.52, 23.58, 23.7]  # rises, then gains < 0.1 dB three windows in a row
    decisions = [stop.update(p, 100 * (i + 1)) for i, p in enumerate(psnr)]
    assert decisions == [False] * 6 + [True, False]  # stops at the 3rd stale window; a gain resets the count
    assert stop.best == 23.7 and stop.stale == 0


def test_early_stop_waits_for_min_step_and_never_stops_at_the_last_step() -> None:
    stop = EarlyStop(min_improvement_db=0.1, patience=1, min_step=300, last_step=500)
    assert [stop.update(20.0, s) for s in (100, 200, 300, 400, 500)] == [False, False, True, True, False]
    nan = EarlyStop(min_improvement_db=0.1, patience=2, min_step=0, last_step=1000)
    assert [nan.update(math.nan, s) for s in (1, 2)] == [False, True]  # no hold-out pixels: never an improvement


def test_eval_window_psnr_and_means() -> None:
    cams = ring_cameras(2)
    photos = render_all(blob_set(30, 1), cams)
    scene = prepare_scene(cams, photos, None, None, TrainOptions(holdout_fraction=0.1))
    view = scene.views[0]
    w = EvalWindow()
    assert math.isnan(w.holdout_psnr())
    w.add_holdout(view.image + 0.1, view)  # error 0.1 on every hold-out channel (where the photo is < 0.9)
    err = np.clip(view.image.numpy() + 0.1, 0, 1) - view.image.numpy()
    mse = float((err[view.holdout_mask.numpy()] ** 2).mean())
    assert w.holdout_psnr() == pytest.approx(-10 * math.log10(mse), rel=1e-5)
    w.add_loss(0.2)
    w.add_loss(0.4)
    c = w.checkpoint(step=7, gaussians=30, seconds=1.0)
    assert (c.step, c.gaussians, c.loss) == (7, 30, pytest.approx(0.3))


# -- view sampler -------------------------------------------------------------------------------------------------
def test_sampler_visits_every_view_once_per_epoch() -> None:
    s = ViewSampler.start(5, np.random.default_rng(0))
    epochs = [[s.next(step) for step in range(e * 5, e * 5 + 5)] for e in range(4)]
    assert all(sorted(e) == list(range(5)) for e in epochs) and len({tuple(e) for e in epochs}) > 1
    assert s.counts.tolist() == [4] * 5
    rng = np.random.default_rng(0)  # the same seeded sequence: one permutation per epoch, drawn at its start
    assert epochs == [rng.permutation(5).tolist() for _ in range(4)]


# -- one step -----------------------------------------------------------------------------------------------------
def _tiny(iterations: int = 10, **kw):
    cams = ring_cameras(4)
    truth = blob_set(60, 2)
    photos = render_all(truth, cams)
    opts = TrainOptions(iterations=iterations, sh_degree=0, seed=3, lr_sh_dc=0.02,
                        strategy=kw.pop("strategy", DefaultStrategy(refine_start=10_000)), **kw)  # fmt: skip
    return cams, photos, perturbed(truth, 6), opts


def test_one_step_lowers_the_loss_of_its_view() -> None:
    cams, photos, init, opts = _tiny()
    scene = prepare_scene(cams, photos, None, None, opts)
    schedule = TrainSchedule.from_options(opts, scene.scale, len(scene.views))
    state = initial_state(init, scene, schedule, opts)

    def loss_on(view: int) -> float:
        with torch.no_grad():
            out = render_step(state.params, scene.views[view], None, 0, scene.background)
            return float(photometric_terms(out.colour, scene.views[view], opts).loss)

    before = loss_on(1)
    outcome = train_step(state, scene, schedule, opts, 1)
    assert state.step == 1 and outcome.view == 1 and outcome.loss == pytest.approx(before, rel=1e-5)
    assert loss_on(1) < before
    assert all(p.grad is None for p in state.params.values())  # gradients cleared after the Adam step


def test_step_loss_adds_the_scale_regulariser() -> None:
    cams, photos, init, opts = _tiny(scale_reg=0.5)
    scene = prepare_scene(cams, photos, None, None, opts)
    schedule = TrainSchedule.from_options(opts, scene.scale, len(scene.views))
    state = initial_state(init, scene, schedule, opts)
    out = render_step(state.params, scene.views[0], None, 0, scene.background)
    loss = step_loss(state.params, scene.views[0], out, opts, scene.scale, schedule.strategy)
    sigma = state.params["log_scales"].detach().exp()
    expected = loss.terms.loss.detach() + 0.5 * sigma.mean() / scene.scale
    assert float(loss.total.detach()) == pytest.approx(float(expected), rel=1e-6)


@dataclass(frozen=True)
class _RecordingStrategy:
    """A do-nothing strategy that records how the trainer drives the :class:`Strategy` interface."""

    calls: list = field(default_factory=list)
    cap: int = 1000
    refine_start: int = 0
    refine_stop: int = 0

    def initial_state(self, n: int):
        return DefaultStrategy().initial_state(n)

    def regularisation(self, params):
        return torch.zeros(())

    def after_backward(self, state, means2d, width, height, step, **_):
        self.calls.append(("after_backward", step, means2d.grad is not None))

    def refine(self, state, params, optimizer, step, total_steps, scene_scale, generator, **_):
        self.calls.append(("refine", step, total_steps))
        return RefineCounts()


def test_trainer_drives_the_strategy_interface_each_step() -> None:
    rec = _RecordingStrategy()
    cams, photos, init, opts = _tiny(iterations=3, strategy=rec)
    train_splats(cams, photos, None, init, options=opts)
    assert rec.calls == [call for t in range(3) for call in (("after_backward", t, True), ("refine", t + 1, 3))]


def test_refine_after_step_passes_the_finished_steps_and_the_run_length() -> None:
    rec = _RecordingStrategy()
    cams, photos, init, opts = _tiny(strategy=rec)
    scene = prepare_scene(cams, photos, None, None, opts)
    schedule = TrainSchedule.from_options(opts, scene.scale, len(scene.views))
    state = initial_state(init, scene, schedule, opts)
    state.step = 5
    refine_after_step(state, scene, schedule)
    assert rec.calls == [("refine", 5, opts.iterations)]


def test_options_and_strategies_are_configured_without_torch() -> None:
    """The trainer's options (and the strategies they name) import and validate without loading torch, so the
    pipeline's configuration and the command line can check them cheaply."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from fusion.train.options import TrainOptions\n"
        "from fusion.train.strategy import DefaultStrategy\n"
        "TrainOptions(strategy=DefaultStrategy(cap=10))\n"
        "print('torch' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False", out.stderr
