"""Passes over the samples in chunks, split between threads.

numpy releases the GIL inside BLAS and its element-wise loops, and the chunk work here is too
small for BLAS to spread over the cores by itself; so each core takes one contiguous share of the
chunks, with BLAS held to one thread meanwhile (through threadpoolctl, the `fast` extra; without
it the pass runs in one thread, as BLAS threads and pass threads would fight for the cores). The
shares are fixed by N and the worker count, not by timing, so results are reproducible.
"""

from __future__ import annotations

import contextlib
import os
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache

#: Threads per pass: the cores of this machine, at most four.
WORKERS = max(1, min(4, os.cpu_count() or 1))


@lru_cache(maxsize=1)
def _blas_controller():
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:
        return None
    return ThreadpoolController()


def parallel_available() -> bool:
    """Whether passes can run in several threads (threadpoolctl installed, several cores)."""
    return WORKERS > 1 and _blas_controller() is not None


def shares(n: int, chunk_rows: int, workers: int = WORKERS):
    """Contiguous (start, stop) ranges, aligned to chunks, one per worker that has work."""
    chunks = -(-n // chunk_rows)
    workers = max(1, min(workers, chunks))
    bounds = [min(n, round(k * chunks / workers) * chunk_rows) for k in range(workers + 1)]
    return [(a, b) for a, b in zip(bounds, bounds[1:]) if b > a]


def map_shares(work, n: int, chunk_rows: int, workers: int | None = None) -> list:
    """work(start, stop) for every share, in threads; the results in order of the shares."""
    if workers is None:
        workers = WORKERS if parallel_available() else 1
    ranges = shares(n, chunk_rows, workers) or [(0, n)]
    if len(ranges) == 1:
        return [work(*ranges[0])]
    controller = _blas_controller()
    limit = (
        controller.limit(limits=1, user_api="blas")
        if controller is not None
        else contextlib.nullcontext()
    )
    with limit, ThreadPoolExecutor(max_workers=len(ranges)) as pool:
        return list(pool.map(lambda r: work(*r), ranges))
