"""Passes over the samples in chunks, split between threads, never oversubscribing the cores.

numpy releases the GIL inside BLAS and its element-wise loops, and the chunk work here is too
small for BLAS to spread over the cores by itself; so each thread takes one contiguous share of
the chunks, and BLAS is held to one thread for the whole pass (threadpoolctl, a dependency of
nlpcal). Without that hold every BLAS call may start threads of its own beside the pass's, and
on a busy machine (OpenBLAS threads wait by spinning) they fight for the cores.

The pass uses the cores available to the process (its CPU affinity and the CPU quota of its
cgroup), or the number set with `threads`; `available_memory` tells the memory the process may
still take, within its cgroup's limit (for a Dask log kept in memory,
`nlpcal.cluster.memory_to_keep`). The shares are fixed by N and the thread count, not by
timing, so results are reproducible for a given thread count.
"""

from __future__ import annotations

import contextlib
import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from contextvars import ContextVar
from functools import lru_cache

from threadpoolctl import ThreadpoolController


def available_cores() -> int:
    """The cores this process may use: its CPU affinity, within its cgroup's CPU quota."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    quota = _cgroup_quota()
    return max(1, min(cores, quota) if quota else cores)


def _cgroup_quota() -> int | None:
    """ceil(quota / period) of the cgroup's CPU limit (v2 cpu.max or v1 cfs), or None."""
    candidates = (
        ("/sys/fs/cgroup/cpu.max", None),
        ("/sys/fs/cgroup/cpu/cpu.cfs_quota_us", "/sys/fs/cgroup/cpu/cpu.cfs_period_us"),
    )
    for fields in _cgroup_fields(candidates):
        if len(fields) >= 2 and fields[0] not in ("max", "-1"):
            try:
                return max(1, math.ceil(int(fields[0]) / int(fields[1])))
            except (ValueError, ZeroDivisionError):
                return None
    return None


def _cgroup_fields(candidates):
    """The fields of each of a cgroup's (file, second file or None) that can be read, in turn:
    the first file's, then the second's (v2, then v1)."""
    for path, second in candidates:
        try:
            with open(path) as handle:
                fields = handle.read().split()
            if second:
                with open(second) as handle:
                    fields.append(handle.read().strip())
        except OSError:
            continue
        yield fields


def available_memory() -> float | None:
    """The memory new data may take in this process: what the machine has available (psutil's,
    else Linux's MemAvailable), held to what is left below the limit of its container (a Linux
    cgroup's memory.max, v2, or limit_in_bytes, v1); None where the machine does not tell, or
    the process's address space is limited (`ulimit -v`: its size is not its data). [byte]"""
    try:
        import resource
    except ImportError:  # Windows
        pass
    else:
        if resource.getrlimit(resource.RLIMIT_AS)[0] != resource.RLIM_INFINITY:
            return None
    try:
        import psutil
    except ImportError:
        available = _meminfo_available()
    else:
        available = float(psutil.virtual_memory().available)
    if available is None:
        return None
    room = _cgroup_memory_room()
    return available if room is None else min(available, room)


def _meminfo_available() -> float | None:
    """Linux's MemAvailable, or None. [byte]"""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0  # given in kB
    except (OSError, ValueError, IndexError):
        pass
    return None


def _cgroup_memory_room() -> float | None:
    """What this process's cgroup may still take below its memory limit (v2 memory.max, or v1
    limit_in_bytes, less the usage), or None without a limit. [byte]"""
    candidates = (
        ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
        (
            "/sys/fs/cgroup/memory/memory.limit_in_bytes",
            "/sys/fs/cgroup/memory/memory.usage_in_bytes",
        ),
    )
    for fields in _cgroup_fields(candidates):
        if len(fields) != 2 or not fields[1].isdigit():
            continue
        limit, used = fields
        if not limit.isdigit() or int(limit) >= 2**60:  # "max", or v1's huge number: no limit
            return None
        return max(0.0, float(limit) - float(used))
    return None


#: Threads per pass when none are set: the cores available to the process when it started.
WORKERS = available_cores()
#: Threads per pass set for the call running in this thread (None: WORKERS).
_threads: ContextVar[int | None] = ContextVar("nlpcal_pass_threads", default=None)


@contextlib.contextmanager
def call_threads(threads: int | None = None):
    """The passes inside the block use `threads` threads (None: the available cores; a count the
    caller has checked, `validation.optional_whole`: this layer sits below validation), and BLAS
    stays at one thread for the whole block, not only inside the passes: the small products
    between them gain nothing from BLAS threads, and OpenBLAS threads woken by one of them keep
    spinning into the next pass, taking a core from it. More threads than cores oversubscribe
    them: that is the caller's choice."""
    token = _threads.set(threads)
    try:
        with single_blas():
            yield
    finally:
        _threads.reset(token)


def thread_count() -> int:
    """The threads a pass uses now."""
    return _threads.get() or WORKERS


@lru_cache(maxsize=1)
def _blas_controller() -> ThreadpoolController:
    return ThreadpoolController()


def shares(n: int, chunk_rows: int, workers: int):
    """Contiguous (start, stop) ranges, aligned to chunks, one per worker that has work."""
    chunks = -(-n // chunk_rows)
    workers = max(1, min(workers, chunks))
    bounds = [min(n, round(k * chunks / workers) * chunk_rows) for k in range(workers + 1)]
    return [(a, b) for a, b in zip(bounds, bounds[1:]) if b > a]


_hold = threading.Lock()
_holders = 0
_limiter = None


@contextlib.contextmanager
def single_blas():
    """BLAS at one thread inside the block. threadpoolctl's limits hold for the whole process, so
    of blocks that overlap (in any threads) the first sets the limit and the last restores what
    was there before the first."""
    global _holders, _limiter
    with _hold:
        if _holders == 0:
            _limiter = _blas_controller().limit(limits=1, user_api="blas")
        _holders += 1
    try:
        yield
    finally:
        with _hold:
            _holders -= 1
            if _holders == 0 and _limiter is not None:
                _limiter.restore_original_limits()
                _limiter = None


def map_shares(work, n: int, chunk_rows: int, workers: int | None = None) -> list:
    """work(start, stop) for every share, in threads (the calling thread takes the first share),
    BLAS held to one thread meanwhile; the results in order of the shares."""
    ranges = shares(n, chunk_rows, workers or thread_count()) or [(0, n)]
    with single_blas():
        if len(ranges) == 1:
            return [work(*ranges[0])]
        with ThreadPoolExecutor(max_workers=len(ranges) - 1) as pool:
            others = [pool.submit(work, *r) for r in ranges[1:]]
            return [work(*ranges[0])] + [future.result() for future in others]
