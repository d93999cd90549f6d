"""The joint temperature calibration as a Gauss-Newton sequence of fixed-size IPOPT problems.

The objective is the reference variant of Eq. 8 of Zhou et al. (2010) [2] with a temperature in
every sample (the mean square of the residuals whose RMSE is Eq. 10 of Liu et al. (2022) [1]):

    f(theta) = (1/N) sum_i r_i(theta)^2,    r_i = |B1_i(t_i)| - F_i,
    B1_i = T^-1 diag(gain(t_i))^-1 (B_m,i - z(t_i))                         Eq. 2, 9 in [1]

A temperature in every sample breaks the moment expansion of `nlpcal.moments` (the parameters
differ from sample to sample), so the problem is solved by Levenberg-Marquardt steps instead: at
theta one chunked pass over the data gathers the Gauss-Newton sums

    A = J^T J / N,   b = J^T r / N,   c = r^T r / N        (J = dr/dx, x the scaled variables)

and IPOPT minimises the model c + 2 b.d + d^T (A + lambda I) d over the step d. The step problem
has the same size for every log (nx^2 + nx + 3 parameters), is built once per model kind, and the
sequence stops where the model promises no further decrease: a stationary point of the exact
objective, the optimum of the per-sample problem. The residuals and their Jacobian are one CasADi
function of a chunk of fixed width, built once and re-evaluated chunk by chunk.

References
----------
[1] Liu et al. (2022), see `nlpcal.models.liu2022`.
[2] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import casadi as ca

from ..models.liu2022 import TEMPERATURE_MODELS
from ..models.zhou2010 import correction_matrix_entries
from .solver import IpoptOptions, build_nlpsol, problem

#: Samples per chunk of the residual function (the last chunk is padded with zero weights).
CHUNK = 2048


def n_coefficients(kind: str) -> int:
    """Temperature coefficients of a model: c (common), or sigma and zeta per axis."""
    return 1 if kind == "common" else 6


def magnitude_expression(theta, samples, dt, kind: str):
    """|B1_i(t_i)| as a 1 x W CasADi expression (Eq. 2 and 9 in [1], Eq. 4 in [2]).

    theta : z [field], s [1], angles [rad], then c [1/degC] (common) or sigma [1/degC] and
        zeta [field/degC] (per-axis). samples : 3 x W raw output; dt : 1 x W values t_i - t0.
    """
    width = samples.shape[1]
    entries = correction_matrix_entries(theta[6], theta[7], theta[8], 0.0, 0.0, 0.0,
                                        cos=ca.cos, sin=ca.sin)  # T^-1 of Eq. 4 in [2]
    t_inv = ca.blockcat([[ca.MX(v) if isinstance(v, float) else v for v in row]
                         for row in entries])
    z, s = theta[0:3], theta[3:6]
    if kind == "common":
        k = 1 + theta[9] * dt  # Eq. 9: k(t) = 1 + c (t - t0)
        gains = ca.repmat(1 + s, 1, width) * ca.repmat(k, 3, 1)  # Eq. 9: alpha = k alpha_0
        offsets = z @ k  # Eq. 9: B_b = k B_b0
    else:
        gains = ca.repmat(1 + s, 1, width) * (1 + theta[9:12] @ dt)
        offsets = ca.repmat(z, 1, width) + theta[12:15] @ dt
    corrected = t_inv @ ((samples - offsets) / gains)
    return ca.sqrt(ca.sum1(corrected * corrected))


@problem("liu2022.residuals", examples=[(kind,) for kind in TEMPERATURE_MODELS])
def residual_function(kind: str) -> ca.Function:
    """(theta, B [3 x CHUNK], dt [1 x CHUNK], F [1 x CHUNK]) -> (r [CHUNK x 1], dr/dtheta)."""
    nx = 9 + n_coefficients(kind)
    theta = ca.MX.sym("theta", nx)
    samples = ca.MX.sym("B", 3, CHUNK)
    dt = ca.MX.sym("dt", 1, CHUNK)
    reference = ca.MX.sym("F", 1, CHUNK)
    r = (magnitude_expression(theta, samples, dt, kind) - reference).T  # Eq. 10 residuals
    return ca.Function(f"nlpcal_temperature_residuals_{kind.replace('-', '_')}",
                       [theta, samples, dt, reference], [r, ca.jacobian(r, theta)],
                       ["theta", "B", "dt", "F"], ["r", "J"])


@problem("liu2022.step", examples=[(kind,) for kind in TEMPERATURE_MODELS])
def step_solver(kind: str, options: IpoptOptions = IpoptOptions()):
    """min_d (c + 2 b.d + d^T (A + lambda I) d) / c over the scaled step d (Levenberg-Marquardt).

    p = (vec(A), b, c, lambda): the Gauss-Newton sums of one pass and the damping.
    """
    nx = 9 + n_coefficients(kind)
    d = ca.SX.sym("d", nx)
    a = ca.SX.sym("A", nx, nx)
    b = ca.SX.sym("b", nx)
    c = ca.SX.sym("c")
    damping = ca.SX.sym("lambda")
    model = c + 2 * ca.dot(b, d) + ca.dot(d, ca.mtimes(a, d)) + damping * ca.dot(d, d)
    p = ca.vertcat(ca.vec(a), b, c, damping)
    return build_nlpsol(f"nlpcal_temperature_step_{kind.replace('-', '_')}", d, model / c, p,
                        options=options)
