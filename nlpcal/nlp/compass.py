"""The NLPs of the e-compass calibration (Qiu et al. 2017), each built once per process.

Problem sizes do not depend on the number of samples: the data enter as moment matrices
accumulated once (sums of outer products), passed as parameters.

References
----------
[1] Qiu et al. (2017), see `nlpcal.models.qiu2017`.
"""

from __future__ import annotations

import casadi as ca

from .solver import build_nlpsol, problem


@problem("qiu2017.compensation")
def compensation_nlp():
    """min_c w(c)^T S w(c), w = (1, -tan c_j, -tan c_l). Eq. 4-8 in [1].

    x = (c_j, c_l), the compensation angles of sensor axis k toward j and l [rad]; p = S, the
    within-turn scatter of the raw outputs over the turns about k, axes ordered (k, j, l) and
    divided by S_jj + S_ll so that the Hessian is of order 1. w^T m is the compensated output along
    k: m_k - tan(c_j) m_j - tan(c_l) m_l (Eq. 4, 5); its within-turn variance is the objective
    (Eq. 6-8: the optimal angles make it constant over the turn).
    """
    x = ca.SX.sym("c", 2)
    p = ca.SX.sym("S", 9)
    S = ca.reshape(p, 3, 3)
    w = ca.vertcat(1, -ca.tan(x[0]), -ca.tan(x[1]))  # Eq. 4, 5: compensated output w^T m
    return build_nlpsol("qiu2017_compensation", x, ca.mtimes([w.T, S, w]), p)  # Eq. 6-8


def axis_ellipsoid_theta(x):
    a, o = x[0:3], x[3:6]
    return ca.vertcat(a, -2 * a * o, ca.sum1(a * o**2) - 1)


@problem("qiu2017.axis_ellipsoid")
def axis_ellipsoid_nlp():
    """Axis-aligned ellipsoid, algebraic residual sum_k a_k (u_k - o_k)^2 - 1 per sample.

    x = (a, o): squared inverse semi-axes and centre of the normalised compensated outputs u;
    p = Phi / N with Phi = sum phi phi^T, phi = (u_x^2, u_y^2, u_z^2, u_x, u_y, u_z, 1), so that
    the objective mean(residual^2) = theta(x)^T (Phi / N) theta(x).
    """
    x = ca.SX.sym("x", 6)
    p = ca.SX.sym("Phi", 49)
    theta = axis_ellipsoid_theta(x)
    f = ca.mtimes([theta.T, ca.reshape(p, 7, 7), theta])
    return build_nlpsol("qiu2017_axis_ellipsoid", x, f, p)


def general_theta(x):
    A = _symmetric(x[0:6])
    o = x[6:9]
    Ao = ca.mtimes(A, o)
    return ca.vertcat(
        x[0], x[1], x[2], 2 * x[3], 2 * x[4], 2 * x[5], -2 * Ao, ca.mtimes(o.T, Ao) - 1
    )


def _symmetric(values):
    a11, a22, a33, a12, a13, a23 = (values[i] for i in range(6))
    return ca.vertcat(
        ca.horzcat(a11, a12, a13), ca.horzcat(a12, a22, a23), ca.horzcat(a13, a23, a33)
    )


@problem("qiu2017.general_ellipsoid")
def general_ellipsoid_nlp():
    """General ellipsoid (u - o)^T A (u - o) = 1, A symmetric positive definite.

    x = (A11, A22, A33, A12, A13, A23, o); p = Phi / N with
    phi = (u_x^2, u_y^2, u_z^2, u_x u_y, u_x u_z, u_y u_z, u_x, u_y, u_z, 1); g = the leading
    principal minors of A, kept positive.
    """
    x = ca.SX.sym("x", 9)
    p = ca.SX.sym("Phi", 100)
    theta = general_theta(x)
    A = _symmetric(x[0:6])
    minors = ca.vertcat(A[0, 0], A[0, 0] * A[1, 1] - A[0, 1] ** 2, ca.det(A))
    return build_nlpsol(
        "qiu2017_general_ellipsoid",
        x,
        ca.mtimes([theta.T, ca.reshape(p, 10, 10), theta]),
        p,
        g=minors,
    )


def _gibbs_rotation(r):
    """Rotation matrix of the Gibbs vector r (angle 2 atan|r| about r), smooth everywhere."""
    rx = ca.vertcat(
        ca.horzcat(0, -r[2], r[1]), ca.horzcat(r[2], 0, -r[0]), ca.horzcat(-r[1], r[0], 0)
    )
    return ca.SX.eye(3) + 2 / (1 + ca.dot(r, r)) * (rx + ca.mtimes(rx, rx))


@problem("qiu2017.dip_alignment")
def dip_alignment_nlp():
    """min mean_i (d_i^T R b_i - c)^2: the dip angle asin(c) is constant (free-rotation mode).

    x = (r, c): Gibbs vector of the rotation R taking the magnetometer's calibrated frame into the
    accelerometer's, and the sine of the dip; p = Psi / N with Psi = sum psi psi^T,
    psi = (vec(d b^T), 1) (row-major), d the calibrated down direction, b the calibrated field
    direction.
    """
    x = ca.SX.sym("x", 4)
    p = ca.SX.sym("Psi", 100)
    R = _gibbs_rotation(x[0:3])
    theta = ca.vertcat(ca.reshape(R.T, 9, 1), -x[3])  # row-major vec(R)
    return build_nlpsol(
        "qiu2017_dip_alignment", x, ca.mtimes([theta.T, ca.reshape(p, 10, 10), theta]), p
    )
