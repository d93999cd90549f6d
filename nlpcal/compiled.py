"""The data pass's compiled kernel: `nlpcal.monomials.MomentSet.add` as one numba function.

The numpy kernel builds the rows of monomials with element-wise products and sums them with
matrix products (BLAS), a dozen short calls per 4 096 samples; two threads running it side by
side spend much of their time waiting for each other's Python (the GIL): on 2 cores, 10^6
samples take 100 ms on two threads against 74 ms on one. The compiled kernel
(`nlpcal._moment_kernel`) does the same work in one call per chunk that releases the GIL: 32 ms
on one thread, 17 ms on two (`benchmarks/bench_calibrate.py --pass-costs`).

It needs numba (the `fast` extra), which costs time to load: importing it and reading the
compiled kernel from numba's cache take 0.3-0.45 s in a new process (compiling it, the first
time after an install, 2-3 s). A pass therefore uses it (`use`) when it is long enough to repay
the load, COMPILED_FROM samples, unless the environment variable NLPCAL_KERNEL says otherwise:
"numpy" never, "numba" always (for a process that runs many passes: a notebook, a service, a
batch of logs, where the load is paid once). Both kernels compute the same sums to rounding:
the compiled one adds the samples of a chunk in another order (~1e-16 of a moment,
`tests/test_compiled.py`).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable

import numpy as np

from .errors import InputError

#: The environment variable that chooses the kernel: "auto" (unset), "numpy" or "numba".
KERNEL_VARIABLE = "NLPCAL_KERNEL"
KERNELS = ("auto", "numpy", "numba")
#: The samples of one pass from which, in "auto", the compiled kernel is loaded: it saves
#: 60-110 ns per sample on 2 cores against a load of 0.3-0.45 s. [samples]
COMPILED_FROM = 5_000_000
#: Samples per step of the compiled kernel: its rows of monomials (70 for the nine-parameter
#: objective, 560 kB) stay in a core's L2 cache between their building and their sums; 512
#: to 2 048 cost the same within 10 % (4 096: +30 %). [samples]
STEP = 1024

_lock = threading.Lock()
_loaded: list = []  # the kernel (None without numba), once looked for in this process


def choice() -> str:
    """NLPCAL_KERNEL, checked: one of KERNELS. Raises InputError otherwise, or when it asks
    for numba and numba is not installed."""
    kernel = os.environ.get(KERNEL_VARIABLE, "auto").strip().lower() or "auto"
    if kernel not in KERNELS:
        raise InputError(
            f"{KERNEL_VARIABLE}={os.environ[KERNEL_VARIABLE]!r} is not a kernel: use one of "
            + ", ".join(KERNELS)
        )
    if kernel == "numba" and not available():
        raise InputError(
            f"{KERNEL_VARIABLE}=numba, but numba is not installed (pip install 'nlpcal[fast]')"
        )
    return kernel


def available() -> bool:
    """Whether numba can be imported (without importing it)."""
    from importlib.util import find_spec

    return find_spec("numba") is not None


def use(samples: float) -> bool:
    """Whether a pass over `samples` samples runs the compiled kernel (see the module)."""
    kernel = choice()
    if kernel != "auto":
        return kernel == "numba"
    return samples >= COMPILED_FROM and available()


def add(sums: np.ndarray, variables: np.ndarray, weight, plan: tuple) -> bool:
    """Add the moments of a chunk to the flat block sums `sums` (`MomentSet.add`'s contract),
    with `plan` the arrays of `MomentSet.compiled_plan`; False, with nothing added, where numba
    cannot be imported (a Dask worker without the `fast` extra: the numpy kernel then runs)."""
    kernel = _kernel()
    if kernel is None:
        return False
    # C-contiguous writeable float arrays only, so that numba compiles one specialisation (a
    # copy is made of a chunk's columns cut from a longer buffer, or of a scalar weight)
    rows = variables.shape[1]
    if weight is None:
        w = np.empty(0)
    elif np.ndim(weight) == 0:
        w = np.full(rows, float(weight))
    else:
        w = np.ascontiguousarray(weight, dtype=float)
    kernel(sums, np.ascontiguousarray(variables, dtype=float), w, *plan, STEP)
    return True


def load() -> None:
    """Import numba and make the compiled kernel ready (read from numba's cache, or compiled
    there the first time), as the first pass that runs it would: for a benchmark, or a process
    that wants the cost paid before its first log."""
    # the moments 1 and y of two variables (x, y): one left row (x^0), two right rows (1, y)
    integer = np.int64
    plan = (
        np.array([0], dtype=integer),  # the left variable: x
        np.array([[-1, -1]], dtype=integer),
        np.zeros((1, 1), dtype=integer),
        np.array([1], dtype=integer),  # the right variable: y
        np.array([[-1, -1], [0, 0]], dtype=integer),
        np.array([[0, 1, 2, 0]], dtype=integer),
    )
    if not add(np.zeros(2), np.ones((2, 3)), None, plan):
        raise InputError("numba is not installed (pip install 'nlpcal[fast]')")


def _kernel() -> Callable | None:
    """The compiled `nlpcal._moment_kernel.add`, imported (and numba with it) at first use;
    None where numba cannot be imported."""
    if not _loaded:
        with _lock:
            if not _loaded:
                _loaded.append(_imported())
    return _loaded[0]


def _imported() -> Callable | None:
    try:
        from ._moment_kernel import add
    except ImportError:
        return None
    return add
