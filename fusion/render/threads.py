"""Both cores for GIL-free numba kernels: a shared pool of blocking Python threads.

Python threads on ``nogil`` kernels instead of numba's ``prange``: waiting threads block instead of spinning, which
keeps the kernels fast when the cores are shared with other work (OpenMP spin-waits made the renderer 3-5x slower).
The thread count is ``numba.get_num_threads()`` (so ``numba.set_num_threads`` governs every kernel here).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numba

_POOL: list[ThreadPoolExecutor] = []


def n_threads() -> int:
    """The number of threads kernels are split over (``numba.get_num_threads()``)."""
    return int(numba.get_num_threads())


def _pool(n: int) -> ThreadPoolExecutor:
    if not _POOL or _POOL[0]._max_workers < n:
        _POOL[:] = [ThreadPoolExecutor(max_workers=n, thread_name_prefix="splat")]
    return _POOL[0]


def run_threads(kernel: Callable[..., object], args: tuple, tail: tuple = ()) -> None:
    """Run ``kernel(*args, th, n, *tail)`` for th in 0..n-1 on n threads and wait for all of them.

    The kernel must split its work by ``th`` / ``n`` so that threads never write the same memory.
    """
    n = n_threads()
    if n == 1:
        kernel(*args, 0, 1, *tail)
        return
    futures = [_pool(n).submit(kernel, *args, th, n, *tail) for th in range(n)]
    for future in futures:
        future.result()


def run_calls(work: Callable[[int, int], object]) -> None:
    """Run ``work(th, n)`` for th in 0..n-1 on n threads (a Python function that calls GIL-free kernels)."""
    n = n_threads()
    if n == 1:
        work(0, 1)
        return
    futures = [_pool(n).submit(work, th, n) for th in range(n)]
    for future in futures:
        future.result()


def chunk(total: int, th: int, n: int) -> tuple[int, int]:
    """The [start, stop) share of thread ``th`` of ``n`` over ``total`` items (contiguous, balanced)."""
    return total * th // n, total * (th + 1) // n
