"""The non-orthogonality model of Wang, Zong, Zhao and Cheng (2015): total-field error of a probe.

Only the non-orthogonality of the three axes is considered (unit sensitivities, zero offsets).
With the probe output written as

    B' = T B                                                      Eq. 1-2 in [1]

the total-field error is

    dB = |B'| - |B|                                               Eq. 4 in [1]

and for a field of magnitude B along the direction (theta, phi),

    B = B (cos(phi) cos(theta), cos(phi) sin(theta), sin(phi))     Eq. 5 in [1]
    dB(theta, phi) = B (|T u(theta, phi)| - 1)                    Eq. 7-8 in [1]

nlpcal uses the angle convention of Zhou et al. (2010) [2] throughout, so T is the axis matrix of
`nlpcal.models.zhou2010` (rows: the sensor axes in the ideal frame):

    T = [[cos(alpha) cos(gamma), cos(alpha) sin(gamma), -sin(alpha)],
         [0,                     cos(beta),              sin(beta)  ],
         [0,                     0,                      1          ]]

[1] names its angles alpha, beta and 90 deg - gamma between probe axes; the mapping to [2] is in
`../shared/REFERENCE.md`. The surviving text of [1] lost its equation images; the numbers above
follow the text's own references to Eq. 4, 6 and 9.

The worst case over all directions (Eq. 9 in [1]) is a Rayleigh quotient in disguise:
|T u|^2 = u^T (T^T T) u on the unit sphere, so its exact extremes are B (sigma_max - 1) and
B (sigma_min - 1) with sigma the singular values of T (the certificate of
`nlpcal.orthogonality.worst_case`). To first order in the angles [rad], T^T T = I + G with

    G = [[0, gamma, -alpha], [gamma, 0, beta], [-alpha, beta, 0]]

and dB ~= (B / 2) u^T G u, so max |dB| ~= (B / 2) max |eig(G)| (`small_angle_worst_case`). For
alpha = beta = gamma = e the eigenvalues of G are (e, e, -2e), giving max |dB| ~= B e: 96.0 nT
for 0.1 deg at 55 000 nT (the paper reports "about 95 nT").

References
----------
[1] Wang Y., Zong F., Zhao Y., Cheng D. (2015). Calibration and measurement on the orthogonal
    three-axes of three-components magnetic flux-gate sensor. Journal of Shandong Agricultural
    University (Natural Science Edition), 2015(2), 232-237. (No DOI in the source text.)
[2] Zhou C., Jin J., Li H., Zhang B., Yan H. (2010). Cyclic optimisation algorithm for the
    calibration of triaxial fluxgate sensors. Hydrographic Surveying and Charting 30(4), 63-66.
"""

from __future__ import annotations

import math

import numpy as np

from .zhou2010 import axis_matrix_entries, correction_matrix_entries

#: Angle names in the order used everywhere (Zhou 2010 convention).
ANGLE_NAMES = ("alpha", "beta", "gamma")
#: Field of the paper's forward modelling and synthetic inversion. [nT]
PAPER_FIELD_NT = 55_000.0
#: The forward-modelling example of [1] (section 1): its angles [deg] and the largest total-field
#: error of its map over all directions, "about 95 nT". [nT]
PAPER_WORST_ANGLES_DEG = (0.1, 0.1, 0.1)
PAPER_WORST_CASE_NT = 95.0
#: The synthetic inversion of [1] (section 2): the angles it recovers "exactly". [deg]
PAPER_SYNTHETIC_ANGLES_DEG = (0.07, 0.04, 0.1)
#: The real probe of [1] (section 3): alpha and 90 deg - gamma; beta is not given. [deg]
PAPER_PROBE_ANGLES_DEG = {"alpha": 0.064, "gamma": 0.103}
#: Repeated inversions of the probe agree with their mean within this angle [deg], which implies
#: a total-field error of "at most 3.8 nT" [nT] (section 3 of [1]).
PAPER_DEVIATION_DEG = 0.004
PAPER_IMPLIED_NT = 3.8


def direction(theta_deg, phi_deg) -> np.ndarray:
    """Unit vectors u(theta, phi) of Eq. 5 in [1], shape (..., 3).

    theta_deg : azimuth in the ideal frame, in [0, 360). [deg]
    phi_deg : elevation above the x-y plane, in [-90, 90]. [deg]
    """
    theta, phi = np.broadcast_arrays(
        np.radians(np.asarray(theta_deg, dtype=float)), np.radians(np.asarray(phi_deg, dtype=float))
    )
    return np.stack(
        [np.cos(phi) * np.cos(theta), np.cos(phi) * np.sin(theta), np.sin(phi)], axis=-1
    )


def axis_matrix_deg(angles_deg) -> np.ndarray:
    """T of Eq. 2 in [1] in the angle convention of [2] (unit scale, zero offset). [1]"""
    angles = np.radians(np.asarray(angles_deg, dtype=float))
    return np.array(axis_matrix_entries(*angles), dtype=float)  # Eq. 2


def total_field_error(angles_deg, field_nT, theta_deg, phi_deg) -> np.ndarray:
    """dB = |T B| - |B| for a field of magnitude `field_nT` along (theta, phi). [nT]

    Eq. 4 and 8 in [1]. theta_deg and phi_deg broadcast against each other. [deg]
    """
    t = axis_matrix_deg(angles_deg)
    b = float(field_nT)
    u = direction(theta_deg, phi_deg)
    return b * (np.linalg.norm(u @ t.T, axis=-1) - 1.0)  # Eq. 8


def small_angle_form(angles_deg) -> np.ndarray:
    """G, the first-order part of T^T T - I in the angles, symmetric 3 x 3. [1]

    dB ~= (B / 2) u^T G u, so max |dB| ~= (B / 2) max |eig(G)|.
    """
    alpha, beta, gamma = np.radians(np.asarray(angles_deg, dtype=float))
    return np.array([[0.0, gamma, -alpha], [gamma, 0.0, beta], [-alpha, beta, 0.0]])


def small_angle_worst_case(angles_deg, field_nT) -> float:
    """max |dB| to first order in the angles: (B / 2) max |eig(G)|. [nT]"""
    return (
        0.5
        * float(field_nT)
        * float(np.max(np.abs(np.linalg.eigvalsh(small_angle_form(angles_deg)))))
    )


def error_map(angles_deg, field_nT, step_deg: float = 1.0):
    """dB on a regular (theta, phi) grid: the map of Fig. 4 in [1].

    step_deg : grid step in both angles, in (0, 10]. [deg]
    Returns theta [deg] (n_theta,), phi [deg] (n_phi,), dB [nT] (n_phi, n_theta).
    """
    step = float(step_deg)
    if not math.isfinite(step) or step <= 0 or step > 10:
        raise ValueError(f"the map step must lie in (0, 10] deg, got {step_deg!r}")
    theta = np.arange(0.0, 360.0, step)
    phi = np.linspace(-90.0, 90.0, int(round(180.0 / step)) + 1)
    error = total_field_error(angles_deg, field_nT, theta[None, :], phi[:, None])
    return theta, phi, error


def corrected_magnitude(samples, angles_deg) -> np.ndarray:
    """|T^-1 B'_i| for probe output B' (N, 3) [nT] and angles (alpha, beta, gamma) [deg]. [nT]"""
    alpha, beta, gamma = np.radians(np.asarray(angles_deg, dtype=float))
    t_inv = np.array(correction_matrix_entries(alpha, beta, gamma, 0.0, 0.0, 0.0), dtype=float)
    return np.linalg.norm(np.asarray(samples, dtype=float) @ t_inv.T, axis=1)


# --- probe output for directions spread over the sphere (section 2 of [1]) ------------------


def fibonacci_directions(n: int) -> np.ndarray:
    """n unit vectors spread evenly over the sphere (a Fibonacci lattice), shape (n, 3). [1]"""
    n = int(n)
    if n < 1:
        raise ValueError(f"need at least one direction, got {n}")
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    azimuth = math.pi * (1.0 + math.sqrt(5.0)) * k
    r = np.sqrt(1.0 - z**2)
    return np.stack([r * np.cos(azimuth), r * np.sin(azimuth), z], axis=1)


def synthetic_rotation(
    angles_deg, field_nT=PAPER_FIELD_NT, n: int = 500, noise_nT: float = 0.0, seed: int = 0
) -> np.ndarray:
    """Probe output B' = T B + noise for n directions spread over the sphere. [nT]

    angles_deg : (alpha, beta, gamma). [deg]; field_nT : |B|. [nT]; noise_nT : standard deviation
    of white noise added to each axis. [nT]
    """
    b = float(field_nT)
    t = axis_matrix_deg(angles_deg)
    probe = b * fibonacci_directions(n) @ t.T  # Eq. 1
    if noise_nT:
        probe = probe + np.random.default_rng(seed).normal(0.0, float(noise_nT), probe.shape)
    return probe
