"""The joint NLP of the nine parameters and the stray fields of K auxiliary channels.

The model is (*) of `nlpcal.auxiliary.model`, B1 = O_p S_p (B_M - Z_p - sum_k v_k c_k); the
objective the same Eq. 8 in [1] (or its reference variants, `nlpcal.nlp.objective`) on the
moments of `nlpcal.auxiliary.moments`, whose features add the channels' products. The variables
are scaled to order one as in `nlpcal.nlp.blocks`,

    theta = theta_ref + var_scale * (E x_theta),    v = v_ref + v_scale * x_v,

v_scale being 1e-3 of the field per standard deviation of the channel, and the problem carries
the gauge s_x + s_y + s_z = 0 without a reference field. One `nlpsol` per (reference kind, K,
model), built once and re-solved through its parameters.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..auxiliary.moments import ChannelMoments, channel_layout
from .blocks import OPTIONS, variable_scale, variables
from .objective import (
    correction_matrix_sx,
    feature_coefficients,
    moment_kind,
    moment_objective_function,
    power_moments,
)
from .solver import Evaluation, IpoptOptions, build_nlpsol, problem


def channel_coefficients(theta, v, centre, length, c0, cs, channels: int):
    """e(theta, v): the coefficients of u = a + e . psi' over the products v_p v_q of
    v = (d, c~, 1), p <= q (`nlpcal.auxiliary.moments.pair_exponents`):

        |B1|^2 / L^2 = v^T Q v,  Q = E^T A E,  E = [I, -W, -z~],  A = M^T M   (Eq. 4 in [1], (*))

    with W = V diag(cs) / L and z~ = (Z_p + V c0 - centre) / L; e is Q's upper triangle (off the
    diagonal twice), less |d|^2. theta [internal units], v (3K, column k = v_k) [field per
    channel unit].
    """
    M = correction_matrix_sx(theta)
    A = M.T @ M
    V = ca.reshape(v, 3, channels)
    zt = (theta[0:3] + V @ c0 - centre) / length
    W = V @ ca.diag(cs) / length
    E = ca.horzcat(ca.SX.eye(3), -W, -zt)
    Q = E.T @ A @ E
    size = 4 + channels
    return ca.vertcat(
        *[
            Q[p, q] * (1.0 if p == q else 2.0) - (1.0 if p == q and p < 3 else 0.0)
            for p in range(size)
            for q in range(p, size)
        ]
    )


@dataclass(frozen=True)
class ChannelSymbols:
    theta_ref: ca.MX
    v_ref: ca.MX
    theta_scale: ca.MX
    v_scale: ca.MX
    gram: ca.MX
    centre: ca.MX
    length: ca.MX
    c0: ca.MX
    cs: ca.MX
    f_ref: ca.MX

    @property
    def data(self):
        """The parameter vector, in the order `channel_parameters` fills it."""
        return ca.vertcat(
            self.theta_ref,
            self.v_ref,
            self.theta_scale,
            self.v_scale,
            ca.vec(self.gram),
            self.centre,
            self.length,
            self.c0,
            self.cs,
            self.f_ref,
        )


def _symbols(reference: str, channels: int) -> ChannelSymbols:
    size = channel_layout(reference == "series", channels).size
    k3 = 3 * channels
    return ChannelSymbols(
        ca.MX.sym("theta_ref", 9),
        ca.MX.sym("v_ref", k3),
        ca.MX.sym("theta_scale", 9),
        ca.MX.sym("v_scale", k3),
        ca.MX.sym("G", size, size),
        ca.MX.sym("centre", 3),
        ca.MX.sym("length"),
        ca.MX.sym("c0", channels),
        ca.MX.sym("cs", channels),
        ca.MX.sym("f_ref"),
    )


def v_scale(moments: ChannelMoments) -> np.ndarray:
    """(3K,) typical size of each stray coefficient: 1e-3 of the field per standard deviation of
    its channel. [field unit per channel unit]"""
    return np.repeat(1e-3 * moments.frame.radius / moments.channels.scale, 3)


def channel_parameters(moments: ChannelMoments, theta_ref, v_ref, f_ref: float) -> np.ndarray:
    """The numeric parameter vector (the order of `ChannelSymbols.data`)."""
    return np.concatenate(
        [
            np.asarray(theta_ref, dtype=float),
            np.asarray(v_ref, dtype=float),
            variable_scale(moments.frame.radius),
            v_scale(moments),
            moments.gram.ravel(order="F"),
            moments.frame.centre,
            [moments.length],
            moments.channels.centre,
            moments.channels.scale,
            [f_ref],
        ]
    )


def _objective(reference: str, channels: int, model: str):
    """(x, symbols, f, gauge) of the joint problem: f [field^2] in the scaled variables x."""
    s = _symbols(reference, channels)
    free = variables("joint", reference, model)
    x = ca.MX.sym("x", free.size + 3 * channels)
    theta = s.theta_ref + s.theta_scale * ca.mtimes(ca.DM(free.matrix), x[: free.size])
    v = s.v_ref + s.v_scale * x[free.size :]
    th, vv = ca.SX.sym("theta", 9), ca.SX.sym("v", 3 * channels)
    cen, length = ca.SX.sym("centre", 3), ca.SX.sym("L")
    c0, cs = ca.SX.sym("c0", channels), ca.SX.sym("cs", channels)
    layout = channel_layout(reference == "series", channels)
    U, P = feature_coefficients(channel_coefficients(th, vv, cen, length, c0, cs, channels), layout)
    coefficients = ca.Function("channel_coefficients", [th, vv, cen, length, c0, cs], [U, P])
    U, P = coefficients(theta, v, s.centre, s.length, s.c0, s.cs)
    m = ca.vertcat(*power_moments(U, P, s.gram, layout))
    f = moment_objective_function(moment_kind(reference))(m, s.length)
    gauge = ca.sum1(theta[3:6]) if free.gauge else None
    return x, s, f, gauge


@problem(
    "zhou2010.channels",
    examples=[(r, k) for r in ("none", "constant", "series") for k in (1, 2)],
)
def channel_problem(
    reference: str, channels: int, model: str = "full", options: IpoptOptions = OPTIONS
):
    """The `nlpsol` of the joint problem (the objective divided by f_ref)."""
    x, s, f, gauge = _objective(reference, channels, model)
    name = f"nlpcal_channels_{reference}_{channels}_{model}"
    return build_nlpsol(name, x, f / s.f_ref, s.data, gauge, options)


@problem(
    "zhou2010.channel_derivatives",
    examples=[(r, k) for r in ("none", "constant", "series") for k in (1, 2)],
)
def channel_derivatives(reference: str, channels: int, model: str = "full") -> Evaluation:
    """(x, p) -> (f [field^2], its gradient and Hessian in x): the Newton steps that finish a
    solve and the curvature behind the standard errors."""
    x, s, f, _ = _objective(reference, channels, model)
    hess, grad = ca.hessian(f, x)
    return Evaluation(
        ca.Function(
            f"channels_{reference}_{channels}_{model}",
            [x, s.data],
            [f, grad, ca.densify(hess)],
            ["x", "p"],
            ["f", "grad", "hess"],
        )
    )
