"""IPOPT settings, the one build-once idiom of nlpcal's NLPs, and the one way to call them.

Every optimisation problem in nlpcal is a symbolic CasADi NLP whose size does not depend on the
number of samples: the data enter as parameters `p` of fixed size (moment matrices, sums), and the
problem is built once per process and re-solved with new numbers. The idiom is one decorator:

    @problem("zhou2010.block", examples=[("joint", "none"), ...])
    def block_problem(block, reference): ...    # returns what it built

which caches the builder per argument tuple and registers it, so a single test can check, for
every problem nlpcal has, that it is built once and that its parameter vector has the same size
for any log. IPOPT does not raise on failure: `solve` always reads `stats()["success"]` and
`["return_status"]` and hands them back.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from ..errors import SolveError


@dataclass(frozen=True)
class IpoptOptions:
    """The IPOPT settings nlpcal uses; one place to change them."""

    tol: float = 1e-10
    # Tiny objectives (noise-free data near the optimum) carry rounding noise in their gradient;
    # five iterations in a row within acceptable_tol then count as solved.
    acceptable_tol: float = 1e-6
    acceptable_iter: int = 5
    max_iter: int = 200
    print_level: int = 0
    hessian_approximation: str = "exact"
    extra: tuple = ()  # further (name, value) IPOPT options; a tuple keeps the settings hashable

    def as_casadi(self) -> dict:
        ipopt = {
            "tol": self.tol,
            "acceptable_tol": self.acceptable_tol,
            "acceptable_iter": self.acceptable_iter,
            "max_iter": self.max_iter,
            "print_level": self.print_level,
            "sb": "yes",
            "hessian_approximation": self.hessian_approximation,
        }
        ipopt.update(dict(self.extra))
        return {"ipopt": ipopt, "print_time": False}


#: Every registered problem builder: name -> (cached builder, example argument tuples).
PROBLEMS: dict = {}


def problem(name: str, examples=((),)):
    """Register a problem builder under `name` and cache it per argument tuple (build once).

    examples : argument tuples with which the registry test builds the problem.
    """

    def register(builder):
        cached = lru_cache(maxsize=None)(builder)
        PROBLEMS[name] = (cached, tuple(examples))
        return cached

    return register


def builds() -> int:
    """How many problems have been built in this process (cache misses of every builder)."""
    return sum(builder.cache_info().misses for builder, _ in PROBLEMS.values())


class _InPlace:
    """The arrays a built CasADi function reads its arguments from and writes its results to
    (`Function.buffer`), by name: no conversion of the arguments (the Gram matrix of the moment
    problems, 2 139 numbers) or results on every call (30-40 us through the Python call)."""

    def __init__(self, function):
        self.buffer, self.evaluate = function.buffer()  # the buffer must outlive evaluate
        self.arguments = {
            name: np.zeros(function.nnz_in(i)) for i, name in enumerate(function.name_in())
        }
        self.results = {
            name: np.zeros(function.nnz_out(i)) for i, name in enumerate(function.name_out())
        }
        for i, values in enumerate(self.arguments.values()):
            _bind(self.buffer.set_arg, i, values)
        for i, values in enumerate(self.results.values()):
            _bind(self.buffer.set_res, i, values)


class Evaluation:
    """A built CasADi function f(x, p) evaluated in place on numpy arrays (`_InPlace`).

    For the small functions evaluated many times per log (the Newton checks of every stage): a
    call costs a few microseconds where the Python call converts its arguments and results
    (30-40 us, more than the evaluation). Each call returns copies of the results, a float for
    a scalar. Safe to share between threads (one evaluation at a time).
    """

    def __init__(self, function: ca.Function):
        if function.n_in() != 2:
            raise ValueError(f"{function.name()} is not a function of (x, p)")
        if not all(function.sparsity_out(i).is_dense() for i in range(function.n_out())):
            raise ValueError(f"{function.name()} has an output that is not dense")
        self._arrays = _InPlace(function)
        self._x, self._p = self._arrays.arguments.values()
        self._shapes = [function.size_out(i) for i in range(function.n_out())]
        self._lock = threading.Lock()

    def __call__(self, x, p) -> tuple:
        """The results at x for the parameters p."""
        p = np.ravel(p)
        if p.size != self._p.size:
            raise ValueError(f"expected {self._p.size} parameters, got {p.size}")
        with self._lock:
            self._x[:] = x
            self._p[:] = p
            _run(self._arrays.evaluate)
            results = self._arrays.results.values()
            return tuple(_read(r, shape) for r, shape in zip(results, self._shapes))


def _run(evaluate) -> None:
    """Run a FunctionBuffer's evaluation. CasADi checks for signals during a solve (Ctrl-C, or
    SIGTERM where the command line turns it into an exception); one handled while it ran comes
    back wrapped in a SystemError (or, from some places, a RuntimeError naming it) and is raised
    here as the interruption it is."""
    try:
        evaluate()
    except (SystemError, RuntimeError) as error:
        cause = error.__cause__ or error.__context__
        if isinstance(cause, KeyboardInterrupt):
            raise cause from None
        if "KeyboardInterrupt" in str(error):
            raise KeyboardInterrupt(str(error)) from None
        raise


def _bind(bind, i: int, values: np.ndarray) -> None:
    """Point argument or result i of a FunctionBuffer at `values`, read or written in place."""
    bind(i, memoryview(values))  # type: ignore[arg-type]


def _read(values: np.ndarray, shape) -> float | np.ndarray:
    """One result of an Evaluation: a float, a vector or a matrix (CasADi stores by column)."""
    if values.size == 1:
        return float(values[0])
    if shape[1] == 1:
        return values.copy()
    return values.reshape(shape, order="F").copy()


#: One IPOPT solve at a time in a process: IPOPT and its linear solver (MUMPS) are not
#: thread-safe, and a solver's arrays and statistics (`_InPlace`) are those of its latest call.
#: Threads (a fleet calibrated on Dask's threads scheduler) still overlap their reading and
#: their data passes.
SOLVE_LOCK = threading.Lock()

#: IPOPT statuses that count as solved.
SUCCESS_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


def build_nlpsol(name: str, x, f, p, g=None, options: IpoptOptions | None = None):
    """Create an IPOPT `nlpsol` for min f(x; p) s.t. lbg <= g(x; p) <= ubg."""
    nlp = {"x": x, "f": f, "p": p}
    if g is not None:
        nlp["g"] = g
    return ca.nlpsol(name, "ipopt", nlp, (options or IpoptOptions()).as_casadi())


@dataclass
class SolveOutcome:
    """What one IPOPT solve returned."""

    x: np.ndarray
    f: float
    status: str
    success: bool
    iterations: int
    # IPOPT's objective at its start and after each iteration (of its problem, as scaled there)
    objectives: tuple = ()

    def record(self) -> dict:
        """IPOPT's status and iteration count, for a result document."""
        return {"status": self.status, "iterations": self.iterations}

    def checked(self, what: str) -> SolveOutcome:
        """This outcome, or SolveError when IPOPT did not solve `what`."""
        if not self.success:
            raise SolveError(f"IPOPT did not solve the {what}", self.status, self)
        return self


def _in_place(solver) -> _InPlace:
    if getattr(solver, "_nlpcal_in_place", None) is None:
        solver._nlpcal_in_place = _InPlace(solver)
    return solver._nlpcal_in_place


def solve(solver, *, x0, p, lbx=-np.inf, ubx=np.inf, lbg=-np.inf, ubg=np.inf) -> SolveOutcome:
    """Solve a built `nlpsol` and read back IPOPT's status and iteration count.

    x0, p and the bounds are numbers or arrays (a bound may be one number for all).
    """
    with SOLVE_LOCK:
        arrays = _in_place(solver)
        given = {"x0": x0, "p": p, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg}
        for name, values in given.items():
            arrays.arguments[name][:] = np.ravel(np.asarray(values, dtype=float), order="F")
        arrays.arguments["lam_x0"][:] = 0.0
        arrays.arguments["lam_g0"][:] = 0.0
        _run(arrays.evaluate)
        stats = arrays.buffer.stats()
        x, f = arrays.results["x"].copy(), float(arrays.results["f"][0])
    status = str(stats.get("return_status", "unknown"))
    return SolveOutcome(
        x=x,
        f=f,
        status=status,
        success=bool(stats.get("success", False)) or status in SUCCESS_STATUSES,
        iterations=int(stats.get("iter_count", 0)),
        objectives=tuple(float(v) for v in stats.get("iterations", {}).get("obj", ())),
    )
