"""One block solve of the nine-parameter calibration: IPOPT, checked and finished by Newton steps.

`block_step` minimises the objective over one block of parameters (a stage of Fig. 1 in [1], or
all nine) with the others held fixed, on the problems of `nlpcal.nlp.blocks`. Around IPOPT,
Newton steps with the exact gradient and Hessian of the objective in the block's parameters
(`objective_function`, or a stage's smaller `block_objective_function`) decide what IPOPT
cannot: whether a block starts at its optimum to the resolution of the data (then IPOPT is not
called, nor its problem built), and when IPOPT's answer is the optimum (they finish it,
whatever IPOPT's tolerance left, and judge a solve IPOPT gave up on in the rounding noise of
the moment objective).

The resolution is the statistical one: a step shorter than STATIONARY_SE standard errors of the
estimate moves no parameter by more than that (`resolution`).

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

from .. import moments as mom
from ..errors import SolveError
from .blocks import (
    BLOCKS,
    OPTIONS,
    BlockProblem,
    Variables,
    block_objective_function,
    block_problem,
    evaluate,
    objective_function,
    parameter_values,
    value_function,
    variable_scale,
    variables,
)
from .solver import IpoptOptions, SolveOutcome, solve

#: Objective values below this fraction of L^2 (a spread of 1e-8 L, 5e-4 nT in 50 000 nT)
#: are at the resolution of the float64 moments; a block starting there is not re-solved.
PRECISION_FLOOR = 1e-16
#: The objective is divided by its start value, but never by less than this fraction of L^2, so
#: that rounding noise in tiny objectives (noise-free data) is not blown up into the gradient.
SCALE_FLOOR = 1e-14


@dataclass
class Step:
    """What one block solve did: the new parameters and the objective before and after."""

    theta: np.ndarray
    outcome: SolveOutcome
    f_start: float  # [field^2]
    f_end: float  # [field^2], the moment objective at `theta`
    f_ref: float  # [field^2], the objective scale the problem was solved with
    block: str
    x: np.ndarray  # the scaled variables of `theta` in this problem (`free`)
    # Hessian of the scaled objective f / f_ref in x, from the last Newton check: at `x`, or at
    # the point whose Newton step, within STATIONARY_SE standard errors, landed on `x` (over
    # which the Hessian changes by far less than its own precision)
    hess: np.ndarray = field(repr=False)
    # [field^2], what a Newton step from the start promised, when it was taken instead of IPOPT
    newton_decrease: float | None = None
    problem: BlockProblem | None = None  # the IPOPT problem, when IPOPT ran
    free: Variables | None = None  # the problem's variables (block, reference kind, model)

    @property
    def iterations(self) -> int:
        return self.outcome.iterations

    @property
    def status(self) -> str:
        """nlpcal's status of the solve when its checks decided it, else IPOPT's."""
        return self.outcome.nlpcal_status or self.outcome.status


#: The smallest Newton decrease, as a fraction of the objective, that float64 moments resolve. [1]
STATIONARY_RTOL = 1e-12
#: A block whose Newton step from its start would move the parameters by less than this many
#: standard errors starts at its optimum to the resolution of the data (`resolution`): the
#: Newton step, not IPOPT, finishes it. [standard errors]
STATIONARY_SE = 0.01


def resolution(moments: mom.Moments, standard_errors: float = STATIONARY_SE) -> float:
    """The Newton decrease, as a fraction of the objective, of a step `standard_errors` long.

    With the covariance C = (2 f / N) H^-1 of a least-squares estimate (f the mean squared
    residual, H its Hessian), a Newton step delta = H^-1 g is sqrt(delta^T C^-1 delta) =
    sqrt(N d / f) standard errors long, d = g^T H^-1 g / 2 the decrease it promises; that length
    bounds the move of every parameter in its own standard errors. So the step is shorter than
    s standard errors when d / f <= s^2 / N. Above N = s^2 / STATIONARY_RTOL (1e8 samples for
    s = 0.01) the precision of f, not the data, sets the limit: steps up to
    s sqrt(N / 1e8) standard errors are then below what the float64 moments resolve.
    """
    return max(STATIONARY_RTOL, standard_errors**2 / moments.n)


def _newton_step(free: Variables, g: np.ndarray, h: np.ndarray):
    """One Newton step of the objective over a block (gradient g and Hessian h in its scaled
    variables), on the gauge's null space when the block has one: (the decrease it promises,
    the step). The decrease is inf, and the step zero, when the Hessian is not positive."""
    if free.gauge:
        basis = free.gauge_basis
        g, h = basis.T @ g, basis.T @ h @ basis
    try:
        factor = np.linalg.cholesky(0.5 * (h + h.T))
    except np.linalg.LinAlgError:
        return np.inf, np.zeros(free.size)
    half = np.linalg.solve(factor, g)  # H^-1 = L^-T L^-1
    step = -np.linalg.solve(factor.T, half)
    return 0.5 * float(half @ half), basis @ step if free.gauge else step


@dataclass(frozen=True)
class _Newton:
    """One Newton step over a block from theta_ref + var_scale * x (x the block's scaled
    variables), from the objective's exact gradient and Hessian (`objective_function`).

    The objective and the decrease are in field^2, the gradient and Hessian per unit of x.
    """

    moments: mom.Moments
    free: Variables
    theta_ref: np.ndarray
    x: np.ndarray
    f: float
    hess: np.ndarray
    decrease: float
    step: np.ndarray

    @classmethod
    def at(cls, moments: mom.Moments, free: Variables, theta_ref, x) -> _Newton:
        directions = _directions(moments.frame.radius, free)  # d theta[block] / dx
        theta = _theta(moments, free, theta_ref, x)
        f_value, gradient, hess = _derivatives(moments, theta, free.block)
        g = directions.T @ gradient
        h = directions.T @ hess @ directions
        decrease, step = _newton_step(free, g, h)
        x = np.asarray(x, dtype=float)
        return cls(moments, free, theta_ref, x, f_value, h, decrease, step)

    def within(self, threshold: float | None = None) -> bool:
        """Whether x is the block's optimum to the resolution of the data: the step is shorter
        than STATIONARY_SE standard errors (or promises less than `threshold` of f)."""
        limit = resolution(self.moments) if threshold is None else threshold
        return self.decrease <= limit * self.f

    def taken(self) -> _Newton:
        """Where the step lands: x + step with f there (the Hessian and decrease are still the
        ones at x), or this point itself where the step is no finishing one (longer than
        FINISHING_STEP: a jump along a direction the data hardly determine) or f rises (by more
        than the step promised to lower it, or than PRECISION_FLOOR L^2: rounding). From within
        the resolution the step lands on the optimum to the square of its length in standard
        errors, and it is taken whichever way f moves: what it promises (below 1e-11 of f for
        10^7 samples) is less than the rounding of f (1e-10 of f on a 1 nT log in 50 000 nT),
        so that f's last bits, which the kernel that summed the moments decides, would
        otherwise choose between two answers up to STATIONARY_SE standard errors apart."""
        if not np.max(np.abs(self.step)) <= FINISHING_STEP or not np.any(self.step):
            return self
        x = self.x + self.step
        theta = _theta(self.moments, self.free, self.theta_ref, x)
        (f_value,) = evaluate(value_function, self.moments, theta)
        rounding = min(self.decrease, PRECISION_FLOOR * self.moments.length**2)
        if self.within() or f_value <= self.f + rounding:  # (a new _Newton: `replace` is slower)
            return _Newton(
                self.moments,
                self.free,
                self.theta_ref,
                x,
                f_value,
                self.hess,
                self.decrease,
                self.step,
            )
        return self

    def finished(self) -> _Newton:
        """Newton steps from here until one is within the resolution, which is taken: every
        IPOPT answer is finished this way, since IPOPT's tolerance is relative to the objective
        where its solve started (far above the optimum's from a poor start). A step that is not
        a finishing one (longer than FINISHING_STEP in the scaled variables, or not lowering f)
        stops the steps short of the resolution."""
        current = self
        for _ in range(FINISHING_STEPS):
            after = current.taken()
            if current.within() or after is current:
                return after
            current = _Newton.at(self.moments, self.free, self.theta_ref, after.x)
        return current


#: The most Newton steps that finish an IPOPT answer (each squares its distance to the optimum).
FINISHING_STEPS = 4
#: The longest finishing step, in the scaled variables (1e-3 of the field for an offset, 1e-3 for
#: a scale, 1e-2 rad for an angle): a longer one is not a finish but a jump on a flat objective.
FINISHING_STEP = 1.0


def _derivatives(moments: mom.Moments, theta, block: str) -> tuple:
    """f [field^2] at theta, and its gradient and Hessian in the parameters of `block` (the
    others do not move in its solve): those of all nine (`objective_function`, which the
    uncertainty reads too) for the joint problem, a stage's own smaller function for a stage."""
    if block == "joint":
        return evaluate(objective_function, moments, theta)
    return evaluate(block_objective_function, moments, theta, block)


def _theta(moments: mom.Moments, free: Variables, theta_ref, x) -> np.ndarray:
    """theta_ref + var_scale * (E x), x the scaled variables of the block."""
    return free.theta(theta_ref, x, _scale(moments.frame.radius))


@lru_cache(maxsize=64)
def _scale(radius: float) -> np.ndarray:
    """`variable_scale` of a frame, read-only: the same numbers for every check of a log."""
    scale = variable_scale(radius)
    scale.flags.writeable = False
    return scale


@lru_cache(maxsize=256)
def _directions(radius: float, free: Variables) -> np.ndarray:
    """d theta[block] / dx of a block's scaled variables (var_scale E, the rows of the block's
    parameters: E is zero elsewhere), read-only."""
    rows = list(BLOCKS[free.block])
    directions = variable_scale(radius)[rows, None] * free.matrix[rows]
    directions.flags.writeable = False
    return directions


def block_step(
    moments: mom.Moments,
    block: str,
    theta,
    options: IpoptOptions = OPTIONS,
    stationary: float | None = None,
    model: str = "full",
) -> Step:
    """Minimise over one block of theta from `theta`, the other blocks held fixed.

    model : the form of Eq. 4 (`nlpcal.models.zhou2010.MODELS`): the block frees only the
    directions the model estimates (`nlpcal.nlp.blocks.variables`); the others keep their
    values in `theta`.

    A block already at its optimum (a Newton step would gain less than the fraction
    `stationary` of the objective, by default `resolution`: a step shorter than STATIONARY_SE
    standard errors) is not handed to IPOPT, whose problem is then not even built: the Newton
    step finishes it (nlpcal status At_Stationary_Point, zero iterations). Otherwise IPOPT
    solves it, from where that Newton step lands if it is a finishing one (`_Newton.taken`),
    and Newton steps finish IPOPT's answer (`_Newton.finished`). The outcome says what finished
    the solve (`finished_by`: "ipopt", "newton" or "start") and keeps IPOPT's status apart from
    nlpcal's own (`nlpcal_status`, `nlpcal.nlp.solver.NLPCAL_STATUSES`): At_Precision_Floor
    (noise-free data, the objective below what float64 moments resolve), At_Stationary_Point
    (the Newton step from the start), At_Data_Resolution (IPOPT gave up, whatever its reason,
    where Newton steps reach the resolution) and Start_Kept (the solve ended above its start).
    Raises SolveError when IPOPT fails otherwise, or when the objective goes negative (status
    Negative_Objective). A solve that ends above its start, and not within the resolution,
    keeps the start: a stage never makes the objective worse.
    """
    theta = np.asarray(theta, dtype=float)
    free = variables(block, moments.reference, model)
    start = _Newton.at(moments, free, theta, np.zeros(free.size))
    done = _finished_at_start(moments, free, theta, start, stationary)
    if done is not None:
        return done
    f_start = start.f
    problem = block_problem(block, moments.reference, model, options)
    f_ref = max(f_start, SCALE_FLOOR * moments.length**2)
    p = parameter_values(moments).copy()
    p[0:9] = theta  # theta_ref: the blocks held fixed, and where x = 0
    p[-1] = f_ref
    bounds = {"lbg": 0.0, "ubg": 0.0} if problem.has_gauge else {}
    # IPOPT starts where the start's Newton step lands when that step is a finishing one (a
    # warm start: IPOPT checks it, and iterates from it unless it meets IPOPT's tolerance).
    outcome = solve(problem.solver, x0=start.taken().x, p=p, **bounds)
    outcome, end = _checked(moments, free, theta, outcome, f_start)
    # A stage never makes the objective worse, unless the difference is rounding: an answer the
    # Newton steps place within the resolution of the block's optimum is better than a start
    # that was not (else the start would not have been solved).
    if end.f > f_start + 1e-12 * f_ref and not end.within():
        outcome = replace(
            outcome,
            x=start.x,
            f=f_start / f_ref,
            finished_by="start",
            nlpcal_status="Start_Kept",
        )
        return _step(
            moments, free, theta, outcome, f_start, f_ref, start.hess / f_ref, problem=problem
        )
    outcome = replace(outcome, x=end.x, f=end.f / f_ref)
    return _step(moments, free, theta, outcome, f_start, f_ref, end.hess / f_ref, problem=problem)


def _finished_at_start(
    moments: mom.Moments, free: Variables, theta, start: _Newton, stationary: float | None
) -> Step | None:
    """The Step of a block solve that needs no IPOPT (`block_step`): noise-free data at their
    optimum (At_Precision_Floor, the objective below what float64 moments resolve), or a start
    whose Newton step is within `stationary` (At_Stationary_Point, the step finishes it); else
    None."""
    if abs(start.f) <= PRECISION_FLOOR * moments.length**2:
        # Noise-free data at their optimum: nothing left that float64 moments can resolve.
        outcome = SolveOutcome(
            x=start.x,
            f=start.f,
            status="",
            success=True,
            iterations=0,
            finished_by="start",
            nlpcal_status="At_Precision_Floor",
        )
        return _step(moments, free, theta, outcome, start.f, 1.0, start.hess)
    if start.within(stationary):
        landed = start.taken()
        outcome = SolveOutcome(
            x=landed.x,
            f=landed.f,
            status="",
            success=True,
            iterations=0,
            finished_by="newton",
            nlpcal_status="At_Stationary_Point",
        )
        return _step(moments, free, theta, outcome, start.f, 1.0, start.hess, start.decrease)
    return None


def _checked(moments: mom.Moments, free: Variables, theta, outcome, f_start: float) -> tuple:
    """(outcome, end): IPOPT's outcome of a block solve judged by nlpcal (`block_step`), and the
    `_Newton` point where the solve ends, after the Newton steps that finish it. Raises
    SolveError for a negative objective or a failure that Newton steps do not mend."""
    floor = PRECISION_FLOOR * moments.length**2
    # A negative objective (a variance) means the series of `nlp.objective` does not hold where
    # the solve went, which happens when the data leave directions undetermined.
    end = _Newton.at(moments, free, theta, outcome.x)
    if end.f < -floor:
        raise SolveError(
            f"the {free.block} problem's objective, a variance, went negative where the solve "
            "ended: its moment series does not hold there",
            "Negative_Objective",
            result=theta,
        )
    # Below PRECISION_FLOOR the gradient of the moment objective is rounding noise; above it, on
    # low-noise data (0.01 nT in 50 000 nT), the objective still rounds at 1e-7 to 1e-5 of
    # itself. IPOPT may then report a step below machine precision, or run out of iterations, or
    # fail otherwise, depending on the rounding of the BLAS kernel that summed the moments: its
    # last point is solved all the same when the Newton steps from it reach the resolution.
    if abs(end.f) <= floor and end.f <= f_start:
        if not outcome.success:
            outcome = replace(outcome, nlpcal_status="At_Precision_Floor", success=True)
    else:
        end = end.finished()
        if not outcome.success and end.within():
            outcome = replace(
                outcome, nlpcal_status="At_Data_Resolution", success=True, finished_by="newton"
            )
    if not outcome.success:
        raise SolveError(
            f"IPOPT did not solve the {free.block} problem", outcome.status, result=theta
        )  # the start, where the data's null directions show
    return outcome, end


def _step(
    moments, free, theta_ref, outcome, f_start, f_ref, hess, newton_decrease=None, problem=None
) -> Step:
    """The Step of a block solve from theta_ref that ended at `outcome.x` (scaled objective
    `outcome.f`), with the Hessian of the scaled objective from the last Newton check."""
    return Step(
        theta=_theta(moments, free, theta_ref, outcome.x),
        outcome=outcome,
        f_start=f_start,
        f_end=outcome.f * f_ref,
        f_ref=f_ref,
        block=free.block,
        x=outcome.x,
        hess=hess,
        newton_decrease=newton_decrease,
        problem=problem,
        free=free,
    )
