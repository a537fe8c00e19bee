"""hybridsplat.tile_execution.task_resources: what a tile's Ray task declares, against hand-worked cases (the Ray
runs themselves are in tests/test_tiled_run.py, slow)."""

from hybridsplat.config import InputOptions, ProjectConfig
from hybridsplat.tile_execution import ExecutionOptions, task_resources
from hybridsplat.tile_projects import TileJob

MB = 2**20


def _job(memory_mb: float) -> TileJob:
    return TileJob("r0c0", "/p/tiles/r0c0", ProjectConfig(input=InputOptions(path="/p/photos")), memory_mb=memory_mb)


def test_cpus_retries_and_the_predicted_memory_are_declared():
    cluster = {"CPU": 4.0, "memory": 8000.0 * MB}
    got = task_resources(_job(1400.0), ExecutionOptions(workers=4, cpus_per_tile=2), cluster)
    assert got == {"num_cpus": 2, "max_retries": 2, "memory": 1400 * MB}
    # no prediction and no fixed claim: no memory declared; a fixed claim wins over the prediction
    assert "memory" not in task_resources(_job(0.0), ExecutionOptions(workers=2), cluster)
    fixed = task_resources(_job(1400.0), ExecutionOptions(workers=2, memory_mb_per_tile=3000), cluster)
    assert fixed["memory"] == 3000 * MB


def test_a_claim_larger_than_a_node_is_cut_to_what_the_node_can_schedule():
    got = task_resources(_job(10_000.0), ExecutionOptions(workers=2), {"CPU": 2.0, "memory": 4000.0 * MB})
    assert got["memory"] == int(0.9 * 4000 * MB)


def test_gpus_are_shared_among_the_tiles_running_at_once():
    options = ExecutionOptions(workers=4, cpus_per_tile=1)
    assert "num_gpus" not in task_resources(_job(0.0), options, {"CPU": 4.0})
    assert task_resources(_job(0.0), options, {"CPU": 4.0, "GPU": 1.0})["num_gpus"] == 0.25
    assert task_resources(_job(0.0), options, {"CPU": 4.0, "GPU": 8.0})["num_gpus"] == 1.0
