"""The paper's own solver: the conjugate gradient of section 5 in [1], jointly and stage-wise.

Section 5 of [1] minimises Eq. 8 with a Fletcher-Reeves conjugate gradient without line search:

    (1) given X_0 and the stopping threshold eps
    (2) S_0 = -grad f(X_0)
    (3) step p_k = a / (k + 1), a a chosen constant
    (4) X_{k+1} = X_k + p_k S_k
    (5) stop when |grad f(X_{k+1})| <= eps
    (6) v_k = |grad f(X_{k+1})|^2 / |grad f(X_k)|^2,  S_{k+1} = -grad f(X_{k+1}) + v_k S_k; k += 1

The paper says that solving all nine parameters at once "often works badly" with this method,
because offsets [nT], scale errors [1] and angles [rad] differ in unit and magnitude, so eps is hard
to set and the iteration often does not converge; it therefore solves one block at a time inside
the cycle of Fig. 1. This module runs the method as written so that the claim can be tested:

* the gradient is the exact gradient of the moment objective, `nlpcal.nlp.blocks.objective_function`
  (Eq. 8, or its reference variant when a reference field is given);
* `scaled=False` (the paper's setting) iterates on X in the units of Eq. 4: z [field unit],
  s [1] and the angles [rad]; `scaled=True` iterates on X / D with D = `variable_scale` (the
  scaling the IPOPT problems use), to show what the mixed magnitudes alone cost;
* without a reference field, Eq. 8 keeps shrinking as all (1 + s) grow together; as in the IPOPT
  problems, the gradient is projected onto the gauge s_x + s_y + s_z = 0 (a start on the gauge
  then stays on it), so that all methods minimise the same problem.

Choice of the constants (the paper leaves both open):

* a = `step_factor` / lambda_max, lambda_max the largest eigenvalue of the Hessian of f over the
  free block at X_0 (projected on the gauge). 1 / lambda_max is the largest steepest-descent step
  that cannot overshoot along the stiffest direction: the most favourable choice that does not
  depend on knowing the answer. It is set afresh for every solve (every stage of every cycle).
* eps = `rel_eps` |grad f| at the start of the first solve of the block (the first stage of that
  kind in the cycle, or the joint start), kept for the later cycles: the paper gives eps once, at
  step (1). A relative threshold needs no units; in the unscaled joint problem |grad f| is
  nevertheless dominated by the scale and angle components (about 1e5 times the offset components
  at the start), which is exactly the paper's difficulty: the threshold says nothing about the
  offsets. The final gradient norm of each block is reported so that this can be seen. A stage
  that starts below eps takes no step. (An eps set afresh relative to every stage's start would
  sink below the rounding noise of the gradient once the cycle has converged, and the
  Fletcher-Reeves ratio, fed by noise, then blows the direction up.)
* `max_iter` caps the iterations; the outcome says "max_iterations" and returns the last iterate
  when the cap is reached. A non-finite objective or gradient, or an objective DIVERGENCE_FACTOR
  times its start, stops the solve with "diverged"; the start of that solve is then returned
  unchanged (as an IPOPT stage that ends above its start keeps its start), so that a cycle can go
  on. Every outcome is reported, none is hidden.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .. import validation
from ..nlp.blocks import (
    BLOCKS,
    SCALE_INDICES,
    STAGE_ORDER,
    objective_function,
    pack,
    variable_scale,
)
from ..nlp.solver import problem

#: Statuses of a CG solve.
CONVERGED, MAX_ITERATIONS, DIVERGED = "converged", "max_iterations", "diverged"
#: An objective this many times its start counts as divergence.
DIVERGENCE_FACTOR = 1e4


@dataclass(frozen=True)
class CGOptions:
    """Settings of the conjugate gradient of section 5 in [1].

    step_factor : a = step_factor / lambda_max(Hessian at X_0 over the free block). [1]
    rel_eps : eps = rel_eps * |grad f(X_0)| at the first solve of a block. [1]
    max_iter : the most iterations of one solve.
    scaled : iterate on X / variable_scale instead of X (not the paper's setting).
    """

    step_factor: float = 1.0
    rel_eps: float = 1e-6
    max_iter: int = 2000
    scaled: bool = False

    def __post_init__(self):
        validation.number(self.step_factor, "step_factor (--cg-step-factor)", positive=True)
        validation.number(self.rel_eps, "rel_eps (--cg-rel-eps)", positive=True)
        validation.count(self.max_iter, "max_iter (--cg-max-iter)")


@dataclass
class CGOutcome:
    """What one CG solve did.

    status : "converged", "max_iterations" or "diverged".
    iterations : steps taken (gradient evaluations after the start).
    a : the step constant [X^2 / f]; eps : the gradient threshold [f / X] (X in the iteration
        variables: internal units, or scaled units when `scaled`).
    f_start, f_end : the moment objective at the start and at the returned iterate. [field^2]
    grad_norm : |grad f| at the returned iterate (iteration variables).
    grad_norm_blocks : |grad f| over each block in internal units (offset [field^2/field],
        scale [field^2], orthogonal [field^2/rad]).
    history : the objective after every step, starting with f_start. [field^2]
    """

    status: str
    iterations: int
    a: float
    eps: float
    f_start: float
    f_end: float
    grad_norm: float
    grad_norm_blocks: dict
    history: list = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def converged(self) -> bool:
        return self.status == CONVERGED

    def to_dict(self) -> dict:
        return {
            "status": self.status,
            "iterations": self.iterations,
            "a": self.a,
            "eps": self.eps,
            "f_start": self.f_start,
            "f_end": self.f_end,
            "grad_norm": self.grad_norm,
            "grad_norm_blocks": dict(self.grad_norm_blocks),
        }


@problem("zhou2010.value_and_gradient", examples=[("none",), ("constant",), ("series",)])
def _value_and_gradient(kind: str) -> ca.Function:
    """f and grad f of `objective_function(kind)` without its Hessian (cheaper per step).

    kind : the reference mode of the moments, "none", "constant" or "series".
    """
    return objective_function(kind).slice(f"fg_{kind}", [0, 1], [0, 1])


class _Objective:
    """f, grad f and the Hessian over one block, for fixed data."""

    def __init__(self, moments):
        self.kind = moments.reference
        self.p = ca.DM(pack(moments, np.zeros(9), np.ones(9), 1.0))
        self.fg = _value_and_gradient(self.kind)
        self.full = objective_function(self.kind)

    def __call__(self, theta):
        f, g = self.fg(ca.DM(theta), self.p)
        return float(f), np.asarray(g, dtype=float).ravel()

    def hessian(self, theta) -> np.ndarray:
        return np.asarray(self.full(ca.DM(theta), self.p)[2], dtype=float)


def _gauge_projector(free, kind: str) -> np.ndarray:
    """Projector on the free coordinates that removes the common-scale direction (Eq. 8 only)."""
    free = list(free)
    projector = np.eye(len(free))
    scales = [k for k, i in enumerate(free) if i in SCALE_INDICES]
    if kind == "none" and len(scales) == 3:
        ones = np.zeros(len(free))
        ones[scales] = 1.0 / np.sqrt(3.0)
        projector -= np.outer(ones, ones)
    return projector


def _block_norms(gradient: np.ndarray, kind: str) -> dict:
    """|grad f| over each block in internal units (the scale block on the gauge for Eq. 8)."""
    norms = {}
    for name in STAGE_ORDER:
        part = gradient[list(BLOCKS[name])]
        if kind == "none" and name == "scale":
            part = part - part.mean()
        norms[name] = float(np.linalg.norm(part))
    return norms


def conjugate_gradient(
    moments,
    block: str,
    theta,
    options: CGOptions = CGOptions(),
    *,
    eps: float | None = None,
    objective: _Objective | None = None,
):
    """Minimise f over one block of theta by the CG of section 5 in [1], the rest held fixed.

    moments : `nlpcal.moments.Moments` of the log.
    block : "orthogonal", "scale", "offset" or "joint".
    theta : start, internal units (z [field], s [1], angles [rad]).
    eps : the gradient-norm threshold (iteration variables); None: rel_eps |grad f(theta)|.
    objective : a prepared `_Objective` of these moments, to save rebuilding it every stage.
    Returns (theta_new, CGOutcome).
    """
    started = time.perf_counter()
    objective = objective or _Objective(moments)
    free = list(BLOCKS[block])
    theta = np.asarray(theta, dtype=float).copy()
    start = theta.copy()
    # iteration variables y = X / D on the free block (D = 1: the paper's unscaled units)
    D = variable_scale(moments.frame.radius)[free] if options.scaled else np.ones(len(free))
    projector = _gauge_projector(free, objective.kind)

    def evaluate(x):
        f, g = objective(x)
        return f, g, projector @ (D * g[free])

    f, g_full, g = evaluate(theta)
    f_start = f
    a = options.step_factor / _largest_curvature(objective, theta, free, D, projector)
    g_norm = float(np.linalg.norm(g))
    eps = options.rel_eps * g_norm if eps is None else float(eps)
    history = [f]
    status = MAX_ITERATIONS
    iterations = 0
    if g_norm <= eps:
        status = CONVERGED
    else:
        S = -g  # step (2)
        for k in range(int(options.max_iter)):
            p_k = a / (k + 1)  # step (3)
            trial = theta.copy()
            trial[free] += D * (p_k * S)  # step (4)
            f_new, g_full_new, g_new = evaluate(trial)
            if (
                not np.isfinite(f_new)
                or not np.all(np.isfinite(g_new))
                or abs(f_new) > DIVERGENCE_FACTOR * max(abs(f_start), 1e-300)
            ):
                status = DIVERGED  # give back the start of this solve
                iterations = k + 1
                history.append(f_new)
                theta = start
                f, g_full, g = evaluate(start)
                g_norm = float(np.linalg.norm(g))
                break
            iterations = k + 1
            theta, f, g_full = trial, f_new, g_full_new
            history.append(f)
            g_new_norm = float(np.linalg.norm(g_new))
            if g_new_norm <= eps:  # step (5)
                g, g_norm = g_new, g_new_norm
                status = CONVERGED
                break
            v_k = g_new_norm**2 / g_norm**2  # step (6), Fletcher-Reeves
            S = -g_new + v_k * S
            g, g_norm = g_new, g_new_norm
    return theta, CGOutcome(
        status=status,
        iterations=iterations,
        a=float(a),
        eps=float(eps),
        f_start=float(f_start),
        f_end=float(f),
        grad_norm=float(g_norm),
        grad_norm_blocks=_block_norms(g_full, objective.kind),
        history=history,
        wall_s=time.perf_counter() - started,
    )


def _largest_curvature(objective, theta, free: list, D, projector) -> float:
    """The largest eigenvalue of the Hessian of f in the iteration variables of the free block
    at theta (the step constant a is step_factor over it); 1 at a flat or concave start."""
    hess = objective.hessian(theta)[np.ix_(free, free)]
    hess = projector @ (D[:, None] * hess * D[None, :]) @ projector
    lam_max = float(np.linalg.eigvalsh(0.5 * (hess + hess.T))[-1])
    if not (lam_max > 0 and np.isfinite(lam_max)):
        lam_max = 1.0  # flat or concave start: no curvature to set a by; unit step constant
    return lam_max


def run_cg_joint(problem, start, options: CGOptions = CGOptions(), label: str = "cg joint"):
    """All nine parameters at once by the CG of section 5 in [1].

    problem : a `nlpcal.calibration.problem.Problem`; start : X_0 (internal units).
    Returns (theta, row, outcome): the Table 1 row carries the iterations, the wall time, the
    status ("converged", "max_iterations", "diverged") and the constants a and eps.
    """
    objective = _Objective(problem.moments)
    theta, outcome = conjugate_gradient(
        problem.moments, "joint", start, options, objective=objective
    )
    row = problem.row(label, theta, iterations=outcome.iterations, wall_s=outcome.wall_s)
    row.update(variant="scaled" if options.scaled else "unscaled", **outcome.to_dict())
    row["iterations"] = int(outcome.iterations)
    return theta, row, outcome


def run_cg_staged(problem, max_cycles: int, options: CGOptions = CGOptions(), rtol: float = 1e-9):
    """The cycle of Fig. 1 in [1] with every stage solved by the CG of section 5.

    Same stages, order, start (every block at zero) and stop rule (a cycle that lowers the Eq. 8
    objective by less than rtol of its value ends the run) as
    `nlpcal.calibration.staged.run_staged`.
    Returns (theta, rows, stages): the measured row then one row per cycle (iterations summed over
    its three stages; status "converged" only when all three converged), and every stage outcome.
    """
    objective = _Objective(problem.moments)
    theta = np.zeros(9)
    rows = [problem.measured_row()]
    stages = []
    eps: dict[str, float] = {}  # per block, set at its first solve (step (1) of section 5)
    previous = rows[0]["objective"]
    for cycle in range(1, int(max_cycles) + 1):
        started = time.perf_counter()
        outcomes = []
        for stage in STAGE_ORDER:
            theta, outcome = conjugate_gradient(
                problem.moments, stage, theta, options, eps=eps.get(stage), objective=objective
            )
            eps.setdefault(stage, outcome.eps)
            outcomes.append(outcome)
            stages.append(
                {
                    "cycle": cycle,
                    "stage": stage,
                    **outcome.to_dict(),
                    "history": list(outcome.history),
                }
            )
        row = problem.row(
            f"cg cycle {cycle}",
            theta,
            iterations=sum(o.iterations for o in outcomes),
            wall_s=time.perf_counter() - started,
        )
        statuses = [o.status for o in outcomes]
        row["status"] = next((s for s in (DIVERGED, MAX_ITERATIONS) if s in statuses), CONVERGED)
        row["converged"] = row["status"] == CONVERGED
        row["stage_status"] = dict(zip(STAGE_ORDER, statuses))
        rows.append(row)
        if previous - row["objective"] <= rtol * previous:
            break
        previous = row["objective"]
    return theta, rows, stages
