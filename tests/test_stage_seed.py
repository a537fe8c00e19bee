"""A stage whose outputs depend on the project's seed reruns when the seed changes (``run --seed 1`` on a project
run with seed 0 used to call every stage up to date and keep the seed-0 splats); a stage the seed does not touch
stays up to date."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

from hybridsplat.config import ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.runner import stage_config
from hybridsplat.stages import StageContext, registered_stages

SEEDED = {"sfm", "train", "background", "appearance", "baseline", "tiles"}  # they use ctx.config.seed


def _ctx(tmp_path: Path, seed: int) -> StageContext:
    config = replace(ProjectConfig(), seed=seed)
    return StageContext(layout=ProjectLayout(tmp_path), config=config, source=SimpleNamespace(holdout_names=()))


def test_the_seed_is_part_of_exactly_the_seeded_stages_record(tmp_path: Path):
    stages = {stage.name: stage for stage in registered_stages()}
    assert SEEDED <= stages.keys()
    for name in SEEDED | {"mvs", "classify", "masks", "convert", "clean", "merge"}:
        stage = stages[name]
        before, after = stage_config(stage, _ctx(tmp_path, 0)), stage_config(stage, _ctx(tmp_path, 1))
        assert (before != after) == (name in SEEDED), name
        assert before["options"] == after["options"], name  # the seed is not an option of the stage


def test_the_seeded_stages_read_the_seed(tmp_path: Path):
    import inspect

    for stage in registered_stages():
        reads_seed = "ctx.config.seed" in inspect.getsource(type(stage).run)
        if stage.name != "tiles":  # the tile stage passes the seed on in its sub-projects' config
            assert reads_seed == stage.uses_seed, stage.name
