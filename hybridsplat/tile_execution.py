"""Running the tiles of a tiled run: one after another in this process, or as Ray tasks (issue 34).

``workers`` ≤ 1 and no ``ray_address``: the tiles run here, in plan order (Ray is not needed). Otherwise each tile is
a Ray task (:func:`hybridsplat.tile_projects.run_tile`) declaring ``cpus_per_tile`` CPUs (its stages' threads: Ray
sets ``OMP_NUM_THREADS`` to it, and ``NUMBA_NUM_THREADS`` is set alike) and, when known, the memory it needs; a task
whose worker dies is retried (``max_retries``), and since a tile's stages are recorded in its own manifest a retry
resumes after the last stage that finished. ``workers = N`` starts a local Ray instance of N CPUs (N tiles at a time
with one CPU each); ``ray_address`` joins a running cluster instead (``ray start --head`` on one machine, ``ray
start --address ...`` on the others; the project folder must be at the same path on every node, e.g. a shared file
system). Inputs and outputs are files in the project folder; the object store carries only each tile's job (paths
and options) and its small record.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from core.errors import ConfigError
from hybridsplat.tile_projects import run_tile

TileDone = Callable[[str, int, int], None]
"""Called as each tile finishes: (tile name, tiles done, tiles in all)."""

TileTask = Callable[[Any], Any]
"""What runs one tile's job (a module-level function, which Ray pickles by reference): :func:`run_tile` for the tile
stages, :func:`hybridsplat.tile_appearance.run_tile_appearance` for the appearance stage's parts. A job has ``name``
and ``memory_mb`` (the MB its task declares; 0: unknown); the task returns the tile's record, a frozen dataclass with
a ``resources`` field (what Ray gave it)."""


@dataclass(frozen=True)
class ExecutionOptions:
    """How tiles run: ``workers`` tiles at a time on a local Ray instance (≤ 1: here, one by one, no Ray), or on the
    Ray cluster at ``ray_address``; ``cpus_per_tile`` CPUs declared per task; ``memory_mb_per_tile`` the memory
    declared per task (0: each job's ``memory_mb``, e.g. a tile's predicted peak); ``max_retries`` of a task whose
    worker died."""

    workers: int = 1
    ray_address: str = ""
    cpus_per_tile: int = 1
    memory_mb_per_tile: int = 0
    max_retries: int = 2

    def __post_init__(self) -> None:
        if self.workers < 0 or self.cpus_per_tile < 1 or self.max_retries < 0 or self.memory_mb_per_tile < 0:
            raise ConfigError(
                "workers ≥ 0, cpus_per_tile ≥ 1, memory_mb_per_tile ≥ 0 and max_retries ≥ 0 are needed, got "
                f"{self.workers}, {self.cpus_per_tile}, {self.memory_mb_per_tile}, {self.max_retries}"
            )

    @classmethod
    def of(cls, tiles: Any) -> ExecutionOptions:
        """How the tiles of a project run: its ``[tiles]`` options' ``workers``, ``ray_address`` and
        ``cpus_per_tile`` (:class:`hybridsplat.stages.tiles.TilesOptions`)."""
        return cls(workers=tiles.workers, ray_address=tiles.ray_address, cpus_per_tile=tiles.cpus_per_tile)

    @property
    def uses_ray(self) -> bool:
        return bool(self.ray_address) or self.workers > 1


def run_tiles(
    jobs: Sequence[Any], options: ExecutionOptions, on_done: TileDone | None = None, task: TileTask = run_tile
) -> list[Any]:
    """Run ``task`` on every job (:class:`TileJob` for :func:`run_tile`); the tiles' records in the order of
    ``jobs``."""
    if not options.uses_ray:
        results = []
        for k, job in enumerate(jobs):
            results.append(task(job))
            if on_done is not None:
                on_done(job.name, k + 1, len(jobs))
        return results
    return _run_on_ray(jobs, options, on_done, task)


def import_ray() -> Any:
    """The ray module, or a :class:`ConfigError` saying how to install it."""
    try:
        import ray
    except ImportError as err:
        raise ConfigError(
            "tiles on several workers need Ray: pip install 'hybridsplat[distributed]' (or run with --workers 1)"
        ) from err
    return ray


def _result(ray: Any, ref: Any, tile: str) -> Any:
    """A finished task's record; a task that failed raises its own error (a readable one-liner for the CLI, with
    the tile named in a note), not Ray's wrapper with the remote traceback."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as err:
        cause = getattr(err, "cause", None)
        if isinstance(cause, Exception):
            cause.add_note(f"in tile {tile} (a Ray task)")
            raise cause from None
        raise


@contextmanager
def execution_session(options: ExecutionOptions) -> Iterator[int]:
    """Ray started (or joined) once for several :func:`run_tiles` calls, shut down after; nothing without Ray.
    Gives how many tiles run at once: 1 without Ray, ``workers`` on a local instance, and on a cluster
    (``ray_address``) its CPUs over ``cpus_per_tile`` (at least 1)."""
    if not options.uses_ray:
        yield 1
        return
    ray = import_ray()
    started_here = _start_ray(ray, options)
    try:
        slots = options.workers
        if options.ray_address:
            slots = max(1, int(ray.cluster_resources().get("CPU", 1) // options.cpus_per_tile))
        yield slots
    finally:
        if started_here:
            ray.shutdown()


def _start_ray(ray: Any, options: ExecutionOptions) -> bool:
    """Start or join Ray unless this process already did; whether it did now."""
    if ray.is_initialized():
        return False
    threads = str(options.cpus_per_tile)
    env = {"env_vars": {"NUMBA_NUM_THREADS": threads, "OMP_NUM_THREADS": threads}}
    if options.ray_address:
        ray.init(address=options.ray_address, runtime_env=env, log_to_driver=False)
    else:
        # address="local": a new instance of our own, even where another Ray cluster runs on this machine
        ray.init(address="local", num_cpus=options.workers, include_dashboard=False, log_to_driver=False,
                 runtime_env=env)  # fmt: skip
    return True


def task_resources(job: Any, options: ExecutionOptions, cluster: dict[str, float]) -> dict[str, Any]:
    """What a tile's Ray task declares: ``cpus_per_tile`` CPUs; memory (bytes) ``memory_mb_per_tile`` or else the
    job's predicted peak, at most 90 % of ``cluster["memory"]`` (the largest node's: a larger claim would never be
    scheduled); on a cluster with GPUs an equal share of them per tile running at once, at most one (the tile's
    torch stages use it)."""
    resources: dict[str, Any] = {"num_cpus": options.cpus_per_tile, "max_retries": options.max_retries}
    memory_mb = options.memory_mb_per_tile or job.memory_mb
    if memory_mb > 0:
        limit = 0.9 * cluster.get("memory", float("inf"))
        resources["memory"] = int(min(memory_mb * 2**20, limit))
    gpus = cluster.get("GPU", 0.0)
    if gpus > 0:
        at_once = max(1, int(cluster.get("CPU", 1) // options.cpus_per_tile))
        resources["num_gpus"] = min(1.0, gpus / at_once)
    return resources


def run_tile_task(job: Any, task: TileTask = run_tile) -> Any:
    """``task`` (:func:`run_tile`) as a Ray task: its record with the resources Ray assigned to the task."""
    from dataclasses import replace

    import ray

    return replace(task(job), resources=dict(ray.get_runtime_context().get_assigned_resources()))


def _run_on_ray(jobs: Sequence[Any], options: ExecutionOptions, on_done: TileDone | None, task: TileTask) -> list[Any]:
    ray = import_ray()
    started_here = _start_ray(ray, options)
    try:
        cluster = dict(ray.cluster_resources())
        # a task's memory must fit on one node: the largest node's, not the cluster's sum
        cluster["memory"] = max((n["Resources"].get("memory", 0.0) for n in ray.nodes() if n.get("Alive")),
                                default=cluster.get("memory", 0.0))  # fmt: skip
        remote = ray.remote(run_tile_task)
        pending = {remote.options(**task_resources(job, options, cluster)).remote(job, task): k
                   for k, job in enumerate(jobs)}  # fmt: skip
        results: list[Any] = [None] * len(jobs)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            k = pending.pop(ready[0])
            results[k] = _result(ray, ready[0], jobs[k].name)
            if on_done is not None:
                on_done(jobs[k].name, len(jobs) - len(pending), len(jobs))
        return [r for r in results if r is not None]
    finally:
        if started_here:
            ray.shutdown()
