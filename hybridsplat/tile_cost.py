"""The cost model of a tiled run: predicted wall time and peak memory for N workers (issue 34).

A tile's work grows with the pixels it handles: depth estimation, classification, masks, conversion and cleaning
with its photos' pixels (``photos × megapixels a photo``), training with ``iterations × megapixels a photo`` (one
photo rendered a step). So a tile's seconds are predicted as::

    seconds = per_photo_mpx_s × photos × mpx + per_step_mpx_s × iterations × mpx + per_tile_s

and its peak memory (one worker process) as ``base_mb + per_photo_mpx_mb × photos × mpx``. The rates are fitted to
the tiles of this project that already finished (a resumed or repeated run: least squares, non-negative), else
:data:`REFERENCE_RATES`. The wall time for N workers replays Ray's order: tiles are dispatched in plan order, each
to the first worker that is free (list scheduling), so the prediction is that schedule's makespan; the peak memory
is the driver's plus the N largest tiles running at once. Tiles that train in phases (their neighbours' splats as
context) add one such schedule per phase for their training.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from core.errors import ConfigError


@dataclass(frozen=True)
class TileSize:
    """What sets a tile's cost: its training photos, the megapixels of one (as MVS and training see it, after
    ``--max-image-size``) and the training iterations."""

    name: str
    photos: int
    mpx: float
    iterations: int


@dataclass(frozen=True)
class CostRates:
    """Seconds per photo-megapixel, per training step-megapixel and per tile; memory in MB (see module docstring)."""

    per_photo_mpx_s: float
    per_step_mpx_s: float
    per_tile_s: float
    base_mb: float
    per_photo_mpx_mb: float
    source: str = "reference"


REFERENCE_RATES = CostRates(
    per_photo_mpx_s=11.6, per_step_mpx_s=0.75, per_tile_s=2.0, base_mb=700.0, per_photo_mpx_mb=150.0
)
"""Rates of the 2-core reference machine (Python 3.11, torch CPU) for a tile task of one CPU: fitted on the demo
scene (seed 0, 24 photos of 320 × 240, 300 training steps) run as 2 × 1 tiles on 2 Ray workers of one CPU each
(docs/experiments/2026-11-29-tiled-appearance.md; the memory rates of the first fit, 2026-11-28, on tiles in one
process, docs/experiments/2026-11-28-tiled-runs.md); a project's own finished tiles replace them."""


@dataclass(frozen=True)
class CostPrediction:
    """Predicted wall time (s) and peak memory (MB) of the tiles for ``workers`` workers, and per tile seconds."""

    workers: int
    wall_s: float
    peak_mb: float
    tile_seconds: tuple[float, ...]
    rates: CostRates

    def to_json(self) -> dict:
        return {"workers": self.workers, "wall_s": self.wall_s, "peak_mb": self.peak_mb,
                "tile_seconds": list(self.tile_seconds), "rates": asdict(self.rates)}  # fmt: skip


def _terms(size: TileSize) -> np.ndarray:
    return np.array([size.photos * size.mpx, size.iterations * size.mpx, 1.0])


def fit_rates(sizes: Sequence[TileSize], seconds: Sequence[float], peaks_mb: Sequence[float]) -> CostRates:
    """Rates fitted to finished tiles (their sizes, seconds and worker peak MB): non-negative least squares of the
    seconds on the three terms, memory a line through the peaks; fewer than three tiles scale the reference rates
    by what they took instead (three rates cannot be told apart from fewer tiles)."""
    from scipy.optimize import nnls

    if len(sizes) != len(seconds) or len(sizes) != len(peaks_mb) or not sizes:
        raise ConfigError(f"fit_rates needs as many sizes, seconds and peaks (≥ 1), got {len(sizes)}, "
                          f"{len(seconds)}, {len(peaks_mb)}")  # fmt: skip
    if len(sizes) < 3:  # fewer tiles than rates: the reference rates scaled to what these tiles took
        ratio = float(np.sum(seconds)) / max(sum(tile_seconds(s, REFERENCE_RATES) for s in sizes), 1e-9)
        mb = float(np.max(peaks_mb)) / max(max(tile_peak_mb(s, REFERENCE_RATES) for s in sizes), 1e-9)
        r = REFERENCE_RATES
        return CostRates(r.per_photo_mpx_s * ratio, r.per_step_mpx_s * ratio, r.per_tile_s * ratio,
                         r.base_mb * mb, r.per_photo_mpx_mb * mb, "scaled")  # fmt: skip
    a = np.stack([_terms(s) for s in sizes])
    scale = np.maximum(a.max(axis=0), 1e-12)  # columns of very different sizes: solve in unit columns
    coef, _ = nnls(a / scale, np.asarray(seconds, dtype=np.float64))
    coef = coef / scale
    pixels = np.array([s.photos * s.mpx for s in sizes])
    peaks = np.asarray(peaks_mb, dtype=np.float64)
    if len(sizes) > 1 and np.ptp(pixels) > 0:
        slope = max(float(np.polyfit(pixels, peaks, 1)[0]), 0.0)
    else:
        slope = REFERENCE_RATES.per_photo_mpx_mb
    base = float(np.min(peaks - slope * pixels))
    return CostRates(float(coef[0]), float(coef[1]), float(coef[2]), max(base, 0.0), slope, "fitted")


def tile_seconds(size: TileSize, rates: CostRates) -> float:
    return float(_terms(size) @ np.array([rates.per_photo_mpx_s, rates.per_step_mpx_s, rates.per_tile_s]))


def tile_peak_mb(size: TileSize, rates: CostRates) -> float:
    return rates.base_mb + rates.per_photo_mpx_mb * size.photos * size.mpx


def makespan(durations: Sequence[float], workers: int) -> float:
    """Wall time of tasks dispatched in the given order, each to the first free of ``workers`` workers."""
    if workers < 1:
        raise ConfigError(f"workers must be ≥ 1, got {workers}")
    free = [0.0] * min(workers, max(len(durations), 1))
    heapq.heapify(free)
    end = 0.0
    for d in durations:
        start = heapq.heappop(free)
        end = max(end, start + float(d))
        heapq.heappush(free, start + float(d))
    return end


def predict(
    sizes: Sequence[TileSize],
    rates: CostRates,
    workers: int,
    driver_mb: float = 0.0,
    phases: Sequence[Sequence[int]] | None = None,
) -> CostPrediction:
    """The wall time and peak memory of running ``sizes`` (in dispatch order) on ``workers`` workers.

    phases: None when each tile runs all its stages in one task; else the training phases (positions in ``sizes``):
    every tile's work before training at once, then each phase's training (``per_step_mpx_s`` term) after the
    previous phase finished (:func:`hybridsplat.tiled_run.run_in_phases`)."""
    seconds = [tile_seconds(s, rates) for s in sizes]
    peaks = sorted((tile_peak_mb(s, rates) for s in sizes), reverse=True)
    peak = driver_mb + sum(peaks[: max(workers, 1)]) if workers > 1 else max([driver_mb, *peaks])
    if phases is None:
        wall = makespan(seconds, workers)
    else:
        training = [s.iterations * s.mpx * rates.per_step_mpx_s for s in sizes]
        wall = makespan([t - r for t, r in zip(seconds, training, strict=True)], workers)
        wall += sum(makespan([training[k] for k in phase], workers) for phase in phases)
    return CostPrediction(workers, wall, float(peak), tuple(seconds), rates)
