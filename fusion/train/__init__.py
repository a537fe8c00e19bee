"""fusion.train: splats trained inside masks next to frozen MVS Gaussians (and the whole-scene baseline).

- :func:`train_splats` / :class:`TrainResult` — the trainer loop (:mod:`fusion.train.trainer`), composed of a
  state (:mod:`~fusion.train.state`), a step (:mod:`~fusion.train.step`), a schedule (:mod:`~fusion.train.schedule`),
  early stopping (:mod:`~fusion.train.early_stop`) and a view sampler (:mod:`~fusion.train.sampler`).
- :class:`TrainOptions` — its options (:mod:`fusion.train.options`).
- :class:`DefaultStrategy` — capped densification (:mod:`fusion.train.strategy`).
- :func:`masked_photometric_loss` — 0.8 · L1 + 0.2 · (1 − SSIM) over mask pixels (:mod:`fusion.train.loss`).

The names are imported lazily (:func:`core.lazy.lazy_exports`): ``import fusion.train`` or a torch-free
submodule (:mod:`fusion.train.init`, :mod:`fusion.train.options`, :mod:`fusion.train.strategy`) does not load torch;
the first use of a name imports its submodule (the options and strategies without torch).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from core.lazy import lazy_exports

if TYPE_CHECKING:
    from fusion.train.loss import masked_photometric_loss, ssim_map
    from fusion.train.options import TrainOptions
    from fusion.train.state import scene_scale
    from fusion.train.strategy import DefaultStrategy, RefineCounts
    from fusion.train.trainer import StepInfo, TrainResult, splat_normals, train_splats

#: name -> submodule that defines it (imported on first access: the package itself imports nothing heavy)
_EXPORTS: dict[str, str] = {
    "DefaultStrategy": "strategy",
    "RefineCounts": "strategy",
    "StepInfo": "trainer",
    "TrainOptions": "options",
    "TrainResult": "trainer",
    "masked_photometric_loss": "loss",
    "scene_scale": "state",
    "splat_normals": "trainer",
    "ssim_map": "loss",
    "train_splats": "trainer",
}

__all__ = [
    "DefaultStrategy",
    "RefineCounts",
    "StepInfo",
    "TrainOptions",
    "TrainResult",
    "masked_photometric_loss",
    "scene_scale",
    "splat_normals",
    "ssim_map",
    "train_splats",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
