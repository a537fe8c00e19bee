"""fusion.train: splats trained inside masks next to frozen MVS Gaussians (and the whole-scene baseline).

- :func:`train_splats` / :class:`TrainOptions` / :class:`TrainResult` — the trainer (:mod:`fusion.train.trainer`).
- :class:`DefaultStrategy` / :class:`MCMCStrategy` — capped densification (:mod:`fusion.train.strategy`).
- :func:`masked_photometric_loss` — 0.8 · L1 + 0.2 · (1 − SSIM) over mask pixels (:mod:`fusion.train.loss`).

The names are imported lazily (module-level ``__getattr__``): ``import fusion.train`` or a torch-free
submodule (e.g. :mod:`fusion.train.init`) does not load torch; the first use of a name imports its submodule.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fusion.train.loss import masked_photometric_loss, ssim_map
    from fusion.train.priors import PriorOptions
    from fusion.train.strategy import DefaultStrategy, MCMCStrategy, RefineCounts
    from fusion.train.trainer import (
        HardViewOptions,
        StepInfo,
        TrainOptions,
        TrainResult,
        scene_scale,
        splat_normals,
        train_splats,
    )

#: name -> submodule that defines it (imported on first access: the package itself imports nothing heavy)
_EXPORTS: dict[str, str] = {
    "DefaultStrategy": "strategy",
    "HardViewOptions": "trainer",
    "MCMCStrategy": "strategy",
    "PriorOptions": "priors",
    "RefineCounts": "strategy",
    "StepInfo": "trainer",
    "TrainOptions": "trainer",
    "TrainResult": "trainer",
    "masked_photometric_loss": "loss",
    "scene_scale": "trainer",
    "splat_normals": "trainer",
    "ssim_map": "loss",
    "train_splats": "trainer",
}

__all__ = [
    "DefaultStrategy",
    "HardViewOptions",
    "PriorOptions",
    "MCMCStrategy",
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


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
