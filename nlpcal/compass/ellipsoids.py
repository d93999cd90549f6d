"""Ellipsoid fits of one sensor's readings, each an IPOPT problem of fixed size.

The readings are centred and scaled to order one, and enter the NLPs as the mean of the outer
products of their quadratic features (`nlpcal.nlp.compass`), whatever their number.

References
----------
[1] Qiu et al. (2017), see `nlpcal.models.qiu2017`.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError, SolveError
from ..nlp.compass import axis_ellipsoid_nlp, general_ellipsoid_nlp
from ..nlp.solver import solve


def normalise(u) -> tuple:
    centre = u.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum((u - centre) ** 2, axis=1))))
    if not spread > 0:
        raise InputError("all samples are equal; calibration needs many attitudes")
    return (u - centre) / spread, centre, spread


def _axis_features(z) -> np.ndarray:
    return np.column_stack([z**2, z, np.ones(len(z))])


def fit_axis_ellipsoid(
    u, *, magnitude: float, seed: str = "linear", sensor: str = "sensor"
) -> dict:
    """Axis-aligned ellipsoid v = diag(g) (u - o), |v| = magnitude, as an NLP.

    Parameters
    ----------
    u : (N, 3) array
        Compensated outputs (mounting already removed), any unit.
    magnitude : float
        Length the calibrated vectors are scaled to, in the output unit.
    seed : {"linear", "centroid"}
        Start IPOPT from the linear least-squares fit of the same quadric (falling back to the
        centroid when that fit is not an ellipsoid), or from a sphere around the centroid.

    Returns g (gains, output unit per input unit), o (centre, input unit), the RMS of |v| -
    magnitude (output unit), the seed used and the IPOPT record.
    """
    z, centre, spread = normalise(u)
    phi = _axis_features(z)
    Phi = phi.T @ phi / len(z)
    x0, seed_used = np.r_[np.ones(3), np.zeros(3)], "centroid"
    if seed == "linear":
        q, *_ = np.linalg.lstsq(phi[:, :6], np.ones(len(z)), rcond=None)
        A, B = q[:3], q[3:]
        if np.all(A > 0):
            o = -B / (2 * A)
            G = 1 + np.sum(A * o**2)
            if G > 0:
                x0, seed_used = np.r_[A / G, o], "linear"
    elif seed != "centroid":
        raise InputError(f"unknown ellipsoid seed {seed!r}; expected linear or centroid")
    lbx = np.r_[np.full(3, 1e-6), np.full(3, -np.inf)]
    out = solve(axis_ellipsoid_nlp(), x0=x0, p=Phi.ravel(order="F"), lbx=lbx).checked(
        f"{sensor} ellipsoid fit"
    )
    a, o = out.x[:3], out.x[3:]
    gains = magnitude * np.sqrt(a) / spread
    offset = centre + spread * o
    v = (u - offset) * gains
    residual = np.linalg.norm(v, axis=1) - magnitude
    return {
        "gains": gains,
        "offset": offset,
        "residual_rms": float(np.sqrt(np.mean(residual**2))),
        "seed": seed_used,
        "ipopt": out.record(),
    }


def _general_features(z) -> np.ndarray:
    x, y, w = z[:, 0], z[:, 1], z[:, 2]
    return np.column_stack([x * x, y * y, w * w, x * y, x * w, y * w, x, y, w, np.ones(len(z))])


def fit_general_ellipsoid(
    m, *, magnitude: float, seed: str = "linear", sensor: str = "sensor"
) -> dict:
    """General ellipsoid v = L (m - o), L symmetric positive definite, |v| = magnitude, as an NLP.

    The symmetric L is the gauge: a rotation of the sensor triad cannot be seen in an ellipsoid, so
    the correction closest to no rotation is chosen.

    Returns L (output unit per input unit), o (input unit), the RMS of |v| - magnitude, the
    condition number of the design, the seed used and the IPOPT record.
    """
    z, centre, spread = normalise(m)
    phi = _general_features(z)
    design = phi[:, :9]
    singular = np.linalg.svd(design / np.sqrt(len(z)), compute_uv=False)
    condition = float(singular[0] / singular[-1]) if singular[-1] > 0 else np.inf
    if not condition < 1e5:
        raise InputError(
            f"the {sensor} samples cover too few directions for an ellipsoid fit (they lie near a "
            f"plane or a circle); turn the housing through many different attitudes"
        )
    x0, seed_used = np.r_[1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], "centroid"
    if seed == "linear":
        q, *_ = np.linalg.lstsq(design, np.ones(len(z)), rcond=None)
        A = np.array(
            [[q[0], q[3] / 2, q[4] / 2], [q[3] / 2, q[1], q[5] / 2], [q[4] / 2, q[5] / 2, q[2]]]
        )
        if np.all(np.linalg.eigvalsh(A) > 0):
            o = -0.5 * np.linalg.solve(A, q[6:9])
            G = 1 + o @ A @ o
            if G > 0:
                A = A / G
                x0 = np.r_[A[0, 0], A[1, 1], A[2, 2], A[0, 1], A[0, 2], A[1, 2], o]
                seed_used = "linear"
    elif seed != "centroid":
        raise InputError(f"unknown ellipsoid seed {seed!r}; expected linear or centroid")
    Phi = phi.T @ phi / len(z)
    out = solve(
        general_ellipsoid_nlp(),
        x0=x0,
        p=Phi.ravel(order="F"),
        lbg=np.full(3, 1e-9),
        ubg=np.full(3, np.inf),
    ).checked(f"{sensor} ellipsoid fit")
    a = out.x
    A = np.array([[a[0], a[3], a[4]], [a[3], a[1], a[5]], [a[4], a[5], a[2]]])
    w, V = np.linalg.eigh(A)
    if np.any(w <= 0):
        raise SolveError(f"the {sensor} ellipsoid fit did not give an ellipsoid", out.status)
    L = magnitude * (V @ np.diag(np.sqrt(w)) @ V.T) / spread
    offset = centre + spread * a[6:9]
    v = (m - offset) @ L.T
    residual = np.linalg.norm(v, axis=1) - magnitude
    return {
        "L": L,
        "offset": offset,
        "residual_rms": float(np.sqrt(np.mean(residual**2))),
        "condition": condition,
        "seed": seed_used,
        "ipopt": out.record(),
    }
