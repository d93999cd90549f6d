"""The data passes' compiled kernels: `nlpcal.monomials.MomentSet.add` as one numba function,
and the columns of the scores.

The numpy kernel builds the rows of monomials with element-wise products and sums them with
matrix products (BLAS), a dozen short calls per 4 096 samples; two threads running it side by
side spend much of their time waiting for each other's Python (the GIL). The compiled kernel
(`nlpcal._moment_kernel`) does the same work in one call per chunk that releases the GIL: the
moment pass of 10^6 samples with a constant reference takes 26 ms in the pass's two threads
against 98 ms with the numpy kernel (`benchmarks/bench_calibrate.py --pass-costs`). The pass
after the solve runs in the same way the per-sample columns of its scores
(`nlpcal.calibration.scores.ScoreTerms.columns`, compiled in `nlpcal._score_kernel`: one loop
over a chunk's samples in place of a dozen whole-array calls); their block sums stay BLAS's. A
warm joint fit of 10^6 samples then takes 49 ms against 60 with the moments alone compiled.

It needs numba (the `fast` extra), which costs time to load: importing it and reading the
compiled kernel from numba's cache take 0.3-0.45 s in a new process (compiling it, the first
time after an install, 2-3 s). A pass therefore uses it (`use`) when it is long enough to repay
the load, COMPILED_FROM samples, and numba loads, unless the environment variable
NLPCAL_KERNEL says otherwise: "numpy" never, "numba" always (for a process that runs many
passes: a notebook, a service, a batch of logs, where the load is paid once), and a refusal
when it cannot run. A Dask worker where numba does not load runs the numpy kernel. Both
kernels compute the same sums to rounding: the compiled one adds the samples of a chunk in
another order (about 1e-16 of the moments in norm, up to 2e-13 of a single small moment;
`tests/test_compiled.py`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from functools import cache
from typing import NamedTuple

import numpy as np

from .errors import InputError

#: The environment variable that chooses the kernel: "auto" (unset), "numpy" or "numba".
KERNEL_VARIABLE = "NLPCAL_KERNEL"
KERNELS = ("auto", "numpy", "numba")
#: The samples of one pass from which, in "auto", the compiled kernel is loaded: it saves
#: 60-110 ns per sample on 2 cores against a load of 0.3-0.45 s. [samples]
COMPILED_FROM = 5_000_000
#: Samples per step of the compiled kernel: the 70 rows of monomials of the nine-parameter
#: objective by 1 024 samples, 560 kB, stay in a core's L2 cache between their building and
#: their sums; 512 to 2 048 samples cost the same within 10 % (4 096: +30 %). Larger plans keep
#: the same step: held to 560 kB, the series' 101 rows cost 47 ns per sample against 35-38, the
#: two channels' 145 against 118 (`bench_calibrate.py --pass-costs`). [samples]
STEP = 1024


class KernelPlan(NamedTuple):
    """A `MomentSet`'s plan as the arrays of the compiled kernel (`_moment_kernel.add`)."""

    left_variables: np.ndarray  # (L,) the row of the variables of each left variable
    left_recipe: np.ndarray  # (rows, 2) parent row and left variable, (-2, -1): from powers
    left_powers: np.ndarray  # (rows, L) powers of the left variables of rows built from them
    right_variables: np.ndarray  # (R,)
    right_recipe: np.ndarray  # (rows, 2) parent row and right variable
    blocks: np.ndarray  # (blocks, 4) first row, last row + 1, right prefix, offset in the sums


class Kernels(NamedTuple):
    """The compiled functions, imported together."""

    moments: Callable  # `_moment_kernel.add`
    scores: Callable  # `_score_kernel.columns`


def choice() -> str:
    """NLPCAL_KERNEL, checked: one of KERNELS. Raises InputError otherwise."""
    kernel = os.environ.get(KERNEL_VARIABLE, "auto").strip().lower() or "auto"
    if kernel not in KERNELS:
        raise InputError(
            f"{KERNEL_VARIABLE}={os.environ[KERNEL_VARIABLE]!r} is not a kernel: use one of "
            + ", ".join(KERNELS)
        )
    return kernel


def available() -> bool:
    """Whether numba is installed (without importing it)."""
    from importlib.util import find_spec

    return find_spec("numba") is not None


def use(samples: float) -> bool:
    """Whether a pass over `samples` samples runs the compiled kernel (see the module): in
    "auto", from COMPILED_FROM samples where numba loads (imported here); with
    NLPCAL_KERNEL=numba always, or InputError saying why it cannot."""
    kernel = choice()
    if kernel == "numba":
        _ready()
        return True
    if kernel == "numpy" or samples < COMPILED_FROM or not available():
        return False
    return _imported()[0] is not None


def load() -> None:
    """Import numba and make the compiled kernel ready (read from numba's cache, or compiled
    there the first time), as the first pass that runs it would: for a benchmark, or a process
    that wants the cost paid before its first log. InputError when it cannot run."""
    _ready()
    # the moments 1 and y of two variables (x, y): one left row (x^0), two right rows (1, y)
    integer = np.int64
    plan = KernelPlan(
        np.array([0], dtype=integer),  # the left variable: x
        np.array([[-1, -1]], dtype=integer),
        np.zeros((1, 1), dtype=integer),
        np.array([1], dtype=integer),  # the right variable: y
        np.array([[-1, -1], [0, 0]], dtype=integer),
        np.array([[0, 1, 2, 0]], dtype=integer),
    )
    add(np.zeros(2), np.ones((2, 3)), None, plan)
    score_columns(np.ones((4, 3)), np.zeros(3), np.eye(3), np.empty((10, 4)), np.empty((14, 4)))


def add(sums: np.ndarray, variables: np.ndarray, weight, plan: KernelPlan) -> bool:
    """Add the moments of a chunk to the flat block sums `sums` (`MomentSet.add`'s contract:
    weight None or (rows,)), with `plan` its `MomentSet.compiled_plan`; False, with nothing
    added, where the kernel does not load (a Dask worker without numba: numpy then runs)."""
    kernels = _imported()[0]
    if kernels is None:
        return False
    # C-contiguous float arrays, so that numba compiles one specialisation (a copy is made of a
    # chunk's columns cut from a longer buffer)
    w = np.empty(0) if weight is None else np.ascontiguousarray(weight, dtype=float)
    kernels.moments(sums, np.ascontiguousarray(variables, dtype=float), w, *plan, STEP)
    return True


def score_columns(raw, offset, matrix, y: np.ndarray, work: np.ndarray) -> np.ndarray | None:
    """`nlpcal.calibration.scores.ScoreTerms.columns` compiled, for a chunk of raw samples
    (n, 3): fills y[0:9, :n] (f), work[11, :n] (1 / |B1|) and work[13, :n] (|g|^2) of the
    whole arrays of `ScoreTerms.workspace` and returns |B1| (n,) [field unit]; None, with
    nothing filled, where the kernel does not load."""
    kernels = _imported()[0]
    if kernels is None:
        return None
    raw = np.ascontiguousarray(np.asarray(raw, dtype=float).T)  # (3, n), a copy of the chunk
    n = raw.shape[1]
    if y.shape[0] != 10 or work.shape[0] != 14 or min(y.shape[1], work.shape[1]) < n:
        # numba checks no bounds: past them it would write over other memory
        raise ValueError("score_columns takes y (10, >= n) and work (14, >= n)")
    magnitude = np.empty(n)
    kernels.scores(raw, np.asarray(offset, float), np.asarray(matrix, float), y, work, magnitude)
    return magnitude


def _ready() -> None:
    """Nothing when the compiled kernel loads; else InputError saying why."""
    if not available():
        raise InputError(
            f"{KERNEL_VARIABLE}=numba, but numba is not installed (pip install 'nlpcal[fast]')"
        )
    kernel, why = _imported()
    if kernel is None:
        raise InputError(f"{KERNEL_VARIABLE}=numba, but {why}")


@cache
def _imported() -> tuple[Kernels | None, str]:
    """(the compiled `Kernels`, "") imported, and numba with them, at first use; (None, why)
    where they cannot be."""
    try:
        from ._moment_kernel import add as moments
        from ._score_kernel import columns as scores
    except ImportError as error:
        return None, f"numba cannot be imported ({error})"
    except RuntimeError as error:  # numba finds no folder it may write its cache in
        return None, (
            f"numba cannot keep the compiled kernel ({error}); set NUMBA_CACHE_DIR to a "
            "writable folder"
        )
    return Kernels(moments, scores), ""
