"""Qiu, Shi, Sun and Shen (2017): the e-compass model (magnetometer + accelerometer in one housing).

Conventions (fixed; see docs/compass.md for a worked example)

- World frame NED: x north (magnetic north unless a declination is applied), y east, z down.
- Housing (body) frame: x forward, y right, z down.
- Attitude by frame rotations, Eq. 9 in [1]: C = R_x(roll) R_y(pitch) R_z(heading); a body vector is
  C times the world vector. R_a(angle) are *frame* rotations (passive), e.g.
  R_z(psi) = [[cos psi, sin psi, 0], [-sin psi, cos psi, 0], [0, 0, 1]].
- The accelerometer reads specific force: at rest the body components of (0, 0, -1) g.
- The magnetometer reads the body components of the local field (B_N, 0, B_D) = F (cos I, 0, sin I),
  with I the dip (inclination), positive downward.
- Per sensor (Eq. 1 and 3 in [1]): reading = diag(1 + s) E v_body + bias, where row k of E is the
  unit vector of sensor axis k in housing coordinates. Sensor axis x leans toward housing y by
  alpha_xy and toward housing z by alpha_xz, defined through the projections of the axis on the
  housing planes: row x of E is proportional to (1, tan alpha_xy, tan alpha_xz); likewise row y to
  (tan beta_yx, 1, tan beta_yz) and row z to (tan gamma_zx, tan gamma_zy, 1). For small angles this
  is Eq. 3 of [1], E = I + [[0, a_xy, a_xz], [b_yx, 0, b_yz], [g_zx, g_zy, 0]].

References
----------
[1] Qiu X., Shi W., Sun C., Shen H. (2017). A simplified high-precision calibration method for 3D
    electronic compass. Ship Electronic Engineering 37(2). doi:10.3969/j.issn.1672-9730.2017.02.020
"""

from __future__ import annotations

import numpy as np

#: The six mounting angles of Eq. 3 in [1], in the order used everywhere in nlpcal.
ANGLE_NAMES = ("alpha_xy", "alpha_xz", "beta_yx", "beta_yz", "gamma_zx", "gamma_zy")

#: (row, column) of E that each angle tilts: sensor axis `row` toward housing axis `column`.
ANGLE_INDEX = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))

AXES = "xyz"

#: The attitude errors after calibration that [1] reports, as bounds: roll, pitch and heading
#: within +-0.15, +-0.15 and +-0.5 deg for pitch up to +-85 deg (section 4). [deg]
PAPER_ATTITUDE_BOUNDS_DEG = {"roll": 0.15, "pitch": 0.15, "heading": 0.5}
PAPER_MAX_PITCH_DEG = 85.0


def _as_angle_array(angle):
    return np.asarray(angle, dtype=float)


def rotation_x(angle) -> np.ndarray:
    """Frame rotation about x by `angle`. [rad] Returns (3, 3) or (..., 3, 3)."""
    a = _as_angle_array(angle)
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    return np.stack(
        [np.stack([one, zero, zero], -1), np.stack([zero, c, s], -1), np.stack([zero, -s, c], -1)],
        -2,
    )


def rotation_y(angle) -> np.ndarray:
    """Frame rotation about y by `angle`. [rad] Returns (3, 3) or (..., 3, 3)."""
    a = _as_angle_array(angle)
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    return np.stack(
        [np.stack([c, zero, -s], -1), np.stack([zero, one, zero], -1), np.stack([s, zero, c], -1)],
        -2,
    )


def rotation_z(angle) -> np.ndarray:
    """Frame rotation about z by `angle`. [rad] Returns (3, 3) or (..., 3, 3)."""
    a = _as_angle_array(angle)
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    return np.stack(
        [np.stack([c, s, zero], -1), np.stack([-s, c, zero], -1), np.stack([zero, zero, one], -1)],
        -2,
    )


def attitude_matrix(roll, pitch, heading) -> np.ndarray:
    """C = R_x(roll) R_y(pitch) R_z(heading), world (NED) to body. Eq. 9 in [1].

    Parameters
    ----------
    roll, pitch, heading : float or array
        Attitude angles. [rad]
    """
    return rotation_x(roll) @ rotation_y(pitch) @ rotation_z(heading)  # Eq. 9


def euler_from_matrix(C) -> tuple:
    """Roll, pitch, heading of C = R_x(roll) R_y(pitch) R_z(heading). [rad]

    Heading is in [0, 2 pi). Row 0 of C is (cos p cos h, cos p sin h, -sin p) and column 2 is
    (-sin p, sin r cos p, cos r cos p).
    """
    C = np.asarray(C, dtype=float)
    pitch = np.arctan2(-C[..., 0, 2], np.hypot(C[..., 1, 2], C[..., 2, 2]))
    roll = np.arctan2(C[..., 1, 2], C[..., 2, 2])
    heading = np.mod(np.arctan2(C[..., 0, 1], C[..., 0, 0]), 2 * np.pi)
    return roll, pitch, heading


def mounting_matrix(angles) -> np.ndarray:
    """E of Eq. 3 in [1] from the six mounting angles (ANGLE_NAMES order). [rad]

    Row k is the unit vector of sensor axis k in housing coordinates (exact form; Eq. 3 of [1] is
    its small-angle approximation).
    """
    angles = np.asarray(angles, dtype=float).ravel()
    if angles.size != 6:
        raise ValueError(f"expected 6 mounting angles, got {angles.size}")
    E = np.eye(3)
    for angle, (row, col) in zip(angles, ANGLE_INDEX):
        E[row, col] = np.tan(angle)  # Eq. 3 (exact form)
    return E / np.linalg.norm(E, axis=1, keepdims=True)


def sensor_matrix(angles, sensitivity) -> np.ndarray:
    """M = diag(1 + s) E: readings = M v_body + bias. Eq. 1 in [1].

    Parameters
    ----------
    angles : sequence of 6
        Mounting angles, ANGLE_NAMES order. [rad]
    sensitivity : sequence of 3
        Sensitivity errors s (0 for an ideal axis). [1]
    """
    return np.diag(1.0 + np.asarray(sensitivity, dtype=float)) @ mounting_matrix(angles)  # Eq. 1


def decompose_sensor_matrix(M) -> tuple:
    """Split M = diag(1 + s) E into the six mounting angles [rad] and the sensitivities s. [1]

    Exact inverse of `sensor_matrix`: 1 + s_k is the length of row k and the angles are read from
    the ratios of that row's entries. Raises ValueError when a diagonal entry is not positive
    (a sensor axis more than 90 degrees from its housing axis).
    """
    M = np.asarray(M, dtype=float)
    diagonal = np.diag(M)
    if np.any(diagonal <= 0):
        raise ValueError("a sensor axis points more than 90 degrees away from its housing axis")
    norms = np.linalg.norm(M, axis=1)
    angles = np.array([np.arctan2(M[row, col], M[row, row]) for row, col in ANGLE_INDEX])
    return angles, norms - 1.0


def sensor_reading(v_body, angles, sensitivity, bias) -> np.ndarray:
    """Sensor output diag(1 + s) E v_body + bias. Eq. 1 in [1].

    Parameters
    ----------
    v_body : (N, 3) array
        Quantity in housing coordinates (field [nT] or specific force [g]).
    angles : sequence of 6
        Mounting angles, ANGLE_NAMES order. [rad]
    sensitivity : sequence of 3
        Sensitivity errors. [1]
    bias : sequence of 3
        Zero bias, in the unit of v_body.
    """
    v_body = np.atleast_2d(np.asarray(v_body, dtype=float))
    return v_body @ sensor_matrix(angles, sensitivity).T + np.asarray(bias, dtype=float)  # Eq. 1


def field_ned(total, dip) -> np.ndarray:
    """Local field (F cos I, 0, F sin I) in NED, magnetic north.

    Parameters
    ----------
    total : float
        Total field F. [nT]
    dip : float
        Inclination I, positive downward. [rad]
    """
    return float(total) * np.array([np.cos(dip), 0.0, np.sin(dip)])


#: Specific force sensed at rest, NED components. [g]
SPECIFIC_FORCE_AT_REST_NED = np.array([0.0, 0.0, -1.0])


def body_vectors(C, field_world) -> tuple:
    """Body components of the specific force at rest [g] and of the field [nT] for attitudes C."""
    C = np.asarray(C, dtype=float)
    return C @ SPECIFIC_FORCE_AT_REST_NED, C @ np.asarray(field_world, dtype=float)


def attitude_from_vectors(acc, mag, declination=0.0) -> tuple:
    """Roll, pitch and heading from calibrated body vectors. Eq. 10 in [1]. [rad]

    Inverts Eq. 9: with d = -acc / |acc| (gravity direction in body axes),
    d = (-sin p, sin r cos p, cos r cos p), so roll = atan2(d_y, d_z) and
    pitch = atan2(-d_x, hypot(d_y, d_z)); the field levelled by R_y(p)^T R_x(r)^T equals
    R_z(h) (B_N, 0, B_D), whose first two components are (B_N cos h, -B_N sin h).

    Parameters
    ----------
    acc : (N, 3) array
        Calibrated specific force, any unit.
    mag : (N, 3) array
        Calibrated field, any unit.
    declination : float
        Added to the magnetic heading to give true heading. [rad]

    Returns roll in (-pi, pi], pitch in [-pi/2, pi/2] and heading in [0, 2 pi). Roll and heading
    are undefined at pitch = +-90 degrees (only their difference or sum is).
    """
    acc = np.atleast_2d(np.asarray(acc, dtype=float))
    mag = np.atleast_2d(np.asarray(mag, dtype=float))
    d = -acc
    roll = np.arctan2(d[:, 1], d[:, 2])  # Eq. 10
    pitch = np.arctan2(-d[:, 0], np.hypot(d[:, 1], d[:, 2]))  # Eq. 10
    sr, cr = np.sin(roll), np.cos(roll)
    sp, cp = np.sin(pitch), np.cos(pitch)
    h_x = cp * mag[:, 0] + sp * (sr * mag[:, 1] + cr * mag[:, 2])
    h_y = cr * mag[:, 1] - sr * mag[:, 2]
    heading = np.mod(np.arctan2(-h_y, h_x) + declination, 2 * np.pi)  # Eq. 10
    return roll, pitch, heading
