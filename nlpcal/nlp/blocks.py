"""The symbolic NLPs of the nine-parameter calibration, built once per process and re-solved.

One problem per block of parameters (Fig. 1 in [1]): the orthogonal stage (alpha, beta, gamma),
the scale stage (s), the offset stage (z) and the joint solve of all nine. In each, the free
variables x are scaled to order one,

    theta = theta_ref + var_scale * x      (x = 0 at the start)

with theta in internal units (z [field unit], s [1], angles [rad]) and var_scale about 1e-3 of the
field for offsets, 1e-3 for scales and 1e-2 rad for angles, so that the mixed magnitudes the
paper blames for the poor convergence of its joint solve do not reach IPOPT. The objective is
divided by its value at the start (f_ref), so it starts at one whatever the field unit.

Everything that depends on the data enters as parameters: the Gram matrix of the moments, the
frame, the reference scale, theta_ref (which holds the blocks that stay fixed) and f_ref. Each
block's `nlpsol` is built once per process and serves that stage in every cycle, for every log.
The problems are MX graphs: a small SX function maps theta to the coefficients of u and u^2
(`nlpcal.nlp.objective.coefficient_function`), and the Gram matrix enters through two dense matrix
products, so that building a problem takes milliseconds. Solving one block, with the Newton
checks around IPOPT: `nlpcal.nlp.steps`.

Without a reference field, Eq. 8 shrinks as all (1 + s) grow together; the gauge
s_x + s_y + s_z = 0 (an equality constraint in every problem that frees s) removes that direction.

A restricted form of Eq. 4 (`nlpcal.models.zhou2010.MODELS`: offsets alone, or offsets and
scales) is the same problem on fewer variables: a block frees the model's directions that lie
in it (`Variables`), theta = theta_ref + var_scale * (E x), and every parameter the model does
not estimate stays at theta_ref, its identity value zero. One `nlpsol` per (block, reference
kind, model).

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, cached_property

import casadi as ca
import numpy as np

from .. import moments as mom
from ..models.zhou2010 import model_directions
from .objective import (
    magnitude_summary_expression,
    objective_derivatives,
    objective_expression,
)
from .solver import Evaluation, IpoptOptions, build_nlpsol, problem

#: Indices of theta freed by each problem, in the paper's stage order.
BLOCKS = {
    "orthogonal": (6, 7, 8),
    "scale": (3, 4, 5),
    "offset": (0, 1, 2),
    "joint": tuple(range(9)),
}
STAGE_ORDER = ("orthogonal", "scale", "offset")
SCALE_INDICES = (3, 4, 5)

#: Gauge used without a reference field. Recorded in every result.
GAUGE = {
    "name": "mean_scale_zero",
    "constraint": "s_x + s_y + s_z = 0",
    "reason": "Eq. 8 is not invariant to a common factor on (1 + s): without a reference field "
    "the absolute scale is not identifiable; the scale ratios (1 + s_i)/(1 + s_j), "
    "offsets and angles are.",
}


def variable_scale(radius: float) -> np.ndarray:
    """Typical size of each parameter: offsets 1e-3 of the field, scales 1e-3, angles 1e-2 rad."""
    return np.array([1e-3 * radius] * 3 + [1e-3] * 3 + [1e-2] * 3)


#: IPOPT settings of the block problems: a scaled gradient of 1e-6, or two iterations in a row
#: below 1e-4. The objective is scaled by its value where the solve starts, so this tolerance is
#: relative to that value, not to the optimum's: Newton steps with the exact Hessian finish
#: every answer to the resolution of the data (`nlpcal.nlp.steps`), whatever IPOPT stopped at.
#: Tighter settings had IPOPT chase the rounding noise of the moment objective's gradient near
#: the optimum through long line searches (half the iterations of the staged cycle on a 1 nT log).
OPTIONS = IpoptOptions(tol=1e-6, acceptable_tol=1e-4, acceptable_iter=2)


@dataclass(frozen=True)
class Symbols:
    theta_ref: ca.MX
    var_scale: ca.MX
    gram: ca.MX
    centre: ca.MX
    length: ca.MX
    f_ref: ca.MX

    @property
    def data(self):
        """The parameter vector, in the order `pack` fills it."""
        return ca.vertcat(
            self.theta_ref, self.var_scale, ca.vec(self.gram), self.centre, self.length, self.f_ref
        )


def _symbols(reference: str) -> Symbols:
    size = mom.layout(reference == "series").size
    return Symbols(
        theta_ref=ca.MX.sym("theta_ref", 9),
        var_scale=ca.MX.sym("var_scale", 9),
        gram=ca.MX.sym("G", size, size),
        centre=ca.MX.sym("centre", 3),
        length=ca.MX.sym("length"),
        f_ref=ca.MX.sym("f_ref"),
    )


def moment_parameters(moments: mom.Moments) -> np.ndarray:
    """The data part of every moment problem's parameters: vec(G), the frame centre and L."""
    return np.concatenate([moments.gram.ravel(order="F"), moments.frame.centre, [moments.length]])


def pack(moments: mom.Moments, theta_ref, var_scale, f_ref: float) -> np.ndarray:
    """Numeric parameter vector for the problems (same order as Symbols.data)."""
    return np.concatenate(
        [
            np.asarray(theta_ref, dtype=float),
            np.asarray(var_scale, dtype=float),
            moment_parameters(moments),
            [f_ref],
        ]
    )


@problem("zhou2010.objective", examples=[("none",), ("constant",), ("series",)])
def objective_function(reference: str) -> ca.Function:
    """f(theta, p) [field^2] and its gradient and Hessian in theta, for checks and uncertainty.

    reference : "none", "constant" or "series" (`Moments.reference`).
    """
    s = _symbols(reference)
    theta = ca.MX.sym("theta", 9)
    f, grad, hess = objective_derivatives(theta, s.gram, s.centre, s.length, reference)
    return ca.Function(
        f"f_{reference}", [theta, s.data], [f, grad, hess], ["theta", "p"], ["f", "grad", "hess"]
    )


@problem(
    "zhou2010.block_objective",
    examples=[(r, b) for r in ("none", "constant", "series") for b in STAGE_ORDER],
)
def block_objective_function(reference: str, block: str) -> ca.Function:
    """f(theta, p) [field^2] and its gradient and Hessian in the parameters of one block
    (`BLOCKS`: a stage's three, or all nine for "joint"), for the Newton checks of a stage: the
    entries of `objective_function`'s gradient and Hessian in those parameters, from a graph a
    third to a half the size."""
    if block == "joint":
        return objective_function(reference)
    s = _symbols(reference)
    theta = ca.MX.sym("theta", 9)
    f, grad, hess = objective_derivatives(
        theta, s.gram, s.centre, s.length, reference, BLOCKS[block]
    )
    return ca.Function(
        f"f_{reference}_{block}",
        [theta, s.data],
        [f, grad, hess],
        ["theta", "p"],
        ["f", "grad", "hess"],
    )


@problem("zhou2010.summary", examples=[("none",), ("constant",)])
def summary_function(reference: str) -> ca.Function:
    """(theta, p) -> (f [field^2], mean [field unit] and variance [field^2] of |B1|, the spread
    rho of the expansion [1]) from the moments: the Table 1 row of a cycle (Fig. 1 and Table 1
    in [1]) without a pass over the data, valid while rho is small (`nlp.objective`)."""
    s = _symbols(reference)
    theta = ca.MX.sym("theta", 9)
    f = objective_expression(theta, s.gram, s.centre, s.length, reference)
    mean, variance, spread = magnitude_summary_expression(
        theta, s.gram, s.centre, s.length, reference
    )
    return ca.Function(
        f"summary_{reference}",
        [theta, s.data],
        [f, mean, variance, spread],
        ["theta", "p"],
        ["f", "mean", "variance", "rho"],
    )


@problem("zhou2010.value", examples=[("none",), ("constant",), ("series",)])
def value_function(reference: str) -> ca.Function:
    """f(theta, p) [field^2] alone: where a Newton step lands, is the objective lower?"""
    s = _symbols(reference)
    theta = ca.MX.sym("theta", 9)
    f = objective_expression(theta, s.gram, s.centre, s.length, reference)
    return ca.Function(f"value_{reference}", [theta, s.data], [f], ["theta", "p"], ["f"])


@dataclass(frozen=True, eq=False)
class Variables:
    """The scaled variables x of one problem: theta = theta_ref + var_scale * (E x).

    The columns of E are the directions of theta the model frees (`model_directions`) that lie
    within the block's parameters: unit vectors, or the common scale s_x = s_y = s_z of the
    "offset" model with a reference. Built once per (block, reference kind, model).
    """

    block: str
    reference: str
    model: str
    matrix: np.ndarray  # E, (9, k)

    @property
    def size(self) -> int:
        return self.matrix.shape[1]

    @cached_property
    def gauge(self) -> bool:
        """Whether the problem carries the gauge s_x + s_y + s_z = 0 (no reference, and the block
        frees a scale)."""
        return self.reference == "none" and bool(np.any(self.matrix[SCALE_INDICES, :]))

    @cached_property
    def gauge_basis(self) -> np.ndarray:
        """(k, k - 1) orthonormal basis of the x the gauge leaves free (`null_of_gauge`)."""
        return _read_only(null_of_gauge(self.matrix))

    def theta(self, theta_ref, x, var_scale) -> np.ndarray:
        """theta_ref + var_scale * (E x). [internal units]"""
        return np.asarray(theta_ref, dtype=float) + var_scale * (self.matrix @ np.asarray(x))

    def project(self, theta) -> np.ndarray:
        """The nearest theta the model allows: zero along the directions it fixes, tied
        parameters at their mean. [internal units]"""
        theta = np.asarray(theta, dtype=float)
        if self.kept is not None:  # the least-squares projection is exactly this selection
            return np.where(self.kept, theta, 0.0)
        e = self.matrix
        return e @ np.linalg.lstsq(e, theta, rcond=None)[0]

    @cached_property
    def kept(self) -> np.ndarray | None:
        """(9,) which parameters the model frees when each direction frees one parameter (no
        tied ones), else None."""
        e = self.matrix
        if not (np.all((e == 0.0) | (e == 1.0)) and np.all(e.sum(axis=0) == 1.0)):
            return None
        return _read_only(e.sum(axis=1) > 0)

    @cached_property
    def basis(self) -> np.ndarray:
        """(9, q) orthonormal directions of the scaled theta this problem can move along (the
        gauge's null space without a reference): where its uncertainty lives."""
        directions = self.matrix @ self.gauge_basis if self.gauge else self.matrix
        return _read_only(np.linalg.qr(directions)[0] if directions.size else directions)


def _read_only(array: np.ndarray) -> np.ndarray:
    """A copy that cannot be changed: a cached property of a `Variables` shared by every solve."""
    array = np.array(array)
    array.flags.writeable = False
    return array


@cache
def variables(block: str, reference: str, model: str = "full") -> Variables:
    """The `Variables` of a block (stage or joint) of a model, for a kind of reference."""
    directions = model_directions(model, reference != "none")
    inside = np.array([i in BLOCKS[block] for i in range(9)])
    keep = [k for k in range(directions.shape[1]) if not np.any(directions[~inside, k])]
    return Variables(block, reference, model, _read_only(directions[:, keep]))


@dataclass(frozen=True)
class BlockProblem:
    """One block's `nlpsol`."""

    block: str
    solver: ca.Function
    has_gauge: bool


@problem(
    "zhou2010.block",
    examples=[(b, r) for b in BLOCKS for r in ("none", "constant", "series")]
    + [("joint", r, m) for m in ("offset", "diagonal") for r in ("none", "constant")]
    + [("scale", "constant", "offset")],
)
def block_problem(block: str, reference: str, model: str = "full", options: IpoptOptions = OPTIONS):
    """The problem of one block (stage or joint) of a model for one kind of reference.

    Built on first use and cached for the life of the process.
    """
    s = _symbols(reference)
    free = variables(block, reference, model)
    x = ca.MX.sym("x", free.size)
    theta = s.theta_ref + s.var_scale * ca.mtimes(ca.DM(free.matrix), x)
    f = objective_expression(theta, s.gram, s.centre, s.length, reference)
    g = ca.sum1(theta[3:6]) if free.gauge else None
    name = f"nlpcal_{block}_{reference}_{model}"
    solver = build_nlpsol(name, x, f / s.f_ref, s.data, g, options)
    return BlockProblem(block, solver, free.gauge)


def parameter_values(moments: mom.Moments) -> np.ndarray:
    """The problems' parameter vector for these moments (`pack`, theta_ref = 0, f_ref = 1), built
    once per moments: what the functions of theta (`evaluate`) read."""
    if "p" not in moments.cache:
        values = pack(moments, np.zeros(9), variable_scale(moments.frame.radius), 1.0)
        values.flags.writeable = False
        moments.cache["p"] = values
    return moments.cache["p"]


def evaluate(builder, moments: mom.Moments, theta, *args) -> tuple:
    """`builder(moments.reference, *args)` (`objective_function`, `block_objective_function`,
    `value_function`, `summary_function`) at theta on these moments, evaluated in place
    (`Evaluation`): its results as numbers, the arrays read-only. The latest result of each
    builder (and arguments) is kept: a check at the point last checked is not evaluated again."""
    theta = np.asarray(theta, dtype=float)
    key = ("latest", builder.__name__, *args)
    latest = moments.cache.get(key)
    if latest is not None and latest[0] == theta.tobytes():  # the same numbers, bit for bit
        return latest[1]
    results = _evaluation(builder, moments.reference, *args)(theta, parameter_values(moments))
    for value in results:
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    moments.cache[key] = (theta.tobytes(), results)
    return results


@cache
def _evaluation(builder, reference: str, *args) -> Evaluation:
    return Evaluation(builder(reference, *args))


def null_of_gauge(directions) -> np.ndarray:
    """Orthonormal basis of the x, in variables theta = var_scale * (E x) with E = `directions`
    (9, k), that the gauge s_x + s_y + s_z = 0 leaves free (every scale has the same variable
    scale, so the gauge's normal in x is the column sums of E's scale rows)."""
    normal = np.asarray(directions, dtype=float)[list(SCALE_INDICES), :].sum(axis=0)
    return np.linalg.svd(normal[None, :])[2][1:].T


def gauge_basis(free) -> np.ndarray:
    """Orthonormal basis of the scaled variables of the parameters `free` (indices into theta)
    that the gauge s_x + s_y + s_z = 0 leaves free."""
    return null_of_gauge(np.eye(9)[:, list(free)])
