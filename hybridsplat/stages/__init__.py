"""The pipeline's stages, in order: the registry.

Adding a stage is its module (a :class:`~hybridsplat.stages.base.Stage` subclass with its typed ``Result``, see
:mod:`hybridsplat.stages.base`) and one ``register_stage`` line below; its per-stage command, its ``run`` options and
its report section come from its declaration.

Stage modules are imported lazily: :func:`stage_named` imports only that stage's module, so a command fails on a
bad input before the other stages' heavy dependencies (torch, open3d, pycolmap...) are loaded; :func:`registered_stages`
(and ``STAGES``) import every stage.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from core.lazy import lazy_exports

if TYPE_CHECKING:
    from hybridsplat.stages.base import Stage

#: stage name → "module:Class", in pipeline order
_REGISTRY: dict[str, str] = {}
_instances: dict[str, Stage] = {}


def register_stage(name: str, target: str, after: str | None = None) -> None:
    """Add stage ``name``, the class ``target`` (``"package.module:Class"``), at the end of the pipeline or right
    after stage ``after``. Registering a name again replaces it in place."""
    global _REGISTRY
    _instances.pop(name, None)
    entries = [(n, t) for n, t in _REGISTRY.items() if n != name]
    if name in _REGISTRY and after is None:
        entries = [(n, target if n == name else t) for n, t in _REGISTRY.items()]
    elif after is not None:
        if after not in _REGISTRY:
            raise KeyError(after)
        at = [n for n, _ in entries].index(after) + 1
        entries.insert(at, (name, target))
    else:
        entries.append((name, target))
    _REGISTRY = dict(entries)


def unregister_stage(name: str) -> None:
    """Remove stage ``name`` from the pipeline (tests that register a toy stage undo it)."""
    _REGISTRY.pop(name)
    _instances.pop(name, None)


register_stage("sfm", "hybridsplat.stages.sfm:SfmStage")
register_stage("control", "hybridsplat.stages.control:ControlStage")
register_stage("tiles", "hybridsplat.stages.tiles:TilesStage")
register_stage("mvs", "hybridsplat.stages.mvs:MvsStage")
register_stage("classify", "hybridsplat.stages.classify:ClassifyStage")
register_stage("masks", "hybridsplat.stages.masks:MasksStage")
register_stage("convert", "hybridsplat.stages.convert:ConvertStage")
register_stage("train", "hybridsplat.stages.train:TrainStage")
register_stage("clean", "hybridsplat.stages.clean:CleanStage")
register_stage("background", "hybridsplat.stages.background:BackgroundStage")
register_stage("appearance", "hybridsplat.stages.appearance:AppearanceStage")
register_stage("merge", "hybridsplat.stages.merge:MergeStage")
register_stage("mesh", "hybridsplat.stages.mesh:MeshStage")
register_stage("baseline", "hybridsplat.stages.baseline:BaselineStage")
register_stage("eval", "hybridsplat.stages.evaluate:EvalStage")
register_stage("report", "hybridsplat.stages.report:ReportStage")


def stage_names() -> tuple[str, ...]:
    """The registered stages' names, in pipeline order (imports nothing)."""
    return tuple(_REGISTRY)


def stage_named(name: str) -> Stage:
    """The one instance of stage ``name``; imports only that stage's module. :class:`KeyError` for an unknown name."""
    if name not in _instances:
        module, _, cls = _REGISTRY[name].partition(":")
        _instances[name] = getattr(importlib.import_module(module), cls)()
    return _instances[name]


def registered_stages() -> tuple[Stage, ...]:
    """Every registered stage, in pipeline order."""
    return tuple(stage_named(name) for name in _REGISTRY)


def stage_options_types() -> dict[str, type]:
    """Stage name → its ``Options`` type, for every registered stage (what config.toml's tables hold)."""
    return {stage.name: stage.Options for stage in registered_stages()}


_getattr, __dir__ = lazy_exports(__name__, {"Stage": "base", "StageContext": "base", "StageResult": "base"})


def __getattr__(attr: str) -> Any:
    if attr == "STAGES":  # recomputed on each access: a stage registered later is part of it
        return registered_stages()
    return _getattr(attr)


__all__ = [
    "STAGES",
    "Stage",
    "StageContext",
    "StageResult",
    "register_stage",
    "registered_stages",
    "stage_named",
    "stage_names",
    "stage_options_types",
    "unregister_stage",
]
