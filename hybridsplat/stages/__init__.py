"""The pipeline's stages, in order. Adding a stage = one module here + one entry in ``_STAGE_CLASSES`` (+ its test).

The stage modules are imported lazily (module-level ``__getattr__``): importing one stage module, or calling
:func:`stage_named`, does not import the others and their heavy dependencies (torch, open3d, pycolmap...), so
a command fails on a bad input before those are loaded. ``STAGES`` imports every stage on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the names this package offers, for type checkers and readers
    from hybridsplat.stages.base import Stage, StageContext
    from hybridsplat.stages.baseline import BaselineStage
    from hybridsplat.stages.classify import ClassifyStage
    from hybridsplat.stages.clean import CleanStage
    from hybridsplat.stages.convert import ConvertStage
    from hybridsplat.stages.evaluate import EvalStage
    from hybridsplat.stages.masks import MasksStage
    from hybridsplat.stages.merge import MergeStage
    from hybridsplat.stages.mesh import MeshStage
    from hybridsplat.stages.mvs import MvsStage
    from hybridsplat.stages.report import ReportStage
    from hybridsplat.stages.sfm import SfmStage
    from hybridsplat.stages.train import TrainStage

    STAGES: tuple[Stage, ...]

#: (stage name, module under hybridsplat.stages, class), in pipeline order.
_STAGE_CLASSES: tuple[tuple[str, str, str], ...] = (
    ("sfm", "sfm", "SfmStage"),
    ("mvs", "mvs", "MvsStage"),
    ("classify", "classify", "ClassifyStage"),
    ("masks", "masks", "MasksStage"),
    ("convert", "convert", "ConvertStage"),
    ("train", "train", "TrainStage"),
    ("clean", "clean", "CleanStage"),
    ("merge", "merge", "MergeStage"),
    ("mesh", "mesh", "MeshStage"),
    ("baseline", "baseline", "BaselineStage"),
    ("eval", "evaluate", "EvalStage"),
    ("report", "report", "ReportStage"),
)
_LAZY: dict[str, str] = {cls: module for _name, module, cls in _STAGE_CLASSES}
_LAZY.update(Stage="base", StageContext="base")
_instances: dict[str, Stage] = {}

__all__ = [
    "STAGES",
    "BaselineStage",
    "ClassifyStage",
    "CleanStage",
    "ConvertStage",
    "EvalStage",
    "MasksStage",
    "MergeStage",
    "MeshStage",
    "MvsStage",
    "ReportStage",
    "SfmStage",
    "Stage",
    "StageContext",
    "TrainStage",
    "stage_named",
]


def _stage(name: str, module: str, cls: str) -> Stage:
    """The one instance of stage ``name`` (shared by ``STAGES`` and :func:`stage_named`)."""
    if name not in _instances:
        _instances[name] = getattr(importlib.import_module(f"{__name__}.{module}"), cls)()
    return _instances[name]


def stage_named(name: str) -> Stage:
    """The stage called ``name`` (``"sfm"`` … ``"report"``); imports only that stage's module.

    Raises :class:`KeyError` for an unknown name."""
    for stage_name, module, cls in _STAGE_CLASSES:
        if stage_name == name:
            return _stage(stage_name, module, cls)
    raise KeyError(name)


def __getattr__(attr: str) -> Any:
    if attr == "STAGES":
        stages = tuple(_stage(*entry) for entry in _STAGE_CLASSES)
        globals()["STAGES"] = stages
        return stages
    if attr in _LAZY:
        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[attr]}"), attr)
        globals()[attr] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
