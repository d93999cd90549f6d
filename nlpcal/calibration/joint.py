"""The joint solve: all nine parameters of Eq. 4 in [1] in one IPOPT problem.

The paper argues that a joint solve converges badly because offsets (hundreds of nT), scale
errors (~1e-3) and angles (~1e-2 rad) differ by orders of magnitude. `nlpcal.nlp.blocks` scales
every variable to order one, and IPOPT uses the exact Hessian of the moment objective.

Start: the algebraic ellipsoid fit (`algebraic_start`), else offsets at the centre of a sphere
fitted to the raw samples, angles zero, and scales zero (Eq. 8) or the common scale that maps the
sphere radius onto the reference field. A start whose Newton step is shorter than
`nlpcal.nlp.steps.STATIONARY_SE` standard errors is the optimum to the resolution of the data
and is not handed to IPOPT: the Newton step finishes it (its solver report says
`finished_by` "newton", nlpcal status At_Stationary_Point). On a near-spherical log the
algebraic fit often is.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import time
from functools import cache

import numpy as np

from ..models.zhou2010 import from_correction
from ..moments import PSI_EXPONENTS
from ..nlp.blocks import variable_scale
from ..nlp.steps import block_step
from .result import BlockSolve, SolverReport


@cache
def _product_columns(layout) -> np.ndarray:
    """The Gram column of each product psi_k psi_l (a plain monomial of degree <= 4)."""
    column = {key[2]: j for j, key in enumerate(layout.keys) if key[:2] == (0, 0)}
    return np.array([[column[tuple(np.add(e, f))] for f in PSI_EXPONENTS] for e in PSI_EXPONENTS])


def algebraic_start(moments) -> np.ndarray | None:
    """The nine parameters of the algebraic ellipsoid fit, from the moments (internal units), or
    None where it does not give an ellipsoid (or the reference is a series).

    In the frame's coordinates d the fit minimises the mean of (q . psi(d))^2 over the ten
    quadratic monomials psi, with the quadratic part's trace fixed to one: a linear solve with
    the 10 x 10 matrix of their products, whose entries are moments of d up to degree four, all
    in the Gram matrix already. The quadric d^T A d + b.d + c = 0 is an ellipsoid
    (B - Z)^T Q (B - Z) = 1 with Q = A / (k L^2), and |M (B - Z)| is constant when
    M^T M = F^2 Q: the nine-parameter form of M (Eq. 4) is the upper-triangular factor of that
    product, up to a rotation the model does not carry (`models.zhou2010.from_correction`).
    Without a reference F is free: the common scale is set by the gauge s_x + s_y + s_z = 0.
    """
    layout = moments.layout
    if layout.varying_gamma:
        return None
    mean = moments.gram[layout.one] / moments.gram[layout.one, layout.one]
    products = mean[_product_columns(layout)]
    trace = np.r_[1.0, 1.0, 1.0, np.zeros(7)]
    try:
        q = np.linalg.solve(products, trace)
    except np.linalg.LinAlgError:
        return None
    q /= trace @ q
    a = np.array(
        [[q[0], q[3] / 2, q[4] / 2], [q[3] / 2, q[1], q[5] / 2], [q[4] / 2, q[5] / 2, q[2]]]
    )
    if not np.all(np.linalg.eigvalsh(a) > 0):
        return None
    d0 = -0.5 * np.linalg.solve(a, q[6:9])
    k = float(d0 @ a @ d0 - q[9])
    if not k > 0:
        return None
    length = moments.length
    field = length if moments.reference == "constant" else 1.0
    q_matrix = a / (k * length**2)  # (B - Z)^T Q (B - Z) = 1, B - Z = L (d - d0)
    try:
        params, _ = from_correction(
            field * np.linalg.cholesky(q_matrix).T, moments.frame.centre + length * d0
        )
    except (ValueError, np.linalg.LinAlgError):
        return None
    theta = params.theta
    if moments.reference == "none":  # the gauge: scale the field so the gains average one
        gains = 1.0 + theta[3:6]
        theta[3:6] = gains / gains.mean() - 1.0
    return theta


def joint_start(moments) -> np.ndarray:
    """Starting parameters (internal units: z [field], s [1], angles [rad])."""
    theta = np.zeros(9)
    theta[0:3] = moments.frame.centre
    if moments.reference != "none":
        theta[3:6] = moments.frame.radius / moments.length - 1.0
    return theta


#: Reweighting stops when no parameter moves by more than this many of its typical sizes
#: (`nlpcal.nlp.blocks.variable_scale`: 1e-9 of the field for offsets) and the scale is settled.
IRLS_XTOL = 1e-6
#: The most reweightings of a joint solve with a robust loss.
MAX_REWEIGHTS = 100


def run_joint(problem, start=None, start_name: str = "given", defer: bool = False):
    """Solve all nine at once; with a robust loss, reweight and re-solve from the least-squares
    solution until the weights no longer move the parameters (iteratively reweighted least
    squares, each solve warm-started), for at most MAX_REWEIGHTS reweightings: a reweighting
    that stops there, still moving the parameters, is said in `reweighting_limit_warning`.

    start : the first solve's start (internal units); default the algebraic ellipsoid fit
        (`algebraic_start`), else the sphere fit (`joint_start`), projected onto the model's
        parameters (`nlpcal.nlp.blocks.Variables.project`).
    start_name : what a given `start` is, for the report ("sphere" for `joint_start`).
    defer : the joint row's statistics are left to the pass after the solve
        (`Problem.deferred_row`).

    Returns (step, rows, report): the `nlpcal.nlp.steps.Step` of the last solve, the measured
    and the joint Table 1 rows, and the `SolverReport` of every solve (where the first started,
    what finished each, IPOPT's options).
    """
    rows = [problem.measured_row()]
    started = time.perf_counter()
    kind = start_name
    if start is None:
        start, kind = algebraic_start(problem.moments), "algebraic"
    if start is None:
        start, kind = joint_start(problem.moments), "sphere"
    start = problem.free.project(start)
    step = block_step(problem.moments, "joint", start, problem.ipopt, model=problem.model)
    records = [BlockSolve.of(step, 1, "joint")]
    scale = variable_scale(problem.moments.frame.radius)
    settled = not problem.loss.robust
    for _ in range(MAX_REWEIGHTS if problem.loss.robust else 0):
        changed = problem.reweight(step.theta)
        new = block_step(problem.moments, "joint", step.theta, problem.ipopt, model=problem.model)
        move = float(np.max(np.abs(new.theta - step.theta) / scale))
        step = new
        records.append(BlockSolve.of(step, len(records) + 1, "joint (reweighted)"))
        if move < IRLS_XTOL and not changed:
            settled = True
            break
    report = SolverReport(
        stages=records,
        stop_reason="solved" if settled else "reweighting_limit",
        ipopt_options=problem.ipopt.settings(),
        start=kind,
    )
    rows.append(
        (problem.deferred_row if defer else problem.row)(
            "joint",
            step.theta,
            step.f_end,
            iterations=report.iterations,
            wall_s=time.perf_counter() - started,
        )
    )
    return step, rows, report


def reweighting_limit_warning(report: SolverReport) -> str | None:
    """The warning of a joint robust solve whose reweighting stopped at its limit
    (MAX_REWEIGHTS) with the parameters still moving by more than IRLS_XTOL of their typical
    sizes, or the loss scale still changing; None otherwise."""
    if report.stop_reason != "reweighting_limit":
        return None
    return (
        f"the robust reweighting stopped at its limit of {MAX_REWEIGHTS} reweightings with the "
        f"parameters still moving: the weights had not settled, so the estimate is that of the "
        f"last weighting, not the optimum of the robust loss"
    )
