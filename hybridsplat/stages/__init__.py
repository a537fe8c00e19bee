"""The pipeline's stages, in order. Adding a stage = one module here + one entry in ``STAGES`` (+ its test)."""

from __future__ import annotations

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

STAGES: tuple[Stage, ...] = (
    SfmStage(),
    MvsStage(),
    ClassifyStage(),
    MasksStage(),
    ConvertStage(),
    TrainStage(),
    CleanStage(),
    MergeStage(),
    MeshStage(),
    BaselineStage(),
    EvalStage(),
    ReportStage(),
)

__all__ = ["STAGES", "Stage", "StageContext", "stage_named"]


def stage_named(name: str) -> Stage:
    for stage in STAGES:
        if stage.name == name:
            return stage
    raise KeyError(name)
