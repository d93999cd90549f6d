"""The nine-parameter triaxial fluxgate model of Zhou et al. (2010).

    A B = O_p S_p (B_M - Z_p)                                          Eq. 4 in [1]

B is the true field in the geographic frame, A the rotation to the ideal orthogonal sensor frame
o-x1y1z1, B_M the sensor output. Writing T = O_p^-1,

    T = [[cos(alpha) cos(gamma), cos(alpha) sin(gamma), -sin(alpha)],
         [0,                     cos(beta),              sin(beta)  ],
         [0,                     0,                      1          ]]

the rows of T are the sensor axes x, y, z written in the ideal frame, so

    B_M = diag(1 + s) T (A B) + Z_p                        forward model (sensor output)
    B_1 = T^-1 diag(1 + s)^-1 (B_M - Z_p)                  correction (Eq. 4)

Angle convention (Eq. 2 in [1]): oz coincides with oz1 and the plane yoz with y1oz1.
alpha is the angle between the sensor x axis and the plane x1oy1 (positive alpha tilts x toward
-z1), beta the angle between oy and oy1 (positive beta tilts y toward +z1), gamma the angle
between the projection of ox on x1oy1 and ox1 (positive gamma turns x toward +y1).

Worked example: alpha = 1 deg, beta = gamma = 0, unit scale, no offset. A field of 50 000 nT along
+z1 reads B_M = (-sin 1 deg * 50 000, 0, 50 000) = (-872.6, 0, 50 000) nT: the x axis, tilted by 1
deg out of the horizontal plane, sees a part of the vertical field.

The correction matrix M = O_p S_p = T^-1 diag(1 + s)^-1 is upper triangular, so the corrected
field depends on the parameters only through the quadratic form (B_M - Z)^T M^T M (B_M - Z).

References
----------
[1] Zhou C., Jin J., Li H., Zhang B., Yan H. (2010). Cyclic optimisation algorithm for the
    calibration of triaxial fluxgate sensors. Hydrographic Surveying and Charting 30(4), 63-66.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import cache

import numpy as np

#: Names of the nine parameters in the order used everywhere in nlpcal.
PARAMETER_NAMES = ("z_x", "z_y", "z_z", "s_x", "s_y", "s_z", "alpha_deg", "beta_deg", "gamma_deg")
#: Units of the nine parameters, in the same order ("field" is the unit of the data, nT by default).
PARAMETER_UNITS = ("field",) * 3 + ("1",) * 3 + ("deg",) * 3


@dataclass(frozen=True)
class Zhou2010Parameters:
    """The nine calibration parameters of Eq. 4 in [1].

    Attributes
    ----------
    z_x, z_y, z_z : float
        Zero offsets Z_p. [nT]
    s_x, s_y, s_z : float
        Scale errors, the axis gains being 1 + s. [1]
    alpha_deg, beta_deg, gamma_deg : float
        Non-orthogonality angles. [deg]

    References
    ----------
    [1] Zhou C., Jin J., Li H., Zhang B., Yan H. (2010). Cyclic optimisation algorithm for the
        calibration of triaxial fluxgate sensors. Hydrographic Surveying and Charting 30(4), 63-66.

    Examples
    --------
    >>> import nlpcal
    >>> truth = nlpcal.Zhou2010Parameters(z_x=-71.55, s_x=0.0072, alpha_deg=-2.34)
    >>> truth.offsets  # [nT]
    array([-71.55,   0.  ,   0.  ])
    >>> log = nlpcal.simulate(100, parameters=truth, seed=0)  # a sensor with these errors
    """

    z_x: float = 0.0
    z_y: float = 0.0
    z_z: float = 0.0
    s_x: float = 0.0
    s_y: float = 0.0
    s_z: float = 0.0
    alpha_deg: float = 0.0
    beta_deg: float = 0.0
    gamma_deg: float = 0.0

    @classmethod
    def from_dict(cls, values: dict) -> Zhou2010Parameters:
        """From the nine named values (raises KeyError when one is missing)."""
        missing = [name for name in PARAMETER_NAMES if name not in values]
        if missing:
            raise KeyError(f"parameters missing: {', '.join(missing)}")
        return cls(**{name: float(values[name]) for name in PARAMETER_NAMES})

    @classmethod
    def from_theta(cls, theta) -> Zhou2010Parameters:
        """From the internal vector theta: z [field unit], s [1], angles [rad]."""
        theta = np.asarray(theta, dtype=float).ravel()
        return cls.from_vector(np.concatenate([theta[:6], np.degrees(theta[6:9])]))

    @classmethod
    def from_vector(cls, vector) -> Zhou2010Parameters:
        vector = np.asarray(vector, dtype=float).ravel()
        if vector.size != 9:
            raise ValueError(f"expected 9 parameters, got {vector.size}")
        return cls(*map(float, vector))

    def to_dict(self) -> dict:
        """The nine named values."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    as_dict = to_dict  # the name of nlpcal 0.1; kept for one release

    def as_vector(self) -> np.ndarray:
        """The nine values in PARAMETER_NAMES order (angles in degrees)."""
        return np.array([getattr(self, name) for name in PARAMETER_NAMES])

    @property
    def theta(self) -> np.ndarray:
        """The internal vector the NLPs use: z [field unit], s [1], angles [rad]."""
        return np.concatenate([self.offsets, self.scales, self.angles_rad])

    @property
    def offsets(self) -> np.ndarray:
        """Z_p. [nT]"""
        return np.array([self.z_x, self.z_y, self.z_z])

    @property
    def scales(self) -> np.ndarray:
        """s, the axis gains being 1 + s. [1]"""
        return np.array([self.s_x, self.s_y, self.s_z])

    @property
    def angles_rad(self) -> np.ndarray:
        """(alpha, beta, gamma). [rad]"""
        return np.radians([self.alpha_deg, self.beta_deg, self.gamma_deg])


# The helpers below take plain numbers or CasADi symbols: `cos`, `sin` and `matrix` are passed in
# so that the same lines serve the numeric model and the symbolic NLPs.


def axis_matrix_entries(alpha, beta, gamma, cos=np.cos, sin=np.sin):
    """Entries of T = O_p^-1 (Eq. 4 in [1]); rows are the sensor axes in the ideal frame."""
    return [
        [cos(alpha) * cos(gamma), cos(alpha) * sin(gamma), -sin(alpha)],
        [0.0, cos(beta), sin(beta)],
        [0.0, 0.0, 1.0],
    ]


def correction_matrix_entries(alpha, beta, gamma, s_x, s_y, s_z, cos=np.cos, sin=np.sin):
    """Entries of M = O_p S_p = T^-1 diag(1 + s)^-1, upper triangular (Eq. 4 in [1]).

    T^-1 is written out for the upper-triangular T so that no symbolic inverse is needed.
    """
    t = axis_matrix_entries(alpha, beta, gamma, cos, sin)
    t11, t12, t13 = t[0]
    t22, t23 = t[1][1], t[1][2]
    g_x, g_y, g_z = 1.0 + s_x, 1.0 + s_y, 1.0 + s_z
    t_inv = [
        [1.0 / t11, -t12 / (t11 * t22), (t12 * t23 - t13 * t22) / (t11 * t22)],
        [0.0, 1.0 / t22, -t23 / t22],
        [0.0, 0.0, 1.0],
    ]
    return [
        [t_inv[0][0] / g_x, t_inv[0][1] / g_y, t_inv[0][2] / g_z],
        [0.0, t_inv[1][1] / g_y, t_inv[1][2] / g_z],
        [0.0, 0.0, 1.0 / g_z],
    ]


def triangular(entries, v_x, v_y, v_z) -> list:
    """The rows of M v for an upper-triangular M given by its `entries` (as
    `correction_matrix_entries` writes them) and the components of v: numbers, arrays of
    samples (numpy) or rows of samples (CasADi), entries per sample or shared."""
    return [
        entries[0][0] * v_x + entries[0][1] * v_y + entries[0][2] * v_z,
        entries[1][1] * v_y + entries[1][2] * v_z,
        entries[2][2] * v_z,
    ]


def axis_matrix(params: Zhou2010Parameters) -> np.ndarray:
    """T = O_p^-1 of Eq. 4 in [1]. [1]"""
    return np.array(axis_matrix_entries(*params.angles_rad), dtype=float)


def correction_matrix(params: Zhou2010Parameters) -> np.ndarray:
    """M = O_p S_p of Eq. 4 in [1]. [1]"""
    return np.array(correction_matrix_entries(*params.angles_rad, *params.scales), dtype=float)


def forward(field_sensor_ideal, params: Zhou2010Parameters) -> np.ndarray:
    """Sensor output B_M for the true field A B given in the ideal sensor frame.

    B_M = diag(1 + s) T (A B) + Z_p, the inverse of Eq. 4 in [1].

    field_sensor_ideal : (N, 3) true field in the ideal orthogonal sensor frame. [nT]
    Returns (N, 3) sensor output. [nT]
    """
    field = np.asarray(field_sensor_ideal, dtype=float)
    gains = 1.0 + params.scales
    return (field @ axis_matrix(params).T) * gains + params.offsets


def correct(samples, params: Zhou2010Parameters) -> np.ndarray:
    """Corrected field B1 = O_p S_p (B_M - Z_p), Eq. 4 in [1].

    samples : (N, 3) sensor output B_M. [nT]
    Returns (N, 3) corrected field B1. [nT]
    """
    samples = np.asarray(samples, dtype=float)
    return (samples - params.offsets) @ correction_matrix(params).T


def from_correction(matrix, offsets) -> tuple[Zhou2010Parameters, np.ndarray]:
    """The nine parameters of any affine correction B_out = A (B_M - b), and the rotation Q that
    they do not carry: A = Q O_p S_p.

    Eq. 4 in [1] writes the correction as the upper-triangular M = O_p S_p = (S N)^-1 with
    S = diag(1 + s) and N = T = O_p^-1. A rotation Q in front of M leaves A^T A = M^T M, so

        (A^T A)^-1 = (S N) (S N)^T,

    and S N is the upper-triangular factor, with positive diagonal, of (A^T A)^-1 (a Cholesky
    factorisation taken from the last row up). The rows of S N are the sensor axes scaled by their
    gains (1 + s): row x = (1 + s_x)(cos a cos g, cos a sin g, -sin a), row y = (1 + s_y)(0,
    cos b, sin b), row z = (1 + s_z)(0, 0, 1), which gives the gains and the angles. Q = A S N.

    matrix : (3, 3) A, invertible with det A > 0 (a correction, not a reflection). [1]
    offsets : (3,) b. [field unit]
    Returns (parameters, Q); raises ValueError when A is singular or reverses handedness.
    """
    a = np.asarray(matrix, dtype=float)
    if a.shape != (3, 3) or not np.isfinite(a).all():
        raise ValueError("the correction matrix must be 3 x 3 and finite")
    if not np.linalg.det(a) > 0:
        raise ValueError("the correction matrix is singular or reverses handedness (det <= 0)")
    c = np.linalg.inv(a.T @ a)  # (A^T A)^-1 = (S N)(S N)^T
    flip = np.eye(3)[::-1]
    sn = flip @ np.linalg.cholesky(flip @ c @ flip) @ flip  # upper triangular, positive diagonal
    g_x = float(np.linalg.norm(sn[0]))
    g_y = float(np.hypot(sn[1, 1], sn[1, 2]))
    g_z = float(sn[2, 2])
    alpha = np.arctan2(-sn[0, 2], np.hypot(sn[0, 0], sn[0, 1]))
    gamma = np.arctan2(sn[0, 1], sn[0, 0])
    beta = np.arctan2(sn[1, 2], sn[1, 1])
    offsets = np.asarray(offsets, dtype=float).ravel()
    params = Zhou2010Parameters.from_vector(
        [*offsets, g_x - 1.0, g_y - 1.0, g_z - 1.0, *np.degrees([alpha, beta, gamma])]
    )
    return params, a @ sn


# --- restricted forms of Eq. 4 ------------------------------------------------------------------

#: The forms of Eq. 4 in [1] nlpcal estimates, from the fewest parameters to all nine:
#: "offset" Z_p alone (S_p = O_p = I; with a known field one common scale, s_x = s_y = s_z),
#: "diagonal" Z_p and S_p (O_p = I), "full" the nine of Eq. 4. Parameters a form does not
#: estimate are held at their identity values (zero). MATLAB's magcal calls them 'eye', 'diag'
#: and 'sym'; MotionCal fits 4, 7 and 10 elements.
MODELS = ("offset", "diagonal", "full")


def model_directions(model: str, scale_known: bool) -> np.ndarray:
    """(9, k) directions in theta (PARAMETER_NAMES order) that a form of Eq. 4 frees: the
    estimate is theta = E x, zero along every other direction.

    scale_known : whether a reference field fixes the absolute scale; the "offset" form then
        frees one common scale (the direction s_x = s_y = s_z).
    """
    identity = np.eye(9)
    if model == "full":
        return identity
    if model == "diagonal":
        return identity[:, :6]
    if model == "offset":
        common = np.r_[0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0][:, None]
        return np.hstack([identity[:, :3], common]) if scale_known else identity[:, :3]
    raise ValueError(f"unknown model {model!r}; expected one of {', '.join(MODELS)}")


def estimated_parameters(model: str, scale_known: bool) -> list:
    """The names of the parameters a form of Eq. 4 estimates (the others are fixed at zero)."""
    return list(_estimated(model, bool(scale_known)))


@cache
def _estimated(model: str, scale_known: bool) -> tuple:
    """`estimated_parameters`, found once per form and kind of reference."""
    rows = np.any(model_directions(model, scale_known) != 0.0, axis=1)
    return tuple(name for name, free in zip(PARAMETER_NAMES, rows) if free)


def tied_parameters(model: str, scale_known: bool) -> list:
    """Groups of parameters a form estimates as one value (the common scale of "offset")."""
    directions = model_directions(model, scale_known)
    return [
        [name for name, v in zip(PARAMETER_NAMES, column) if v != 0.0]
        for column in directions.T
        if np.count_nonzero(column) > 1
    ]


def is_of_model(parameters: dict, model: str, scale_known: bool) -> bool:
    """Whether named parameters are of a form: zero where it fixes them, equal (to 1e-12) where
    it ties them."""
    estimated = estimated_parameters(model, scale_known)
    if any(parameters[n] != 0.0 for n in PARAMETER_NAMES if n not in estimated):
        return False
    return all(
        np.allclose([parameters[n] for n in group], parameters[group[0]], rtol=1e-12, atol=1e-15)
        for group in tied_parameters(model, scale_known)
    )


def smallest_model(parameters: dict, scale_known: bool) -> str:
    """The smallest form of Eq. 4 that holds the parameters exactly (an imported correction)."""
    return next(m for m in MODELS if is_of_model(parameters, m, scale_known))
