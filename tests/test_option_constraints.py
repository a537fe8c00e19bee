"""The options classes converted to declared constraints (core.constraints) keep what they accepted and refused.

Each row is a value on one side of a bound that the hand-written check before the conversion drew (the tables are
the old checks' truth, written out by hand): a refused value must raise the one message naming that option, an
accepted one must build. Rules across fields stay hand-written and are tested with their classes."""

from __future__ import annotations

import math
import re

import pytest

from classify.features.geometric import GeometricOptions
from classify.mask_options import ExplainedBy, HoleArea, MaskOptions
from classify.model import ForestOptions
from classify.options import ClassifyOptions
from classify.stream import ClassifyStreamOptions
from core.constraints import Constrained, ConstraintError

NAN, INF = math.nan, math.inf

#: (class, required keyword arguments) of the classes below that have fields without defaults
REQUIRED: dict[type, dict] = {ClassifyStreamOptions: {"memory_limit_mb": 1024.0}}

REFUSED = [
    (MaskOptions, "footprint", [0.0, -1.0, NAN]),
    (MaskOptions, "max_radius_px", [0, -3]),
    (MaskOptions, "close_px", [-1]),
    (MaskOptions, "dilate_px", [-1]),
    (MaskOptions, "hole_gsd", [-0.5, NAN, INF]),
    (MaskOptions, "grow_area", [-1]),
    (MaskOptions, "grow_max_px", [15, 0]),
    (MaskOptions, "dilate_spacings", [-1.0, NAN, INF]),
    (MaskOptions, "train_margin_spacings", [-1e-9, NAN, INF]),
    (MaskOptions, "hole_area", ["region", "", None]),
    (MaskOptions, "explained_by", ["some"]),
    (GeometricOptions, "search", ["octree"]),
    (GeometricOptions, "backend", ["torch"]),
    (GeometricOptions, "k", [2, 0]),
    (GeometricOptions, "voxel_factors", [(), (1.0, 0.0), (1.0, NAN), (INF,), (-1.0,)]),
    (GeometricOptions, "chunk_size", [0, -5]),
    (ForestOptions, "smooth_passes", [-1]),
    (ForestOptions, "folds", [1, 0]),
    (ForestOptions, "n_estimators", [0]),
    (ForestOptions, "min_samples_leaf", [0]),
    (ForestOptions, "max_samples_per_class", [0]),
    (ForestOptions, "class_weight", ["none", "uniform"]),
    (ClassifyOptions, "threshold", [0.0, 1.0, -0.1, 1.5, NAN]),
    (ClassifyStreamOptions, "points_per_cell", [0, -1, 2.5]),
    (ClassifyStreamOptions, "chunk_size", [0]),
]

ACCEPTED = [
    (MaskOptions, "footprint", [1e-6, 100.0]),
    (MaskOptions, "max_radius_px", [1]),
    (MaskOptions, "close_px", [0]),
    (MaskOptions, "hole_gsd", [0.0, 3.0]),
    (MaskOptions, "grow_area", [0]),
    (MaskOptions, "grow_max_px", [16]),
    (MaskOptions, "dilate_spacings", [0.0]),
    (MaskOptions, "train_margin_spacings", [0.0, 5]),
    (MaskOptions, "hole_area", ["hull", HoleArea.ENCLOSED]),
    (MaskOptions, "explained_by", ["all", ExplainedBy.SEEN]),
    (GeometricOptions, "search", ["kdtree"]),
    (GeometricOptions, "backend", ["numpy", "pgeof"]),
    (GeometricOptions, "k", [3]),
    (GeometricOptions, "voxel_factors", [(0.5,), (1.0, 4.0)]),
    (GeometricOptions, "chunk_size", [1]),
    (ForestOptions, "smooth_passes", [0]),
    (ForestOptions, "folds", [2]),
    (ForestOptions, "class_weight", [None, "balanced", "balanced_subsample"]),
    (ClassifyOptions, "threshold", [None, 1e-9, 0.5, 0.999]),
    (ClassifyStreamOptions, "points_per_cell", [None, 1]),
]


def _build(cls: type, name: str, value: object) -> object:
    return cls(**{**REQUIRED.get(cls, {}), name: value})


@pytest.mark.parametrize(("cls", "name", "values"), REFUSED, ids=lambda x: getattr(x, "__name__", None))
def test_refused_with_the_one_message(cls: type, name: str, values: list) -> None:
    for value in values:
        with pytest.raises(ConstraintError, match=rf"^option {re.escape(name)} must be .+, got ") as info:
            _build(cls, name, value)
        assert info.value.option == name


@pytest.mark.parametrize(("cls", "name", "values"), ACCEPTED, ids=lambda x: getattr(x, "__name__", None))
def test_accepted(cls: type, name: str, values: list) -> None:
    for value in values:
        built = _build(cls, name, value)
        stored = getattr(built, name)
        assert stored == value or (hasattr(stored, "value") and stored.value == value) or stored == tuple(value)


def test_every_declaration_names_a_field_and_defaults_satisfy_it() -> None:
    classes = {cls for cls, _, _ in REFUSED + ACCEPTED}
    for cls in classes:
        assert issubclass(cls, Constrained)
        default = cls(**REQUIRED.get(cls, {}))
        for name, constraint in cls.constraints.items():
            assert constraint.accepts(getattr(default, name)), (cls.__name__, name)
