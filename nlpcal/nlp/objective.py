"""The objective of Eq. 8 in [1] and its reference variants, as CasADi expressions of the moments.

Three objectives, all means over the N samples (F_i the reference value of sample i):

    none      f = (1/N) sum_i (|B1_i| - mean_j |B1_j|)^2                 Eq. 8 in [1]
    constant  f = (1/N) sum_i (|B1_i| - F)^2            F a scalar reference (proton, IGRF)
    series    f = (1/N) sum_i (|B1_i| - F_i)^2          F_i a reference sampled with the log

With u_i = |B1_i|^2 / F_i^2 - 1 (see `nlpcal.moments`) and sqrt(1 + u) = sum_k c_k u^k,
c = (1, 1/2, -1/8, 1/16, -5/128, ...), the reference objectives are

    f = L^2 sum_{k>=2} (-2 c_k) m_k,         m_k = (1/N) sum_i w_i u_i^k

so the O(1) parts cancel in the algebra, not in floating point. For Eq. 8, u is centred on its
mean mu = m_1 (central moments k_j of u), and with S = sum_{j>=2} c_j k_j / (1 + mu)^j

    f = -L^2 (1 + mu) (2 S + S^2)

The series is cut after u^4: the relative error of f is of the order of max|u|^3 (about 3e-10
for a 16 nT spread in 49 500 nT, the residual of Table 1 in [1]); `nlpcal.statistics` evaluates the
exact per-sample objective at every reported row, so the cut is checked on every run.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import casadi as ca

from .. import moments as mom
from ..models.zhou2010 import correction_matrix_entries
from .solver import problem

#: Coefficients c_k of sqrt(1 + u) = sum_k c_k u^k, k = 0..4.
SQRT_SERIES = (1.0, 0.5, -0.125, 0.0625, -0.0390625)


def correction_matrix_sx(theta):
    """M = O_p S_p (Eq. 4 in [1]) as a CasADi matrix.

    theta : z [field unit], s [1], angles [rad].
    """
    entries = correction_matrix_entries(
        theta[6], theta[7], theta[8], theta[3], theta[4], theta[5], cos=ca.cos, sin=ca.sin
    )
    return ca.blockcat([[ca.SX(v) if isinstance(v, float) else v for v in row] for row in entries])


def u_coefficients(theta, centre, length):
    """e(theta), the ten coefficients of u = a + e . psi' (`nlpcal.moments`).

    |B1|^2 / L^2 = (d - z~)^T A (d - z~) = |d|^2 + e . psi(d) with A = M^T M (Eq. 4 in [1]),
    z~ = (z - centre) / L.
    """
    M = correction_matrix_sx(theta)
    A = M.T @ M
    zt = (theta[0:3] - centre) / length
    Az = A @ zt
    return ca.vertcat(
        A[0, 0] - 1,
        A[1, 1] - 1,
        A[2, 2] - 1,
        2 * A[0, 1],
        2 * A[0, 2],
        2 * A[1, 2],
        -2 * Az,
        ca.dot(zt, Az),
    )


def feature_coefficients(e, layout: mom.Layout):
    """U and P with u = U . f and u^2 = P . f on the distinct features f of the layout."""
    size = layout.size
    U = [ca.SX(0)] * size
    P = [ca.SX(0)] * size
    U[layout.a] += 1
    for k in range(len(layout.psi)):
        U[layout.psi[k]] += e[k]
        P[layout.apsi[k]] += 2 * e[k]  # 2 a (e . psi')
    for (k, l), index in layout.pair.items():
        P[index] += e[k] * e[l] * (1.0 if k == l else 2.0)  # (e . psi')^2
    P[layout.a2] += 1  # a^2
    return ca.vertcat(*U), ca.vertcat(*P)


@problem("zhou2010.coefficients", examples=[(False,), (True,)])
def coefficient_function(varying_gamma: bool) -> ca.Function:
    """(theta [internal units], centre [field], L [field]) -> (U, P), a small SX function.

    The problems call it from MX graphs whose only other operations are the products with the
    Gram matrix, so that building an NLP takes milliseconds.
    """
    theta, centre, length = ca.SX.sym("theta", 9), ca.SX.sym("centre", 3), ca.SX.sym("L")
    U, P = feature_coefficients(u_coefficients(theta, centre, length), mom.layout(varying_gamma))
    return ca.Function("u_coefficients", [theta, centre, length], [U, P])


#: The indices of all nine parameters: derivatives in the whole of theta.
ALL_PARAMETERS = tuple(range(9))


@problem(
    "zhou2010.coefficient_derivatives",
    examples=[(False,), (True,), (False, (6, 7, 8)), (True, (0, 1, 2))],
)
def coefficient_derivative_functions(
    varying_gamma: bool, within: tuple = ALL_PARAMETERS
) -> tuple[ca.Function, ca.Function]:
    """Two small SX functions for the exact derivatives of the objective (`objective_derivatives`)
    in the parameters theta[within] (all nine, or one stage's three):

    (theta, centre, L) -> (U, P, dU/dtheta, dP/dtheta), the coefficients and their Jacobians;
    (theta, centre, L, wU, wP) -> the Hessian in theta of wU . U + wP . P.
    """
    theta, centre, length = ca.SX.sym("theta", 9), ca.SX.sym("centre", 3), ca.SX.sym("L")
    U, P = feature_coefficients(u_coefficients(theta, centre, length), mom.layout(varying_gamma))
    free = theta[list(within)]
    jacobians = ca.Function(
        "u_jacobians",
        [theta, centre, length],
        [U, P, ca.densify(ca.jacobian(U, free)), ca.densify(ca.jacobian(P, free))],
    )
    wU, wP = ca.SX.sym("wU", U.numel()), ca.SX.sym("wP", P.numel())
    curvature = ca.Function(
        "u_curvature",
        [theta, centre, length, wU, wP],
        [ca.densify(ca.hessian(ca.dot(wU, U) + ca.dot(wP, P), free)[0])],
    )
    return jacobians, curvature


def power_moments(U, P, gram, layout: mom.Layout):
    """m_1..m_4, the weighted means of u^k, from U, P and the Gram matrix (exact polynomials).

    m_1 = U . G_1, m_2 = P . G_1, m_3 = P^T G U and m_4 = P^T G P (G_1: the column of f = 1).
    """
    first = gram[:, layout.one]
    GP = ca.mtimes(gram, P)
    return ca.dot(U, first), ca.dot(P, first), ca.dot(GP, U), ca.dot(GP, P)


def reference_objective(m, length):
    """mean (|B1_i| - F_i)^2 from the power moments of u. [field^2]"""
    _, m2, m3, m4 = m
    c = SQRT_SERIES
    return length**2 * (-2.0) * (c[2] * m2 + c[3] * m3 + c[4] * m4)


def centred_expansion(m):
    """sqrt(1 + u) about the mean mu of u, from the power moments m_1..m_4 of u.

    sqrt(1 + u) = sqrt(1 + mu) sum_j c_j v^j with v = (u - mu) / (1 + mu), so with the central
    moments k_j of u and S = sum_{j>=2} c_j k_j / (1 + mu)^j (the term j = 1 has mean zero)

        mean sqrt(1 + u) = sqrt(1 + mu) (1 + S),   mean (1 + u) = 1 + mu.

    Returns (1 + mu, S, rho) with rho = sqrt(k_2) / (1 + mu), the spread of v: the series cut
    after v^4 holds while rho is small (its error is of the order of rho^5). [1]
    """
    mu, m2, m3, m4 = m
    k2 = m2 - mu**2  # central moments of u
    k3 = m3 - 3 * mu * m2 + 2 * mu**3
    k4 = m4 - 4 * mu * m3 + 6 * mu**2 * m2 - 3 * mu**4
    c = SQRT_SERIES
    one = 1 + mu
    S = c[2] * k2 / one**2 + c[3] * k3 / one**3 + c[4] * k4 / one**4
    return one, S, ca.sqrt(ca.fmax(k2, 0.0)) / one


def magnitude_summary(m, length):
    """Mean and variance of |B1| = L sqrt(1 + u) with uniform weights (the mean and the squared
    std of a Table 1 row in [1]) and the spread rho of the expansion, from the power moments of
    u (`centred_expansion`): the variance is L^2 (1 + mu) - mean^2 = -L^2 (1 + mu) (2 S + S^2).
    [field unit], [field^2], [1]"""
    one, S, spread = centred_expansion(m)
    return length * ca.sqrt(one) * (1 + S), -(length**2) * one * (2 * S + S**2), spread


def spread_objective(m, length):
    """Eq. 8 in [1], the variance of |B1|, from the power moments of u. [field^2]"""
    return magnitude_summary(m, length)[1]


def objective_expression(theta, gram, centre, length, reference: str):
    """f(theta) for reference "none" (Eq. 8), "constant" or "series". [field^2]

    Works on SX and on MX symbols (the problems use MX, the Gram entering as a dense matrix).
    """
    layout = mom.layout(reference == "series")
    U, P = coefficient_function(layout.varying_gamma)(theta, centre, length)
    m = ca.vertcat(*power_moments(U, P, gram, layout))
    return moment_objective_function(moment_kind(reference))(m, length)


def moment_kind(reference: str) -> str:
    """The form of the objective in the power moments: "none" (Eq. 8) or "constant" (a reference
    series has the constant's form, its weights being in the moments)."""
    return "none" if reference == "none" else "constant"


@problem(
    "zhou2010.moment_objective",
    examples=[(kind, d) for kind in ("none", "constant") for d in (False, True)],
)
def moment_objective_function(kind: str, derivatives: bool = False) -> ca.Function:
    """(m_1..m_4, L) -> f [field^2], and with `derivatives` df/dm and d2f/dm2: the objective as a
    function of the power moments of u (Eq. 8 in [1] for kind "none", the reference objective
    for "constant"). A small SX function: the MX problems that call it stay a few nodes, which
    CasADi builds in milliseconds and differentiates cheaply (its scalar algebra written out in
    MX took 20-30 ms to build per problem and a third of IPOPT's Hessian evaluations)."""
    m, length = ca.SX.sym("m", 4), ca.SX.sym("L")
    moments = (m[0], m[1], m[2], m[3])
    f = (
        spread_objective(moments, length)
        if kind == "none"
        else reference_objective(moments, length)
    )
    if not derivatives:
        return ca.Function("f_of_moments", [m, length], [f])
    hess, grad = ca.hessian(f, m)
    return ca.Function("f_of_moments_derivatives", [m, length], [f, grad, ca.densify(hess)])


@problem("zhou2010.moment_summary")
def moment_summary_function() -> ca.Function:
    """(m_1..m_4, L) -> (mean [field unit], variance [field^2], rho [1]) of |B1| with uniform
    weights (`magnitude_summary`), a small SX function like `moment_objective_function`."""
    m, length = ca.SX.sym("m", 4), ca.SX.sym("L")
    mean, variance, spread = magnitude_summary((m[0], m[1], m[2], m[3]), length)
    return ca.Function("summary_of_moments", [m, length], [mean, variance, spread])


def objective_derivatives(
    theta, gram, centre, length, reference: str, within: tuple = ALL_PARAMETERS
):
    """(f, grad f, Hessian of f) in theta[within] [field^2 per internal unit^k], in closed form:
    in all nine parameters, or in one stage's (the Jacobians and the products below then have a
    third of the columns).

    With D the 9 x 4 Jacobian of the power moments m = (U.G_1, P.G_1, P^T G U, P^T G P) and
    the derivatives f_k, f_kl of f in m (`moment_objective_function`), the chain rule gives

        grad f = D f_m
        H f    = D f_mm D^T + f_3 (J_P^T G J_U + J_U^T G J_P) + 2 f_4 J_P^T G J_P
                 + Hessian of (wU . U + wP . P),  wU = f_1 G_1 + f_3 G P,
                                                  wP = f_2 G_1 + f_3 G U + 2 f_4 G P

    (J_U, J_P the Jacobians of U and P in theta, G symmetric): a handful of products with the
    Gram matrix: 77 operations where automatic differentiation of `objective_expression` took
    2 070, three to four times the time on every Newton check.
    """
    layout = mom.layout(reference == "series")
    jacobians, curvature = coefficient_derivative_functions(layout.varying_gamma, within)
    U, P, JU, JP = jacobians(theta, centre, length)
    first = gram[:, layout.one]
    GU, GP, GJP = ca.mtimes(gram, U), ca.mtimes(gram, P), ca.mtimes(gram, JP)
    m = ca.vertcat(ca.dot(U, first), ca.dot(P, first), ca.dot(GP, U), ca.dot(GP, P))
    f, fm, fmm = moment_objective_function(moment_kind(reference), True)(m, length)
    D = ca.horzcat(
        ca.mtimes(JU.T, first),
        ca.mtimes(JP.T, first),
        ca.mtimes(JP.T, GU) + ca.mtimes(JU.T, GP),
        2 * ca.mtimes(JP.T, GP),
    )
    cross = ca.mtimes(JU.T, GJP)
    weights_u = fm[0] * first + fm[2] * GP
    weights_p = fm[1] * first + fm[2] * GU + 2 * fm[3] * GP
    hess = (
        ca.mtimes([D, fmm, D.T])
        + fm[2] * (cross + cross.T)
        + 2 * fm[3] * ca.mtimes(JP.T, GJP)
        + curvature(theta, centre, length, weights_u, weights_p)
    )
    return f, ca.mtimes(D, fm), 0.5 * (hess + hess.T)  # symmetric to the last bit


def magnitude_summary_expression(theta, gram, centre, length, reference: str):
    """(mean, variance, rho) of |B1| from the moments (`magnitude_summary`), for the references
    "none" and "constant" (whose weights are uniform). [field unit], [field^2], [1]"""
    layout = mom.layout(reference == "series")
    U, P = coefficient_function(layout.varying_gamma)(theta, centre, length)
    return moment_summary_function()(ca.vertcat(*power_moments(U, P, gram, layout)), length)
