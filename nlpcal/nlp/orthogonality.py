"""The NLPs of Wang et al. (2015): the worst-case total-field error and the angle inversion.

Both are built once per process and re-solved with new numbers; neither grows with the number of
samples. The inversion is the orthogonal block of the nine-parameter objective of Zhou et al.
(2010) with unit scales and zero offsets: |T^-1 B'_i|^2 is a quadratic form in the sample, so its
objective (the spread of the corrected total field around its mean, or its distance to a known
field) is a function of the Gram matrix of `nlpcal.moments`, whatever N.

References
----------
[1] Wang et al. (2015), see `nlpcal.models.wang2015`.
[2] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import math

import casadi as ca

from .. import moments as mom
from ..models.zhou2010 import axis_matrix_entries
from .objective import objective_expression
from .solver import IpoptOptions, build_nlpsol, problem


@problem("wang2015.worst_case", examples=[(False,)])
def worst_case_solver(verbose: bool = False):
    """min_{theta, phi} -s (|T u| - 1) / kappa, Eq. 9 in [1].

    x = (theta, phi) [rad]; p = (alpha, beta, gamma [rad], s = +1 or -1, kappa [1]). kappa, the
    size of the analytic bracket, scales the objective to order 1. dB / B does not depend on B,
    so B is applied afterwards.
    """
    x = ca.SX.sym("x", 2)
    p = ca.SX.sym("p", 5)
    theta, phi = x[0], x[1]
    alpha, beta, gamma, sign, kappa = (p[i] for i in range(5))
    u = ca.vertcat(ca.cos(phi) * ca.cos(theta), ca.cos(phi) * ca.sin(theta), ca.sin(phi))  # Eq. 5
    t = ca.vertcat(
        *[
            ca.horzcat(*row)
            for row in axis_matrix_entries(alpha, beta, gamma, cos=ca.cos, sin=ca.sin)
        ]
    )  # Eq. 2
    relative_error = ca.sqrt(ca.sumsqr(ca.mtimes(t, u))) - 1.0  # Eq. 8 / B
    objective = -sign * relative_error / kappa  # Eq. 9
    options = IpoptOptions(
        tol=1e-10, acceptable_tol=1e-8, max_iter=100, print_level=5 if verbose else 0
    )
    return build_nlpsol("nlpcal_orthogonality_worst_case", x, objective, p, options=options)


@problem("wang2015.inversion", examples=[("none", False), ("constant", False)])
def inversion_solver(reference: str, verbose: bool = False):
    """The three angles minimising the spread of |T^-1 B'_i| (reference "none", section 2 of
    [1]) or its distance to a known field ("constant"), from the moments of the samples.

    x = (alpha, beta, gamma) [deg], of order 0.1-1 like the bounds of [1].
    p = (vec(G), centre, L, k): the Gram matrix, frame and length of `nlpcal.moments` and an
    objective scale k (the inverse of the objective at the start, in units of L^2).
    """
    size = mom.layout(False).size
    x = ca.MX.sym("angles_deg", 3)
    gram = ca.MX.sym("G", size, size)
    centre = ca.MX.sym("centre", 3)
    length = ca.MX.sym("L")
    scale = ca.MX.sym("k")
    theta = ca.vertcat(ca.MX.zeros(6), x * (math.pi / 180.0))  # unit scales, zero offsets
    f = objective_expression(theta, gram, centre, length, reference)  # Eq. 8 of [2], H_obj of [1]
    p = ca.vertcat(ca.vec(gram), centre, length, scale)
    # the adaptive barrier update halves the iterations here: the objective is flat at roundoff
    # level near the optimum, where the monotone update stalls in the line search
    options = IpoptOptions(
        tol=1e-10,
        acceptable_tol=1e-8,
        max_iter=200,
        print_level=5 if verbose else 0,
        extra=(("mu_strategy", "adaptive"),),
    )
    return build_nlpsol(
        f"nlpcal_orthogonality_inversion_{reference}", x, scale * f / length**2, p, options=options
    )


@problem("wang2015.inversion_objective", examples=[("none",), ("constant",)])
def inversion_objective(reference: str) -> ca.Function:
    """f(angles [deg], p) [field^2] and its Hessian in the angles [field^2/deg^2]."""
    size = mom.layout(False).size
    x = ca.MX.sym("angles_deg", 3)
    gram = ca.MX.sym("G", size, size)
    centre, length = ca.MX.sym("centre", 3), ca.MX.sym("L")
    theta = ca.vertcat(ca.MX.zeros(6), x * (math.pi / 180.0))
    f = objective_expression(theta, gram, centre, length, reference)
    hess, _ = ca.hessian(f, x)
    return ca.Function(
        f"nlpcal_orthogonality_objective_{reference}",
        [x, ca.vertcat(ca.vec(gram), centre, length)],
        [f, hess],
    )
