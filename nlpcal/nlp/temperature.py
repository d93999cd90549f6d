"""The joint temperature calibration as a Gauss-Newton sequence of fixed-size IPOPT problems.

The objective is the reference variant of Eq. 8 of Zhou et al. (2010) [2] with a temperature in
every sample (the mean square of the residuals whose RMSE is Eq. 10 of Liu et al. (2022) [1]):

    f(theta) = (1/N) sum_i r_i(theta)^2,    r_i = |B1_i(t_i)| - F_i,
    B1_i = T(t_i)^-1 diag(gain(t_i) g(tau_i))^-1 (B_m,i - z(t_i))            Eq. 2, 9 in [1]

with t_i the temperature, T(t_i) constant but for the full model (angles linear in t), and
g(tau_i) = 1 + d tau_i the drift of the scale factors in time (`nlpcal.models.time_drift`; tau_i
the sample's time in days from the middle of the log; g = 1 without a time drift).

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
from ..models.time_drift import TIME_DRIFTS
from ..models.zhou2010 import correction_matrix_entries, triangular
from .solver import IpoptOptions, build_nlpsol, problem, solve

#: Samples per chunk of the residual function (the last chunk is padded with zero weights).
CHUNK = 2048
#: Levenberg-Marquardt: most steps, first damping, and the relative decrease the model must
#: still promise for another step. [1]
MAX_STEPS = 200
FIRST_DAMPING = 1e-3
STEP_RTOL = 1e-13


#: Temperature coefficients of each model: c (common); sigma and zeta per axis (per-axis); and
#: eta per angle (full).
TEMPERATURE_COEFFICIENTS = {"common": 1, "per-axis": 6, "full": 9}
#: Time-drift coefficients: none, d for all axes, d per axis.
TIME_COEFFICIENTS = {"none": 0, "common": 1, "per-axis": 3}
#: Every (temperature model, time drift) pair, the problems built.
TERMS = [(kind, drift) for kind in TEMPERATURE_MODELS for drift in TIME_DRIFTS]


def n_coefficients(kind: str, time_drift: str = "none") -> int:
    """Coefficients beyond the nine: the temperature model's, then the time drift's."""
    return TEMPERATURE_COEFFICIENTS[kind] + TIME_COEFFICIENTS[time_drift]


def magnitude_expression(theta, samples, dt, kind: str, days=None, time_drift: str = "none"):
    """|B1_i(t_i)| as a 1 x W CasADi expression (Eq. 2 and 9 in [1], Eq. 4 in [2]).

    theta : z [field], s [1], angles [rad], then c [1/degC] (common) or sigma [1/degC] and
        zeta [field/degC] (per-axis; and eta [rad/degC], full), then d [1/d] (time drift).
    samples : 3 x W raw output; dt : 1 x W values t_i - t0 [degC]; days : 1 x W times tau_i
        from the log's middle [d].
    """
    width = samples.shape[1]
    z, s = theta[0:3], theta[3:6]
    angles = [theta[6], theta[7], theta[8]]
    if kind == "common":
        k = 1 + theta[9] * dt  # Eq. 9: k(t) = 1 + c (t - t0)
        gains = ca.repmat(1 + s, 1, width) * ca.repmat(k, 3, 1)  # Eq. 9: alpha = k alpha_0
        offsets = z @ k  # Eq. 9: B_b = k B_b0
    else:
        gains = ca.repmat(1 + s, 1, width) * (1 + theta[9:12] @ dt)
        offsets = ca.repmat(z, 1, width) + theta[12:15] @ dt
    if kind == "full":
        angles = [angle + theta[15 + k] * dt for k, angle in enumerate(angles)]
    first = 9 + TEMPERATURE_COEFFICIENTS[kind]
    if time_drift == "common":
        gains = gains * ca.repmat(1 + theta[first] * days, 3, 1)
    elif time_drift == "per-axis":
        gains = gains * (1 + theta[first : first + 3] @ days)
    alpha, beta, gamma = angles
    entries = correction_matrix_entries(alpha, beta, gamma, 0.0, 0.0, 0.0, cos=ca.cos, sin=ca.sin)
    along = (samples - offsets) / gains
    corrected = triangular(entries, along[0, :], along[1, :], along[2, :])  # T^-1 of Eq. 4 [2]
    return ca.sqrt(sum(row * row for row in corrected))


@problem("liu2022.residuals", examples=TERMS)
def residual_function(kind: str, time_drift: str = "none") -> ca.Function:
    """(theta, B [3 x CHUNK], dt, days, F [1 x CHUNK]) -> (r [CHUNK x 1], dr/dtheta)."""
    nx = 9 + n_coefficients(kind, time_drift)
    theta = ca.MX.sym("theta", nx)
    samples = ca.MX.sym("B", 3, CHUNK)
    dt = ca.MX.sym("dt", 1, CHUNK)
    days = ca.MX.sym("days", 1, CHUNK)
    reference = ca.MX.sym("F", 1, CHUNK)
    magnitude = magnitude_expression(theta, samples, dt, kind, days, time_drift)
    r = (magnitude - reference).T  # Eq. 10 residuals
    return ca.Function(
        f"nlpcal_temperature_residuals_{kind.replace('-', '_')}_{time_drift.replace('-', '_')}",
        [theta, samples, dt, days, reference],
        [r, ca.jacobian(r, theta)],
        ["theta", "B", "dt", "days", "F"],
        ["r", "J"],
    )


#: IPOPT's settings of every Gauss-Newton step (recorded in the result's solver report).
STEP_OPTIONS = IpoptOptions()


@problem("liu2022.step", examples=[(9 + n_coefficients(*terms),) for terms in TERMS])
def step_solver(nx: int, options: IpoptOptions = STEP_OPTIONS):
    """min_d (c + 2 b.d + d^T (A + lambda I) d) / c over the scaled step d (Levenberg-Marquardt).

    nx : the variables. p = (vec(A), b, c, lambda): the Gauss-Newton sums of one pass and the
    damping.
    """
    d = ca.SX.sym("d", nx)
    a = ca.SX.sym("A", nx, nx)
    b = ca.SX.sym("b", nx)
    c = ca.SX.sym("c")
    damping = ca.SX.sym("lambda")
    model = c + 2 * ca.dot(b, d) + ca.dot(d, ca.mtimes(a, d)) + damping * ca.dot(d, d)
    p = ca.vertcat(ca.vec(a), b, c, damping)
    return build_nlpsol(f"nlpcal_temperature_step_{nx}", d, model / c, p, options=options)


@dataclass
class Sums:
    """Gauss-Newton sums of one pass: A = Js^T Js / N, b = Js^T r / N, c = r^T r / N (Js the
    Jacobian in the scaled variables), and the residuals."""

    a: np.ndarray
    b: np.ndarray
    c: float
    residuals: np.ndarray


def _padded(values: np.ndarray, start: int, stop: int) -> np.ndarray:
    """Rows start:stop of (N,) values as 1 x CHUNK, padded with copies of the first."""
    out = np.full(CHUNK, values[start])
    out[: stop - start] = values[start:stop]
    return out[None, :]


def gauss_newton_pass(
    kind: str, theta, scale, samples, dt, reference, days=None, time_drift="none", blocks=None
) -> Sums:
    """One chunked pass over the data with the built residual function (fixed chunk width).

    days : the samples' times from the log's middle [d] (a time drift; None: zero).
    blocks : None, or a pair of zero arrays (K, nx) and (K, nx, nx) into which the pass adds
    the scores r_i Js_i and the information shares Js_i Js_i^T of blocks of
    `inference.block_rows(N)` consecutive samples (for `inference.dependence_meat`).
    """
    function = residual_function(kind, time_drift)
    n, nx = samples.shape[0], theta.size
    days = np.zeros(n) if days is None else days
    a, b = np.zeros((nx, nx)), np.zeros(nx)
    residuals = np.empty(n)
    rows_per_block = block_rows(n)
    for start in range(0, n, CHUNK):
        stop = min(start + CHUNK, n)
        rows = stop - start
        block = np.zeros((3, CHUNK))
        block[:] = samples[start][:, None]  # padding: a copy of a real sample, weight 0
        block[:, :rows] = samples[start:stop].T
        r, jac = function(
            theta,
            block,
            _padded(dt, start, stop),
            _padded(days, start, stop),
            _padded(reference, start, stop),
        )
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


def minimise(kind, theta, scale, data, time_drift: str = "none"):
    """Levenberg-Marquardt from `theta`: each step an IPOPT solve of the Gauss-Newton model.

    data : (samples, dt, reference, days) as `gauss_newton_pass` takes them.
    Returns (theta, sums at theta, steps taken, IPOPT iterations, last IPOPT status).
    """

    samples, dt, reference, days = data

    def evaluated(at):
        return gauss_newton_pass(kind, at, scale, samples, dt, reference, days, time_drift)

    sums = evaluated(theta)
    damping = FIRST_DAMPING * float(np.mean(np.diag(sums.a)))
    solver = step_solver(theta.size)
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
        new = evaluated(trial)
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
