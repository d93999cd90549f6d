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

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..errors import SolveError
from ..inference import block_rows
from ..models.liu2022 import TEMPERATURE_MODELS
from ..models.zhou2010 import correction_matrix_entries
from .solver import IpoptOptions, build_nlpsol, problem, solve

#: Samples per chunk of the residual function (the last chunk is padded with zero weights).
CHUNK = 2048
#: Levenberg-Marquardt: most steps, first damping, and the relative decrease the model must
#: still promise for another step. [1]
MAX_STEPS = 200
FIRST_DAMPING = 1e-3
STEP_RTOL = 1e-13


def n_coefficients(kind: str) -> int:
    """Temperature coefficients of a model: c (common), or sigma and zeta per axis."""
    return 1 if kind == "common" else 6


def magnitude_expression(theta, samples, dt, kind: str):
    """|B1_i(t_i)| as a 1 x W CasADi expression (Eq. 2 and 9 in [1], Eq. 4 in [2]).

    theta : z [field], s [1], angles [rad], then c [1/degC] (common) or sigma [1/degC] and
        zeta [field/degC] (per-axis). samples : 3 x W raw output; dt : 1 x W values t_i - t0.
    """
    width = samples.shape[1]
    entries = correction_matrix_entries(
        theta[6], theta[7], theta[8], 0.0, 0.0, 0.0, cos=ca.cos, sin=ca.sin
    )  # T^-1 of Eq. 4 in [2]
    t_inv = ca.blockcat([[ca.MX(v) if isinstance(v, float) else v for v in row] for row in entries])
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
    return ca.Function(
        f"nlpcal_temperature_residuals_{kind.replace('-', '_')}",
        [theta, samples, dt, reference],
        [r, ca.jacobian(r, theta)],
        ["theta", "B", "dt", "F"],
        ["r", "J"],
    )


#: IPOPT's settings of every Gauss-Newton step (recorded in the result's solver report).
STEP_OPTIONS = IpoptOptions()


@problem("liu2022.step", examples=[(kind,) for kind in TEMPERATURE_MODELS])
def step_solver(kind: str, options: IpoptOptions = STEP_OPTIONS):
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
    return build_nlpsol(
        f"nlpcal_temperature_step_{kind.replace('-', '_')}", d, model / c, p, options=options
    )


@dataclass
class Sums:
    """Gauss-Newton sums of one pass: A = Js^T Js / N, b = Js^T r / N, c = r^T r / N (Js the
    Jacobian in the scaled variables), and the residuals."""

    a: np.ndarray
    b: np.ndarray
    c: float
    residuals: np.ndarray


def gauss_newton_pass(kind: str, theta, scale, samples, dt, reference, blocks=None) -> Sums:
    """One chunked pass over the data with the built residual function (fixed chunk width).

    blocks : None, or a pair of zero arrays (K, nx) and (K, nx, nx) into which the pass adds
    the scores r_i Js_i and the information shares Js_i Js_i^T of blocks of
    `inference.block_rows(N)` consecutive samples (for `inference.dependence_meat`)."""
    function = residual_function(kind)
    n, nx = samples.shape[0], theta.size
    a, b = np.zeros((nx, nx)), np.zeros(nx)
    residuals = np.empty(n)
    rows_per_block = block_rows(n)
    for start in range(0, n, CHUNK):
        stop = min(start + CHUNK, n)
        rows = stop - start
        block = np.zeros((3, CHUNK))
        block[:] = samples[start][:, None]  # padding: a copy of a real sample, weight 0
        block[:, :rows] = samples[start:stop].T
        pad_dt = np.full(CHUNK, dt[start])
        pad_dt[:rows] = dt[start:stop]
        pad_f = np.full(CHUNK, reference[start])
        pad_f[:rows] = reference[start:stop]
        r, jac = function(theta, block, pad_dt[None, :], pad_f[None, :])
        r = np.asarray(r, dtype=float).ravel()[:rows]
        js = np.asarray(jac, dtype=float)[:rows] * scale[None, :]
        residuals[start:stop] = r
        a += js.T @ js
        b += js.T @ r
        if blocks is not None:
            index = np.arange(start, stop) // rows_per_block
            np.add.at(blocks[0], index, js * r[:, None])
            np.add.at(blocks[1], index, js[:, :, None] * js[:, None, :])
    return Sums(a / n, b / n, float(residuals @ residuals) / n, residuals)


def minimise(kind, theta, scale, data):
    """Levenberg-Marquardt from `theta`: each step an IPOPT solve of the Gauss-Newton model.

    Returns (theta, sums at theta, steps taken, IPOPT iterations, last IPOPT status).
    """
    sums = gauss_newton_pass(kind, theta, scale, *data)
    damping = FIRST_DAMPING * float(np.mean(np.diag(sums.a)))
    solver = step_solver(kind)
    steps = iterations = 0
    status = "Solve_Succeeded"
    for _ in range(MAX_STEPS):
        if sums.c == 0.0:
            break
        p = np.concatenate([sums.a.ravel(order="F"), sums.b, [sums.c, damping]])
        outcome = solve(solver, x0=np.zeros(theta.size), p=p)
        iterations += outcome.iterations
        status = outcome.status
        if not outcome.success:
            raise SolveError(
                f"IPOPT did not solve a step of the joint temperature calibration ({kind})",
                outcome.status,
            )
        promised = sums.c * (1.0 - outcome.f)  # f is the model over c
        if promised <= STEP_RTOL * sums.c:
            break
        trial = theta + scale * outcome.x
        new = gauss_newton_pass(kind, trial, scale, *data)
        if new.c < sums.c:
            theta, sums, steps = trial, new, steps + 1
            damping = max(damping / 10.0, 1e-15 * float(np.mean(np.diag(sums.a))))
        else:
            damping *= 10.0
    else:
        raise SolveError(
            f"the joint temperature calibration ({kind}) did not converge in {MAX_STEPS} steps",
            "Maximum_Iterations_Exceeded",
        )
    return theta, sums, steps, iterations, status
