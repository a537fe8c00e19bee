"""hybridsplat.tile_cost: the schedule's makespan against hand-worked and limiting cases, rates recovered exactly from
noiseless tiles, the reference rates scaled to one finished tile, peak memory of N workers."""

import numpy as np
import pytest

from core.errors import ConfigError
from hybridsplat.tile_cost import (
    REFERENCE_RATES,
    CostRates,
    TileSize,
    fit_rates,
    makespan,
    predict,
    tile_peak_mb,
    tile_seconds,
)


def test_makespan_replays_dispatch_in_order_to_the_first_free_worker():
    # 2 workers: 3 | 1 start at 0; the third (2) goes to the worker free at 1 (ends 3); the fourth (2) starts at 3
    assert makespan([3, 1, 2, 2], 2) == 5
    # the order matters (not a sorted LPT schedule): long last is worse (1 | 1, 1 at 1, 3 at 1 on the other)
    assert makespan([1, 1, 1, 3], 2) == 4 and makespan([3, 1, 1, 1], 2) == 3
    rng = np.random.default_rng(0)
    d = rng.uniform(1, 10, 9)
    assert makespan(d, 1) == pytest.approx(d.sum())
    assert makespan(d, 9) == makespan(d, 20) == pytest.approx(d.max())
    assert makespan([], 3) == 0
    with pytest.raises(ConfigError, match="workers"):
        makespan([1.0], 0)


def test_rates_are_recovered_from_noiseless_tiles():
    truth = CostRates(12.0, 0.8, 3.0, 500.0, 90.0, "truth")
    shapes = [(20, 0.08, 300), (45, 0.08, 300), (30, 0.3, 100), (60, 0.3, 1000), (10, 1.2, 500)]
    sizes = [TileSize(f"t{k}", p, m, it) for k, (p, m, it) in enumerate(shapes)]
    seconds = [tile_seconds(s, truth) for s in sizes]
    peaks = [tile_peak_mb(s, truth) for s in sizes]
    fitted = fit_rates(sizes, seconds, peaks)
    assert fitted.source == "fitted"
    for name in ("per_photo_mpx_s", "per_step_mpx_s", "per_tile_s", "base_mb", "per_photo_mpx_mb"):
        assert getattr(fitted, name) == pytest.approx(getattr(truth, name), rel=1e-6), name


def test_one_finished_tile_scales_the_reference_rates():
    size = TileSize("r0c0", 24, 0.0768, 300)
    rates = fit_rates([size], [2 * tile_seconds(size, REFERENCE_RATES)], [1.5 * tile_peak_mb(size, REFERENCE_RATES)])
    assert rates.source == "scaled"
    assert tile_seconds(size, rates) == pytest.approx(2 * tile_seconds(size, REFERENCE_RATES))
    assert tile_peak_mb(size, rates) == pytest.approx(1.5 * tile_peak_mb(size, REFERENCE_RATES))
    with pytest.raises(ConfigError, match="as many"):
        fit_rates([size], [1.0, 2.0], [1.0])


def test_prediction_of_n_workers():
    rates = CostRates(10.0, 0.0, 0.0, 100.0, 10.0)
    sizes = [TileSize(f"t{k}", n, 1.0, 0) for k, n in enumerate([1, 2, 3, 4])]  # 10, 20, 30, 40 s
    one, two = predict(sizes, rates, 1, driver_mb=50.0), predict(sizes, rates, 2, driver_mb=50.0)
    assert one.wall_s == pytest.approx(100.0) and two.wall_s == pytest.approx(60.0)  # 10|20, 30 at 10, 40 at 20
    assert one.peak_mb == pytest.approx(140.0)  # the largest tile, run where the driver is
    assert two.peak_mb == pytest.approx(50.0 + 140.0 + 130.0)  # the driver and the two largest tiles at once
    assert two.to_json()["tile_seconds"] == [10.0, 20.0, 30.0, 40.0]


def test_training_in_phases_waits_for_the_phase_before():
    # work before training 10, 20, 30, 40 s; training 5, 5, 5, 5 s (5 steps of 1 megapixel at 1 s)
    rates = CostRates(10.0, 1.0, 0.0, 100.0, 10.0)
    sizes = [TileSize(f"t{k}", n, 1.0, 5) for k, n in enumerate([1, 2, 3, 4])]
    together = predict(sizes, rates, 2)
    assert together.wall_s == pytest.approx(70.0)  # 15 | 25, 35 at 15, 45 at 25
    phased = predict(sizes, rates, 2, phases=[[0, 3], [1, 2]])
    # before training: 10 | 20, 30 at 10, 40 at 20 -> 60; then each phase's two trainings side by side: 5 + 5
    assert phased.wall_s == pytest.approx(70.0)
    assert predict(sizes, rates, 1, phases=[[0, 3], [1, 2]]).wall_s == pytest.approx(120.0)  # one worker: the sum
    assert phased.tile_seconds == together.tile_seconds == (15.0, 25.0, 35.0, 45.0)
    assert predict(sizes, rates, 4, phases=[[0], [1], [2], [3]]).wall_s == pytest.approx(40.0 + 20.0)
