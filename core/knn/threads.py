"""Numba kernels released from the GIL, run on a pool of Python threads over interleaved work ranges.

Waiting threads block instead of spinning, which matters on shared cores (the pattern of ``fusion/render/cpu.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

CHUNKS_PER_THREAD = 16
"""Interleaved work chunks per thread (balances uneven columns without a scheduler)."""


_POOL: list[ThreadPoolExecutor] = []


def run_threads(kernel: Callable[..., None], args: tuple, n: int) -> None:
    """Run ``kernel(*args, th, n)`` for th in 0..n-1 on n Python threads (GIL-free kernels; blocking, not spinning,
    when the cores are shared: the pattern of ``fusion/render/cpu.py``)."""
    if n <= 1:
        kernel(*args, 0, 1)
        return
    if not _POOL or _POOL[0]._max_workers < n:
        _POOL[:] = [ThreadPoolExecutor(max_workers=n, thread_name_prefix="knn")]
    for future in [_POOL[0].submit(kernel, *args, th, n) for th in range(n)]:
        future.result()
