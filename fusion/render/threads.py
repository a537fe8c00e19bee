"""Both cores for GIL-free numba kernels: a shared pool of blocking Python threads.

Python threads on ``nogil`` kernels instead of numba's ``prange``: waiting threads block instead of spinning, which
keeps the kernels fast when the cores are shared with other work (OpenMP spin-waits made the renderer 3-5x slower).
The thread count is ``numba.get_num_threads()`` (so ``numba.set_num_threads`` governs every kernel here).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numba

_POOL: list[ThreadPoolExecutor] = []
_TIMES: dict[str, list[float]] = {}
_RECORDING: list[bool] = [False]


def record_times(enabled: bool) -> None:
    """Start (and clear) or stop accumulating wall and process-CPU seconds per named kernel (for bench scripts)."""
    _RECORDING[0] = enabled
    _TIMES.clear()


def kernel_times() -> dict[str, tuple[float, float]]:
    """Accumulated (wall s, process CPU s) per kernel name since :func:`record_times`; clears them."""
    out = {k: (v[0], v[1]) for k, v in _TIMES.items()}
    _TIMES.clear()
    return out


@contextmanager
def timed(name: str) -> Iterator[None]:
    """Adds the block's wall and process-CPU time to ``name`` while recording (a no-op otherwise)."""
    if not _RECORDING[0]:
        yield
        return
    w0, c0 = time.perf_counter(), time.process_time()
    try:
        yield
    finally:
        acc = _TIMES.setdefault(name, [0.0, 0.0])
        acc[0] += time.perf_counter() - w0
        acc[1] += time.process_time() - c0


def n_threads() -> int:
    """The number of threads kernels are split over (``numba.get_num_threads()``)."""
    return int(numba.get_num_threads())


def _pool(n: int) -> ThreadPoolExecutor:
    if not _POOL or _POOL[0]._max_workers < n:
        _POOL[:] = [ThreadPoolExecutor(max_workers=n, thread_name_prefix="splat")]
    return _POOL[0]


def run_threads(kernel: Callable[..., object], args: tuple, tail: tuple = (), name: str = "") -> None:
    """Run ``kernel(*args, th, n, *tail)`` for th in 0..n-1 on n threads and wait for all of them.

    The kernel must split its work by ``th`` / ``n`` so that threads never write the same memory. ``name``: the
    label its time is recorded under (see :func:`record_times`).
    """
    with timed(name or "other"):
        _run_threads(kernel, args, tail)


def _run_threads(kernel: Callable[..., object], args: tuple, tail: tuple) -> None:
    n = n_threads()
    if n == 1:
        kernel(*args, 0, 1, *tail)
        return
    futures = [_pool(n).submit(kernel, *args, th, n, *tail) for th in range(n)]
    for future in futures:
        future.result()


def run_calls(work: Callable[[int, int], object], name: str = "") -> None:
    """Run ``work(th, n)`` for th in 0..n-1 on n threads (a Python function that calls GIL-free kernels)."""
    with timed(name or "other"):
        _run_calls(work)


def _run_calls(work: Callable[[int, int], object]) -> None:
    n = n_threads()
    if n == 1:
        work(0, 1)
        return
    futures = [_pool(n).submit(work, th, n) for th in range(n)]
    for future in futures:
        future.result()


def run_chunks(kernel: Callable[..., object], args: tuple, tail: tuple, n_items: int, name: str = "") -> None:
    """Run ``kernel(*args, j0, j1, *tail)`` over [0, n_items) in chunks handed out on demand to n threads.

    Dynamic rather than static shares: on a shared machine a thread the OS deschedules no longer holds back the
    others (they take its chunks). The kernel must make the result independent of which thread runs a chunk
    (each item writes only its own outputs), so results do not depend on the thread count or the schedule.
    Chunks are ~1/8 of an even share (at least 1 item): ~20 µs of dispatch each.
    """
    n = n_threads()
    if n == 1 or n_items <= 1:
        with timed(name or "other"):
            kernel(*args, 0, n_items, *tail)
        return
    size = max(1, n_items // (8 * n))
    counter = itertools.count()  # next() is atomic under the GIL

    def work(_th: int, _n: int) -> None:
        while (start := next(counter) * size) < n_items:
            kernel(*args, start, min(n_items, start + size), *tail)

    run_calls(work, name)


def chunk(total: int, th: int, n: int) -> tuple[int, int]:
    """The [start, stop) share of thread ``th`` of ``n`` over ``total`` items (contiguous, balanced)."""
    return total * th // n, total * (th + 1) // n
