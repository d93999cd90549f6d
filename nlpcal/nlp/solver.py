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

import io
import os
import re
import tempfile
import threading
import time
from contextlib import redirect_stdout
from dataclasses import dataclass, replace
from functools import lru_cache, wraps

import casadi as ca
import numpy as np

from .. import interruptions
from ..errors import InputError, SolveError


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

    def settings(self) -> dict:
        """IPOPT's options as IPOPT is given them (the `extra` ones last, overriding)."""
        return {
            "tol": self.tol,
            "acceptable_tol": self.acceptable_tol,
            "acceptable_iter": self.acceptable_iter,
            "max_iter": self.max_iter,
            "print_level": self.print_level,
            "sb": "yes",
            "hessian_approximation": self.hessian_approximation,
            **dict(self.extra),
        }

    def as_casadi(self) -> dict:
        """CasADi's `nlpsol` options: IPOPT's, no timing printout, and no multipliers of the
        parameters (`lam_p`), which nlpcal never reads: CasADi would differentiate the
        Lagrangian by the whole parameter vector (the Gram matrix: 2 139 entries) after every
        solve, 4 % of a small solve's time."""
        return {"ipopt": self.settings(), "print_time": False, "calc_lam_p": False}

    def with_options(self, options: dict | None) -> IpoptOptions:
        """These settings with the further IPOPT `options` (name -> int, float or str), each
        checked by IPOPT itself (`check_ipopt_options`)."""
        if not options:
            return self
        check_ipopt_options(options)
        merged = {**dict(self.extra), **options}
        return replace(self, extra=tuple(sorted(merged.items())))


def ipopt_value(text: str) -> int | float | str:
    """The value of an IPOPT option given as text: an integer, else a number, else the text
    (IPOPT's option types: Integer, Number, String)."""
    text = text.strip()
    if re.fullmatch(r"[+-]?\d+", text):
        return int(text)
    try:
        value = float(text)
    except ValueError:
        return text
    return value if np.isfinite(value) else text


def check_ipopt_options(options: dict) -> None:
    """InputError, in IPOPT's words, unless IPOPT knows every option and accepts its value.

    IPOPT checks its options when a solver is created; a one-variable problem is created with
    them, IPOPT's printed complaint captured (it writes to the process's standard output).
    """
    for name, value in options.items():
        if not isinstance(name, str) or isinstance(value, bool):
            raise InputError(f"IPOPT option {name!r}: expected a name and a number or a string")
        if not isinstance(value, (int, float, str)):
            raise InputError(f"IPOPT option {name}: expected a number or a string, got {value!r}")
    x = ca.SX.sym("x")
    settings = {**options, "print_level": 0, "sb": "yes"}
    python_side = io.StringIO()  # CasADi hands IPOPT's messages to Python's stdout
    with tempfile.TemporaryFile(mode="w+b") as captured, redirect_stdout(python_side):
        saved = os.dup(1)
        try:
            os.dup2(captured.fileno(), 1)
            try:
                with interruptions.deferred():  # a symbolic operation: see `problem`
                    ca.nlpsol("check", "ipopt", {"x": x, "f": x * x}, {"ipopt": settings})
                error = None
            except RuntimeError as exc:
                error = str(exc)
        finally:
            os.dup2(saved, 1)
            os.close(saved)
        captured.seek(0)
        printed = captured.read().decode(errors="replace") + python_side.getvalue()
    if error is None:
        return
    said = re.search(
        r'Setting: "(.*?)" is not a valid setting for Option: (\S+?)\.?(?=\s|$)', printed
    )
    unknown = re.search(r"No such IPOPT option: (\S+)", error)
    if said:
        reason = f"IPOPT refuses {said.group(1)} for its option {said.group(2)}"
    elif unknown:
        reason = f"IPOPT has no option {unknown.group(1)}"
    elif "type mismatch" in error:
        reason = f"a value of the wrong type for IPOPT (given: {options})"
    else:
        reason = error.strip().splitlines()[-1]
    raise InputError(f"bad IPOPT option: {reason}")


#: Every registered problem builder: name -> (cached builder, example argument tuples).
PROBLEMS: dict = {}


def problem(name: str, examples=((),)):
    """Register a problem builder under `name` and cache it per argument tuple (build once).
    A Ctrl-C or SIGTERM during a build acts as the build ends (`nlpcal.interruptions`).

    examples : argument tuples with which the registry test builds the problem.
    """

    def register(builder):
        @wraps(builder)
        def build(*args, **kwargs):
            # CasADi's symbolic operations would drop a Ctrl-C raised inside them
            with interruptions.deferred():
                return builder(*args, **kwargs)

        cached = lru_cache(maxsize=None)(build)
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
        self.evaluated = 0.0  # CasADi's running total of the time in the solver's functions [s]

    def evaluation_time(self, stats: dict) -> float:
        """The time the latest call spent evaluating the problem's functions (objective,
        gradient, Hessian) [s]: the increase of CasADi's timers, which run on across the calls
        of a FunctionBuffer (taken whole should a CasADi restart them)."""
        total = sum(v for k, v in stats.items() if k.startswith("t_wall_nlp_"))
        spent = total - self.evaluated if total >= self.evaluated else total
        self.evaluated = total
        return float(spent)


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
        self._held = None  # the read-only parameters last copied in, which cannot have changed

    def __call__(self, x, p) -> tuple:
        """The results at x for the parameters p (a read-only array given again is not copied
        again: the Gram matrix of every check of one log; the caller does not change a
        read-only array it gave, `nlpcal.nlp.blocks.parameter_values` never does)."""
        with self._lock:
            self._x[:] = x
            if p is not self._held:
                self._hold(p)
            _run(self._arrays.evaluate)
            results = self._arrays.results.values()
            return tuple(_read(r, shape) for r, shape in zip(results, self._shapes))

    def _hold(self, p) -> None:
        values = np.ravel(p)
        if values.size != self._p.size:
            self._held = None
            raise ValueError(f"expected {self._p.size} parameters, got {values.size}")
        self._p[:] = values
        # kept only when nothing can change it: read-only, and no view of another array
        fixed = isinstance(p, np.ndarray) and not p.flags.writeable and p.base is None
        self._held = p if fixed else None


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


#: What finished a block solve (`nlpcal.nlp.steps.block_step`): IPOPT, a Newton step verified
#: to land within the resolution of the data, or the start itself (nothing to improve on).
FINISHERS = ("ipopt", "newton", "start")
#: nlpcal's own statuses of a block solve, beside IPOPT's: the start at the precision of the
#: float64 moments, a Newton step within the resolution of the data (IPOPT not run), IPOPT given
#: up where Newton steps reach that resolution, and a solve that ended above its start.
NLPCAL_STATUSES = ("At_Precision_Floor", "At_Stationary_Point", "At_Data_Resolution", "Start_Kept")


@dataclass
class SolveOutcome:
    """What one solve returned.

    status : IPOPT's return status; "" when IPOPT did not run (`finished_by` "newton" or
        "start"). iterations : IPOPT's iterations (0 when it did not run).
    finished_by : what finished the solve (FINISHERS). nlpcal_status : nlpcal's own status
        (NLPCAL_STATUSES) when its checks, not IPOPT's, decided the solve; None otherwise.
    """

    x: np.ndarray
    f: float
    status: str
    success: bool
    iterations: int
    # IPOPT's objective at its start and after each iteration (of its problem, as scaled there)
    objectives: tuple = ()
    finished_by: str = "ipopt"
    nlpcal_status: str | None = None
    # the wall time of the solver's call [s], and of it in the evaluations of the problem's
    # functions [s]; IPOPT's own time (with CasADi's) is the rest: what benchmarks split
    wall_s: float = 0.0
    evaluations_s: float = 0.0

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
        started = time.perf_counter()
        _run(arrays.evaluate)
        wall = time.perf_counter() - started
        stats = arrays.buffer.stats()
        evaluations = arrays.evaluation_time(stats)
        x, f = arrays.results["x"].copy(), float(arrays.results["f"][0])
    status = str(stats.get("return_status", "unknown"))
    return SolveOutcome(
        x=x,
        f=f,
        status=status,
        success=bool(stats.get("success", False)) or status in SUCCESS_STATUSES,
        iterations=int(stats.get("iter_count", 0)),
        objectives=tuple(float(v) for v in stats.get("iterations", {}).get("obj", ())),
        wall_s=wall,
        evaluations_s=evaluations,
    )
