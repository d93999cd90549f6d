"""E-compass calibration and attitude after Qiu et al. (2017), every estimation a CasADi/IPOPT NLP.

Two calibration modes share one result type, `CompassCalibration`:

- Turn mode (`calibrate_turns`), the paper's protocol: the housing is turned about its own x, y and
  z axes. For each axis k, the compensation angles of sensor axis k are the ones that make the
  compensated output along k constant over the turns about k (Eq. 4-8 in [1], one NLP per axis and
  sensor); then zero bias and sensitivity come from an axis-aligned ellipsoid fit of the compensated
  outputs (an NLP, seeded by a linear least-squares fit). Everything of the model
  reading = diag(1 + s) E v_body + bias is identified, in the housing frame.
- Free-rotation mode (`calibrate_free`), for logs without turns: a general ellipsoid fit per sensor
  (an NLP), then the magnetometer-to-accelerometer rotation from the constancy of the angle between
  the two calibrated vectors (the dip angle; an NLP). What it cannot identify: the orientation of
  the sensor pair relative to the housing (a rotation common to both sensors leaves every ellipsoid
  and every dip angle unchanged). The accelerometer frame, corrected by a symmetric matrix (no
  rotation), stands in for the housing frame; the magnetometer is rotated into it.

Problem sizes do not depend on the number of samples: the data enter as moment matrices accumulated
once (sums of outer products), passed as parameters to solvers built once per process.

References
----------
[1] Qiu X., Shi W., Sun C., Shen H. (2017). A simplified high-precision calibration method for 3D
    electronic compass. Ship Electronic Engineering 37(2). doi:10.3969/j.issn.1672-9730.2017.02.020
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np
import pandas as pd

from . import io
from .errors import InputError, SolveError
from .models import qiu2017 as model
from .solver import build_nlpsol, solve
from .statistics import lag1_autocorrelation, standard_error_inflation

#: Accelerometer units and their size in g (standard gravity 9.80665 m/s2).
ACC_UNITS_G = {"g": 1.0, "mg": 1e-3, "m/s2": 1.0 / 9.80665}

#: Fewest samples accepted in one turn (a constant plus two compensation angles, and spares).
MIN_TURN_SAMPLES = 6

#: Fewest samples accepted in free-rotation mode (nine ellipsoid parameters, then four more).
MIN_FREE_SAMPLES = 20

#: Bound on the compensation angles; reaching it means the turn labels do not fit the motion. [deg]
MAX_COMPENSATION_DEG = 20.0

#: A turn about axis k must move the other two components by at least this fraction of the field.
MIN_EXCITATION = 0.05

#: Warn when the calibrated component along a turn axis varies by more than this fraction. [1]
TURN_WARN_FRACTION = 0.02

#: Refuse the calibration when it varies by more than this fraction (mislabelled turns). [1]
TURN_ERROR_FRACTION = 0.10

#: Warn when a component of the magnetometer-to-accelerometer rotation is this uncertain. [deg]
ALIGNMENT_WARN_STD_DEG = 0.5

#: Pitch above which roll and heading become ill-defined and `attitude` warns. [deg]
NEAR_VERTICAL_DEG = 89.0

#: Free-rotation mode: samples whose calibrated |acc| is further than this from 1 g are moving. [g]
DEFAULT_REST_TOLERANCE = 0.02

#: Free-rotation mode: most refits of the accelerometer on the samples at rest.
REST_ITERATIONS = 5

#: Default pitch bands for `evaluate`, edges of |true pitch|. [deg]
DEFAULT_PITCH_BANDS = (0.0, 30.0, 60.0, 85.0, 90.0)

ESTIMATED_SCALE = "estimated: unknown field, scaled so that det(correction_matrix) = 1"
GRAVITY_SCALE = "1 g by definition (sensitivity relative to the local gravity)"

FORMAT = "nlpcal-compass"
FORMAT_VERSION = 1

_TURN_LABEL = re.compile(r"^([xyz])([a-z0-9_.\-]*)$")


# --------------------------------------------------------------------------------------------------
# The NLPs, built once per process


def _compensation_nlp():
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


def _axis_ellipsoid_theta(x):
    a, o = x[0:3], x[3:6]
    return ca.vertcat(a, -2 * a * o, ca.sum1(a * o ** 2) - 1)


def _axis_ellipsoid_nlp():
    """Axis-aligned ellipsoid, algebraic residual sum_k a_k (u_k - o_k)^2 - 1 per sample.

    x = (a, o): squared inverse semi-axes and centre of the normalised compensated outputs u;
    p = Phi / N with Phi = sum phi phi^T, phi = (u_x^2, u_y^2, u_z^2, u_x, u_y, u_z, 1), so that
    the objective mean(residual^2) = theta(x)^T (Phi / N) theta(x).
    """
    x = ca.SX.sym("x", 6)
    p = ca.SX.sym("Phi", 49)
    theta = _axis_ellipsoid_theta(x)
    f = ca.mtimes([theta.T, ca.reshape(p, 7, 7), theta])
    return build_nlpsol("qiu2017_axis_ellipsoid", x, f, p)


def _general_theta(x):
    A = _symmetric(x[0:6])
    o = x[6:9]
    Ao = ca.mtimes(A, o)
    return ca.vertcat(x[0], x[1], x[2], 2 * x[3], 2 * x[4], 2 * x[5], -2 * Ao,
                      ca.mtimes(o.T, Ao) - 1)


def _symmetric(values):
    a11, a22, a33, a12, a13, a23 = (values[i] for i in range(6))
    return ca.vertcat(ca.horzcat(a11, a12, a13), ca.horzcat(a12, a22, a23),
                      ca.horzcat(a13, a23, a33))


def _general_ellipsoid_nlp():
    """General ellipsoid (u - o)^T A (u - o) = 1, A symmetric positive definite.

    x = (A11, A22, A33, A12, A13, A23, o); p = Phi / N with
    phi = (u_x^2, u_y^2, u_z^2, u_x u_y, u_x u_z, u_y u_z, u_x, u_y, u_z, 1); g = the leading
    principal minors of A, kept positive.
    """
    x = ca.SX.sym("x", 9)
    p = ca.SX.sym("Phi", 100)
    theta = _general_theta(x)
    A = _symmetric(x[0:6])
    minors = ca.vertcat(A[0, 0], A[0, 0] * A[1, 1] - A[0, 1] ** 2, ca.det(A))
    return build_nlpsol("qiu2017_general_ellipsoid", x,
                        ca.mtimes([theta.T, ca.reshape(p, 10, 10), theta]), p, g=minors)


def _gibbs_rotation(r):
    """Rotation matrix of the Gibbs vector r (angle 2 atan|r| about r), smooth everywhere."""
    rx = ca.vertcat(ca.horzcat(0, -r[2], r[1]), ca.horzcat(r[2], 0, -r[0]),
                    ca.horzcat(-r[1], r[0], 0))
    return ca.SX.eye(3) + 2 / (1 + ca.dot(r, r)) * (rx + ca.mtimes(rx, rx))


def _dip_alignment_nlp():
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
    return build_nlpsol("qiu2017_dip_alignment", x,
                        ca.mtimes([theta.T, ca.reshape(p, 10, 10), theta]), p)


_BUILDERS = {
    "compensation": _compensation_nlp,
    "axis_ellipsoid": _axis_ellipsoid_nlp,
    "general_ellipsoid": _general_ellipsoid_nlp,
    "dip_alignment": _dip_alignment_nlp,
}
_SOLVERS: dict = {}


def _solver(name: str):
    """The cached nlpsol of problem `name`, built on first use."""
    if name not in _SOLVERS:
        _SOLVERS[name] = _BUILDERS[name]()
    return _SOLVERS[name]


def _checked(outcome, what: str):
    if not outcome.success:
        raise SolveError(f"IPOPT did not solve the {what}", outcome.status, outcome)
    return outcome


def _ipopt_record(outcome) -> dict:
    return {"status": outcome.status, "iterations": outcome.iterations}


# --------------------------------------------------------------------------------------------------
# Results


@dataclass
class SensorCalibration:
    """One sensor's correction v = K (reading - bias), with the model's parameters.

    `correction` K is the inverse of the sensor matrix M = diag(1 + s) E of Eq. 1 in [1];
    `bias` is in `unit`; `magnitude` is the length of v the fit scales to (1 g for the
    accelerometer; the field for the magnetometer, given or estimated).
    """

    sensor: str
    unit: str
    correction: np.ndarray
    bias: np.ndarray
    magnitude: float
    magnitude_source: str
    frame: str
    compensation: dict | None = None  # per turn axis: the two compensation angles [rad]
    compensation_std: dict | None = None  # their standard deviations [rad]
    quality: dict = field(default_factory=dict)

    @property
    def sensor_matrix(self) -> np.ndarray:
        return np.linalg.inv(self.correction)

    @property
    def mounting_angles(self) -> np.ndarray:
        """The six angles of Eq. 3, ANGLE_NAMES order. [rad]"""
        return model.decompose_sensor_matrix(self.sensor_matrix)[0]

    @property
    def sensitivity(self) -> np.ndarray:
        """Sensitivity errors s. [1]"""
        return model.decompose_sensor_matrix(self.sensor_matrix)[1]

    def apply(self, readings) -> np.ndarray:
        """Calibrated vectors (N, 3) from raw readings (N, 3) in `unit`. Eq. 2 in [1]."""
        readings = np.atleast_2d(np.asarray(readings, dtype=float))
        return (readings - self.bias) @ self.correction.T  # Eq. 2

    def to_dict(self) -> dict:
        angles = self.mounting_angles
        out = {
            "unit": self.unit,
            "frame": self.frame,
            "mounting_deg": {n: float(np.degrees(a)) for n, a in zip(model.ANGLE_NAMES, angles)},
            "sensitivity": [float(v) for v in self.sensitivity],
            "bias": [float(v) for v in self.bias],
            "magnitude": float(self.magnitude),
            "magnitude_source": self.magnitude_source,
            "correction_matrix": [[float(v) for v in row] for row in self.correction],
            "sensor_matrix": [[float(v) for v in row] for row in self.sensor_matrix],
        }
        if self.compensation is not None:
            out["compensation_deg"] = {
                axis: {f"toward_{other}": float(np.degrees(value))
                       for other, value in angles_.items()}
                for axis, angles_ in self.compensation.items()}
            out["compensation_std_deg"] = {
                axis: {f"toward_{other}": float(np.degrees(value))
                       for other, value in angles_.items()}
                for axis, angles_ in self.compensation_std.items()}
        out["quality"] = self.quality
        return out

    @classmethod
    def from_dict(cls, sensor: str, doc: dict) -> "SensorCalibration":
        try:
            correction = np.asarray(doc["correction_matrix"], dtype=float)
            bias = np.asarray(doc["bias"], dtype=float)
            unit = str(doc["unit"])
        except (KeyError, TypeError, ValueError):
            raise InputError(f"the {sensor} entry lacks a 3 x 3 correction_matrix, bias or "
                             f"unit; recreate it with 'nlpcal compass calibrate'") from None
        if correction.shape != (3, 3) or bias.shape != (3,) or not (
                np.isfinite(correction).all() and np.isfinite(bias).all()):
            raise InputError(f"the {sensor} entry has a malformed correction_matrix or bias; "
                             f"recreate it with 'nlpcal compass calibrate'")
        return cls(sensor=sensor, unit=unit, correction=correction, bias=bias,
                   magnitude=float(doc.get("magnitude", np.nan)),
                   magnitude_source=str(doc.get("magnitude_source", "")),
                   frame=str(doc.get("frame", "")), quality=doc.get("quality", {}))


@dataclass
class CompassCalibration:
    """Both sensors' corrections, how they were found, and what could not be identified."""

    mode: str  # "turns" or "free-rotation"
    magnetometer: SensorCalibration
    accelerometer: SensorCalibration
    identifiability: str
    alignment: dict | None = None  # free-rotation mode: magnetometer-to-accelerometer rotation
    warnings: list = field(default_factory=list)
    input: dict = field(default_factory=dict)

    def apply(self, mag, acc) -> tuple:
        """Calibrated (field [nT], specific force [g]) from raw readings in nT and g."""
        return self.magnetometer.apply(mag), self.accelerometer.apply(acc)

    def to_dict(self) -> dict:
        doc = {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "mode": self.mode,
            "conventions": {
                "world": "NED (x magnetic north, y east, z down)",
                "body": "housing: x forward, y right, z down",
                "attitude": "C = R_x(roll) R_y(pitch) R_z(heading); v_body = C v_world (Eq. 9)",
                "accelerometer": "specific force: at rest the body components of (0, 0, -1) g",
                "model": "reading = diag(1 + s) E v_body + bias; calibrated v = K (reading - bias)",
                "mounting_angles": "row x of E ~ (1, tan alpha_xy, tan alpha_xz), row y ~ "
                                   "(tan beta_yx, 1, tan beta_yz), row z ~ (tan gamma_zx, "
                                   "tan gamma_zy, 1) (Eq. 3)",
            },
            "identifiability": self.identifiability,
            "magnetometer": self.magnetometer.to_dict(),
            "accelerometer": self.accelerometer.to_dict(),
        }
        if self.alignment is not None:
            doc["alignment"] = self.alignment
        doc["warnings"] = list(self.warnings)
        doc["input"] = self.input
        return doc

    @classmethod
    def from_dict(cls, doc) -> "CompassCalibration":
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise InputError("not an nlpcal compass calibration (no \"format\": "
                             f"\"{FORMAT}\"); create one with 'nlpcal compass calibrate'")
        if doc.get("version") != FORMAT_VERSION:
            raise InputError(f"compass calibration version {doc.get('version')!r} is not "
                             f"supported (expected {FORMAT_VERSION})")
        for key in ("magnetometer", "accelerometer"):
            if not isinstance(doc.get(key), dict):
                raise InputError(f"the compass calibration has no {key} entry")
        return cls(mode=str(doc.get("mode", "")),
                   magnetometer=SensorCalibration.from_dict("magnetometer", doc["magnetometer"]),
                   accelerometer=SensorCalibration.from_dict("accelerometer", doc["accelerometer"]),
                   identifiability=str(doc.get("identifiability", "")),
                   alignment=doc.get("alignment"), warnings=list(doc.get("warnings", [])),
                   input=doc.get("input", {}))


# --------------------------------------------------------------------------------------------------
# Validation


def _check_vectors(values, what: str, minimum: int) -> np.ndarray:
    try:
        values = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what} readings must be numeric, an (N, 3) array-like") from None
    if values.ndim != 2 or values.shape[1] != 3:
        raise InputError(f"{what} readings must have shape (N, 3), got {values.shape}")
    if not np.isfinite(values).all():
        raise InputError(f"{what} readings contain NaN or infinite values; drop or fix those rows")
    if values.shape[0] < minimum:
        raise InputError(f"got {values.shape[0]} {what} samples, need at least {minimum}")
    return values


def parse_turn_labels(labels) -> tuple:
    """Housing axis (0, 1, 2) and turn name of each sample from labels like x, y, z, y2, z_b.

    Raises InputError naming the first labels that are not an axis letter plus an optional suffix.
    """
    labels = pd.Series(labels, dtype=object)
    names = labels.map(lambda v: "" if v is None or (isinstance(v, float) and np.isnan(v))
                       else str(v).strip().lower())
    matched = names.map(_TURN_LABEL.match)
    bad = names[matched.isna()]
    if len(bad):
        shown = ", ".join(repr(v) for v in pd.unique(bad)[:5])
        raise InputError(
            f"{len(bad)} sample(s) have a turn label that is not x, y or z with an optional suffix "
            f"(e.g. y2): {shown}; label each sample with the housing axis it was turned about")
    axes = np.array([model.AXES.index(m.group(1)) for m in matched], dtype=int)
    return axes, names.to_numpy(dtype=object)


def _check_turns(axes, names) -> dict:
    """{turn name: sample indices}; every axis needs a turn, every turn MIN_TURN_SAMPLES samples."""
    turns = {name: np.flatnonzero(names == name) for name in pd.unique(names)}
    short = {name: len(idx) for name, idx in turns.items() if len(idx) < MIN_TURN_SAMPLES}
    if short:
        shown = ", ".join(f"{name} ({count})" for name, count in short.items())
        raise InputError(f"turn(s) with fewer than {MIN_TURN_SAMPLES} samples: {shown}; record a "
                         f"full turn with a sample at least every 60 degrees")
    missing = [model.AXES[k] for k in range(3) if not np.any(axes == k)]
    if missing:
        raise InputError(f"no turn about the housing {' and '.join(missing)} axis; the turn "
                         f"protocol needs turns about x, y and z")
    return turns


# --------------------------------------------------------------------------------------------------
# Turn mode: compensation angles (Eq. 4-8), then the axis-aligned ellipsoid


def within_turn_scatter(readings, turns: dict, names: list) -> tuple:
    """Pooled within-turn scatter sum_t sum_i (m_i - mean_t)(m_i - mean_t)^T over the named turns.

    Returns (S (3, 3), samples, degrees of freedom lost to the turn means).
    """
    S = np.zeros((3, 3))
    count = 0
    for name in names:
        block = readings[turns[name]]
        centred = block - block.mean(axis=0)
        S += centred.T @ centred
        count += len(block)
    return S, count, len(names)


def compensation_angles(readings, turns: dict, axis: int, *, sensor: str = "sensor",
                        scale: float | None = None) -> dict:
    """The compensation angles of sensor axis `axis` from the turns about that housing axis.

    The compensated output along k, m_k - tan(c_j) m_j - tan(c_l) m_l (Eq. 4, 5 in [1]), is made
    constant over every turn about k (Eq. 6-8) by one NLP. For small errors c_j is the mounting
    angle of sensor axis k toward j (Eq. 3); exactly, (1, -tan c_j, -tan c_l) is proportional to
    row k of the inverse sensor matrix, whatever the sensitivities.

    Parameters
    ----------
    readings : (N, 3) array
        Raw outputs of one sensor, any unit.
    turns : dict
        {turn name: sample indices}; the names starting with the axis letter are used.
    axis : int
        Housing axis 0, 1, 2 (x, y, z).
    scale : float, optional
        Typical size of the sensed vector, for the excitation check; default the RMS spread.

    Returns a dict with the angles [rad], their standard deviations [rad] (Gauss-Newton, scaled by
    the residual variance), the residual RMS of the compensated output (in the readings' unit), the
    turn names and the IPOPT record.
    """
    k = axis
    j, l = [i for i in range(3) if i != k]
    letter = model.AXES[k]
    names = [name for name in turns if name.startswith(letter)]
    S, count, lost = within_turn_scatter(readings, turns, names)
    order = [k, j, l]
    S = S[np.ix_(order, order)]
    sub = S[1:, 1:]
    if scale is None:
        centred = readings - readings.mean(axis=0)
        scale = float(np.sqrt(np.mean(np.sum(centred ** 2, axis=1))))
    smallest = float(np.linalg.eigvalsh(sub)[0])
    if not smallest > (MIN_EXCITATION * scale) ** 2 * count:
        raise InputError(
            f"the {sensor}'s {model.AXES[j]} and {model.AXES[l]} outputs hardly change over the "
            f"turns labelled {letter}, so its {letter}-axis mounting cannot be found; check that "
            f"they are full turns about the housing {letter} axis, and add one with that axis "
            f"away from the sensed field (for the accelerometer, {letter} horizontal)")
    excitation = float(sub[0, 0] + sub[1, 1])
    bound = np.radians(MAX_COMPENSATION_DEG)
    out = _checked(solve(_solver("compensation"), x0=np.zeros(2),
                         p=(S / excitation).ravel(order="F"), lbx=-bound, ubx=bound),
                   f"{sensor} {letter}-axis compensation (Eq. 6-8)")
    c = out.x
    if np.any(np.abs(c) > 0.999 * bound):
        raise InputError(
            f"the {sensor}'s {letter}-axis compensation angles reach the {MAX_COMPENSATION_DEG:g} "
            f"degree bound; the samples labelled {letter} are probably not turns about the housing "
            f"{letter} axis")
    dof = count - lost - 2
    objective = max(out.f, 0.0)  # may round to -1e-20 on noiseless data
    variance = objective * excitation / max(dof, 1)
    covariance = variance * np.linalg.inv(sub)  # Gauss-Newton in tan(c); d tan / dc ~ 1
    std = np.sqrt(np.diag(covariance)) * np.cos(c) ** 2
    return {
        "angles": {model.AXES[j]: float(c[0]), model.AXES[l]: float(c[1])},
        "std": {model.AXES[j]: float(std[0]), model.AXES[l]: float(std[1])},
        "residual_rms": float(np.sqrt(objective * excitation / max(count - lost, 1))),
        "turns": names,
        "ipopt": _ipopt_record(out),
    }


def _compensation_matrix(compensation: dict) -> np.ndarray:
    """W: row k = e_k - tan(c_kj) e_j - tan(c_kl) e_l (Eq. 4, 5 for each axis)."""
    W = np.eye(3)
    for k, letter in enumerate(model.AXES):
        for other, angle in compensation[letter].items():
            W[k, model.AXES.index(other)] = -np.tan(angle)  # Eq. 4, 5
    return W


def _normalise(u) -> tuple:
    centre = u.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum((u - centre) ** 2, axis=1))))
    if not spread > 0:
        raise InputError("all samples are equal; calibration needs many attitudes")
    return (u - centre) / spread, centre, spread


def _axis_features(z) -> np.ndarray:
    return np.column_stack([z ** 2, z, np.ones(len(z))])


def fit_axis_ellipsoid(u, *, magnitude: float, seed: str = "linear",
                       sensor: str = "sensor") -> dict:
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
    z, centre, spread = _normalise(u)
    phi = _axis_features(z)
    Phi = phi.T @ phi / len(z)
    x0, seed_used = np.r_[np.ones(3), np.zeros(3)], "centroid"
    if seed == "linear":
        q, *_ = np.linalg.lstsq(phi[:, :6], np.ones(len(z)), rcond=None)
        A, B = q[:3], q[3:]
        if np.all(A > 0):
            o = -B / (2 * A)
            G = 1 + np.sum(A * o ** 2)
            if G > 0:
                x0, seed_used = np.r_[A / G, o], "linear"
    elif seed != "centroid":
        raise InputError(f"unknown ellipsoid seed {seed!r}; expected linear or centroid")
    lbx = np.r_[np.full(3, 1e-6), np.full(3, -np.inf)]
    out = _checked(solve(_solver("axis_ellipsoid"), x0=x0, p=Phi.ravel(order="F"), lbx=lbx),
                   f"{sensor} ellipsoid fit")
    a, o = out.x[:3], out.x[3:]
    gains = magnitude * np.sqrt(a) / spread
    offset = centre + spread * o
    v = (u - offset) * gains
    residual = np.linalg.norm(v, axis=1) - magnitude
    return {"gains": gains, "offset": offset,
            "residual_rms": float(np.sqrt(np.mean(residual ** 2))),
            "seed": seed_used, "ipopt": _ipopt_record(out)}


def _calibrate_sensor_turns(readings, turns, *, sensor: str, unit: str, magnitude: float | None,
                            seed: str) -> tuple:
    warnings = []
    centred = readings - readings.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum(centred ** 2, axis=1))))
    compensation, compensation_std, quality_turns, ipopt = {}, {}, {}, {}
    for k, letter in enumerate(model.AXES):
        result = compensation_angles(readings, turns, k, sensor=sensor, scale=scale)
        compensation[letter] = result["angles"]
        compensation_std[letter] = result["std"]
        ipopt[f"compensation_{letter}"] = result["ipopt"]
    W = _compensation_matrix(compensation)
    u = readings @ W.T
    fit = fit_axis_ellipsoid(u, magnitude=1.0 if magnitude is None else magnitude, seed=seed,
                             sensor=sensor)
    ipopt["ellipsoid"] = fit["ipopt"]
    K = np.diag(fit["gains"]) @ W
    source = "given"
    if magnitude is None:  # scale gauge: det K = 1, i.e. geometric-mean sensitivity ~ 1
        factor = abs(np.linalg.det(K)) ** (-1.0 / 3.0)
        K = K * factor
        magnitude = factor
        source = ESTIMATED_SCALE
    bias = np.linalg.solve(W, fit["offset"])
    v = (readings - bias) @ K.T
    norms = np.linalg.norm(v, axis=1)
    for name, idx in turns.items():
        k = model.AXES.index(name[0])
        spread = float(np.std(v[idx, k]))
        quality_turns[name] = spread
        if spread > TURN_ERROR_FRACTION * magnitude:
            raise InputError(
                f"turn {name!r} does not look like a turn about the housing {name[0]} axis: the "
                f"{sensor}'s calibrated {name[0]} component varies by "
                f"{100 * spread / magnitude:.2g}% of the field over it; check the turn labels")
        if spread > TURN_WARN_FRACTION * magnitude:
            warnings.append(
                f"{sensor}: the calibrated {name[0]} component varies by {spread:.4g} {unit} RMS "
                f"over turn {name!r} ({100 * spread / magnitude:.2g}% of the field); is it really "
                f"a turn about the housing {name[0]} axis?")
    calibration = SensorCalibration(
        sensor=sensor, unit=unit, correction=K, bias=bias, magnitude=float(magnitude),
        magnitude_source=source, frame="housing",
        compensation=compensation, compensation_std=compensation_std,
        quality={
            "turn_axis_residual_rms": quality_turns,
            "magnitude_residual_rms": float(np.sqrt(np.mean((norms - magnitude) ** 2))),
            "ellipsoid_seed": fit["seed"],
            "ipopt": ipopt,
        })
    return calibration, warnings


TURN_IDENTIFIABILITY = (
    "turn mode: each sensor's six mounting angles (relative to the housing axes), zero bias and "
    "sensitivity are identified. The magnetometer's overall scale is not, unless the field is "
    "given: it is then fixed by det(correction_matrix) = 1; heading does not depend on it.")


def calibrate_turns(mag, acc, turn_labels, *, field_nt: float | None = None,
                    ellipsoid_seed: str = "linear") -> CompassCalibration:
    """The paper's protocol: turns about the housing axes, then ellipsoid fits. [1]

    Parameters
    ----------
    mag : (N, 3) array
        Magnetometer readings. [nT]
    acc : (N, 3) array
        Accelerometer readings. [g]
    turn_labels : sequence of N str
        Housing axis of each sample's turn, x, y or z plus an optional suffix separating repeated
        turns about one axis (y2).
    field_nt : float, optional
        Local total field; default estimated under det(correction_matrix) = 1. [nT]
    ellipsoid_seed : {"linear", "centroid"}
        Start of the ellipsoid NLPs.
    """
    mag = _check_vectors(mag, "magnetometer", 3 * MIN_TURN_SAMPLES)
    acc = _check_vectors(acc, "accelerometer", 3 * MIN_TURN_SAMPLES)
    if len(mag) != len(acc) or len(turn_labels) != len(mag):
        raise InputError(f"got {len(mag)} magnetometer, {len(acc)} accelerometer samples and "
                         f"{len(turn_labels)} turn labels; they must be the same rows")
    if field_nt is not None and not (np.isfinite(field_nt) and field_nt > 0):
        raise InputError(f"the field must be a positive number of nT, got {field_nt}")
    axes, names = parse_turn_labels(turn_labels)
    turns = _check_turns(axes, names)
    mag_cal, mag_warn = _calibrate_sensor_turns(mag, turns, sensor="magnetometer", unit="nT",
                                                magnitude=field_nt, seed=ellipsoid_seed)
    acc_cal, acc_warn = _calibrate_sensor_turns(acc, turns, sensor="accelerometer", unit="g",
                                                magnitude=1.0, seed=ellipsoid_seed)
    acc_cal.magnitude_source = GRAVITY_SCALE
    return CompassCalibration(
        mode="turns", magnetometer=mag_cal, accelerometer=acc_cal,
        identifiability=TURN_IDENTIFIABILITY, warnings=mag_warn + acc_warn,
        input={"samples": int(len(mag)),
               "turns": {name: int(len(idx)) for name, idx in turns.items()}})


# --------------------------------------------------------------------------------------------------
# Free-rotation mode: general ellipsoids, then the dip-angle constancy


def _general_features(z) -> np.ndarray:
    x, y, w = z[:, 0], z[:, 1], z[:, 2]
    return np.column_stack([x * x, y * y, w * w, x * y, x * w, y * w, x, y, w, np.ones(len(z))])


def fit_general_ellipsoid(m, *, magnitude: float, seed: str = "linear",
                          sensor: str = "sensor") -> dict:
    """General ellipsoid v = L (m - o), L symmetric positive definite, |v| = magnitude, as an NLP.

    The symmetric L is the gauge: a rotation of the sensor triad cannot be seen in an ellipsoid, so
    the correction closest to no rotation is chosen.

    Returns L (output unit per input unit), o (input unit), the RMS of |v| - magnitude, the
    condition number of the design, the seed used and the IPOPT record.
    """
    z, centre, spread = _normalise(m)
    phi = _general_features(z)
    design = phi[:, :9]
    singular = np.linalg.svd(design / np.sqrt(len(z)), compute_uv=False)
    condition = float(singular[0] / singular[-1]) if singular[-1] > 0 else np.inf
    if not condition < 1e5:
        raise InputError(
            f"the {sensor} samples cover too few directions for an ellipsoid fit (they lie near a "
            f"plane or a circle); turn the housing through many different attitudes")
    x0, seed_used = np.r_[1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], "centroid"
    if seed == "linear":
        q, *_ = np.linalg.lstsq(design, np.ones(len(z)), rcond=None)
        A = np.array([[q[0], q[3] / 2, q[4] / 2], [q[3] / 2, q[1], q[5] / 2],
                      [q[4] / 2, q[5] / 2, q[2]]])
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
    out = _checked(solve(_solver("general_ellipsoid"), x0=x0, p=Phi.ravel(order="F"),
                         lbg=np.full(3, 1e-9), ubg=np.full(3, np.inf)),
                   f"{sensor} ellipsoid fit")
    a = out.x
    A = np.array([[a[0], a[3], a[4]], [a[3], a[1], a[5]], [a[4], a[5], a[2]]])
    w, V = np.linalg.eigh(A)
    if np.any(w <= 0):
        raise SolveError(f"the {sensor} ellipsoid fit did not give an ellipsoid", out.status)
    L = magnitude * (V @ np.diag(np.sqrt(w)) @ V.T) / spread
    offset = centre + spread * a[6:9]
    v = (m - offset) @ L.T
    residual = np.linalg.norm(v, axis=1) - magnitude
    return {"L": L, "offset": offset, "residual_rms": float(np.sqrt(np.mean(residual ** 2))),
            "condition": condition, "seed": seed_used, "ipopt": _ipopt_record(out)}


def _gibbs_matrix(r) -> np.ndarray:
    rx = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    return np.eye(3) + 2 / (1 + r @ r) * (rx + rx @ rx)


def dip_alignment(down, field_dir) -> dict:
    """Rotation R of the magnetometer frame into the accelerometer frame from dip constancy.

    Minimises mean_i (d_i^T R b_i - sin I)^2 over R and the dip I (an NLP): at rest, the angle
    between gravity and the field is the same in every attitude. Identifiable only as far as the
    attitudes differ: rotations of the housing about a single axis leave the component of R about
    that axis (in body coordinates) undetermined; the standard deviations returned show it.

    Parameters
    ----------
    down : (N, 3) array
        Calibrated gravity directions (unit vectors, accelerometer frame).
    field_dir : (N, 3) array
        Calibrated field directions (unit vectors, magnetometer frame).

    Returns R, the rotation vector [rad], its standard deviations [rad], the dip [rad] and its
    standard deviation, the residual RMS of the dip [rad] before and after, and the IPOPT record.
    """
    n = len(down)
    psi = np.column_stack([np.einsum("ni,nj->nij", down, field_dir).reshape(n, 9), np.ones(n)])
    Psi = psi.T @ psi / n
    c0 = float(np.mean(np.sum(down * field_dir, axis=1)))
    out = _checked(solve(_solver("dip_alignment"), x0=np.r_[0.0, 0.0, 0.0, c0],
                         p=Psi.ravel(order="F"), lbx=np.r_[np.full(3, -0.5), -1.0],
                         ubx=np.r_[np.full(3, 0.5), 1.0]),
                   "magnetometer-to-accelerometer alignment (dip constancy)")
    r, c = out.x[:3], float(out.x[3])
    R = _gibbs_matrix(r)
    rb = field_dir @ R.T
    residual = np.sum(down * rb, axis=1) - c
    # Gauss-Newton information of (small rotation delta applied after R, c):
    # d/d delta of d^T exp([delta]x) R b = (R b x d)
    J = np.column_stack([np.cross(rb, down), -np.ones(n)])
    variance = float(residual @ residual) / max(n - 4, 1)
    # A free-rotation log is a time series: neighbouring residuals alike carry less information.
    rho = lag1_autocorrelation(residual)
    try:
        covariance = variance * np.linalg.inv(J.T @ J)
        std = np.sqrt(np.maximum(np.diag(covariance), 0)) * standard_error_inflation(rho)
    except np.linalg.LinAlgError:
        std = np.full(4, np.inf)
    angle = 2 * np.arctan(np.linalg.norm(r))
    axis = r / np.linalg.norm(r) if np.linalg.norm(r) > 0 else np.zeros(3)
    before = np.sum(down * field_dir, axis=1)
    slope = max(np.sqrt(1 - c ** 2), 1e-12)  # d sin(I) / dI: residuals of sin(I) to angles
    return {"R": R, "rotation": angle * axis, "rotation_std": std[:3], "dip": float(np.arcsin(c)),
            "dip_std": float(std[3] / slope),
            "dip_residual_rms_before": float(np.std(before) / slope),
            "dip_residual_rms": float(np.sqrt(np.mean(residual ** 2)) / slope),
            "residual_lag1_autocorrelation": rho,
            "ipopt": _ipopt_record(out)}


FREE_IDENTIFIABILITY = (
    "free-rotation mode: per sensor, the zero bias and a symmetric correction (sensitivities and "
    "non-orthogonality) are identified by its own ellipsoid fit, and the rotation of the "
    "magnetometer relative to the accelerometer by the constancy of the dip angle. Not "
    "identifiable: the orientation of the sensor pair relative to the housing (a rotation common "
    "to both sensors changes neither ellipsoid nor the dip), so attitudes refer to the "
    "accelerometer frame with its symmetric correction, not to the housing axes; 'mounting_deg' "
    "are angles relative to that frame. Components of the magnetometer-to-accelerometer rotation "
    "about body axes the housing never left are not identifiable either (see alignment."
    "rotation_std_deg). The magnetometer's overall scale is fixed by the given field or by "
    "det(correction_matrix) = 1.")


def calibrate_free(mag, acc, *, field_nt: float | None = None, ellipsoid_seed: str = "linear",
                   rest_tolerance: float | None = DEFAULT_REST_TOLERANCE) -> CompassCalibration:
    """Free-rotation mode: each sensor's general ellipsoid fit, then the dip-angle constancy.

    Parameters
    ----------
    mag : (N, 3) array
        Magnetometer readings, taken at rest (or moving slowly) in many attitudes. [nT]
    acc : (N, 3) array
        Accelerometer readings of the same rows. [g]
    field_nt : float, optional
        Local total field; default estimated under det(correction_matrix) = 1. [nT]
    ellipsoid_seed : {"linear", "centroid"}
        Start of the ellipsoid NLPs.
    rest_tolerance : float or None
        Samples whose calibrated specific force differs from 1 g by more than this are taken as
        moving: they are left out of the accelerometer fit (refitted until the kept set no longer
        changes, at most REST_ITERATIONS times) and of the dip alignment, and kept for the
        magnetometer fit. None keeps every sample. [g]
    """
    mag = _check_vectors(mag, "magnetometer", MIN_FREE_SAMPLES)
    acc = _check_vectors(acc, "accelerometer", MIN_FREE_SAMPLES)
    if len(mag) != len(acc):
        raise InputError(f"got {len(mag)} magnetometer and {len(acc)} accelerometer samples; they "
                         f"must be the same rows")
    if field_nt is not None and not (np.isfinite(field_nt) and field_nt > 0):
        raise InputError(f"the field must be a positive number of nT, got {field_nt}")
    if rest_tolerance is not None and not (np.isfinite(rest_tolerance) and rest_tolerance > 0):
        raise InputError(f"the rest tolerance must be a positive number of g, got {rest_tolerance}")
    warnings = []
    mag_fit = fit_general_ellipsoid(mag, magnitude=1.0, seed=ellipsoid_seed, sensor="magnetometer")
    rest = np.ones(len(acc), dtype=bool)
    iterations = 0
    while True:
        acc_fit = fit_general_ellipsoid(acc[rest], magnitude=1.0, seed=ellipsoid_seed,
                                        sensor="accelerometer (samples at rest)")
        a = (acc - acc_fit["offset"]) @ acc_fit["L"].T
        if rest_tolerance is None or iterations == REST_ITERATIONS:
            break
        iterations += 1
        new_rest = np.abs(np.linalg.norm(a, axis=1) - 1.0) <= rest_tolerance
        if new_rest.sum() < MIN_FREE_SAMPLES:
            raise InputError(
                f"only {int(new_rest.sum())} samples look at rest (calibrated |acc| within "
                f"{rest_tolerance:g} g of 1 g); record more slow or still attitudes or pass a "
                f"larger rest tolerance")
        if np.array_equal(new_rest, rest):
            break
        rest = new_rest
    if rest.sum() < 0.5 * len(acc):
        warnings.append(f"only {int(rest.sum())} of {len(acc)} samples look at rest (calibrated "
                        f"|acc| within {rest_tolerance:g} g of 1 g); the accelerometer fit and the "
                        f"alignment use those alone")
    b = (mag[rest] - mag_fit["offset"]) @ mag_fit["L"].T
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    d = -a[rest] / np.linalg.norm(a[rest], axis=1, keepdims=True)
    align = dip_alignment(d, b)
    K_mag = align["R"] @ mag_fit["L"]
    if field_nt is None:
        factor = abs(np.linalg.det(K_mag)) ** (-1.0 / 3.0)
        magnitude, source = factor, ESTIMATED_SCALE
    else:
        magnitude, source = float(field_nt), "given"
    K_mag = K_mag * magnitude
    rotation_std_deg = np.degrees(align["rotation_std"])
    poorly = [model.AXES[i] for i in range(3) if not rotation_std_deg[i] <= ALIGNMENT_WARN_STD_DEG]
    if poorly:
        warnings.append(
            f"the magnetometer-to-accelerometer rotation about body {', '.join(poorly)} is poorly "
            f"determined (std {', '.join(f'{s:.2g}' for s in rotation_std_deg)} deg about "
            f"x, y, z); "
            f"the log needs more varied attitudes")
    mag_norm = np.linalg.norm((mag - mag_fit["offset"]) @ K_mag.T, axis=1)
    acc_norm = np.linalg.norm(a[rest], axis=1)
    mag_cal = SensorCalibration(
        sensor="magnetometer", unit="nT", correction=K_mag, bias=mag_fit["offset"],
        magnitude=float(magnitude), magnitude_source=source,
        frame="accelerometer (rotated into it by the dip-angle constancy)",
        quality={"magnitude_residual_rms": float(np.sqrt(np.mean((mag_norm - magnitude) ** 2))),
                 "ellipsoid_condition": mag_fit["condition"], "ellipsoid_seed": mag_fit["seed"],
                 "ipopt": {"ellipsoid": mag_fit["ipopt"], "alignment": align["ipopt"]}})
    acc_cal = SensorCalibration(
        sensor="accelerometer", unit="g", correction=acc_fit["L"], bias=acc_fit["offset"],
        magnitude=1.0, magnitude_source=GRAVITY_SCALE,
        frame="accelerometer, symmetric correction (orientation relative to the housing unknown)",
        quality={"magnitude_residual_rms": float(np.sqrt(np.mean((acc_norm - 1.0) ** 2))),
                 "rest_samples": int(rest.sum()), "rest_tolerance_g": rest_tolerance,
                 "rest_refits": iterations,
                 "ellipsoid_condition": acc_fit["condition"], "ellipsoid_seed": acc_fit["seed"],
                 "ipopt": {"ellipsoid": acc_fit["ipopt"]}})
    alignment = {
        "rotation_deg": [float(v) for v in np.degrees(align["rotation"])],
        "rotation_std_deg": [float(v) for v in rotation_std_deg],
        "rotation_matrix": [[float(v) for v in row] for row in align["R"]],
        "dip_deg": float(np.degrees(align["dip"])),
        "dip_std_deg": float(np.degrees(align["dip_std"])),
        "dip_residual_rms_deg_before": float(np.degrees(align["dip_residual_rms_before"])),
        "dip_residual_rms_deg": float(np.degrees(align["dip_residual_rms"])),
        "residual_lag1_autocorrelation": align["residual_lag1_autocorrelation"],
        "note": "standard deviations widened for the autocorrelation of the dip residuals; "
                "rotation vector (axis times angle) taking the magnetometer's calibrated frame "
                "into the accelerometer's, body x, y, z components",
    }
    return CompassCalibration(mode="free-rotation", magnetometer=mag_cal, accelerometer=acc_cal,
                              identifiability=FREE_IDENTIFIABILITY, alignment=alignment,
                              warnings=warnings, input={"samples": int(len(mag))})


# --------------------------------------------------------------------------------------------------
# Attitude and evaluation


@dataclass
class Attitude:
    """Roll, pitch and heading [deg] per sample, and warnings."""

    roll_deg: np.ndarray
    pitch_deg: np.ndarray
    heading_deg: np.ndarray
    near_vertical: int
    warnings: list


def attitude(calibration: CompassCalibration, mag, acc, *,
             declination_deg: float = 0.0) -> Attitude:
    """Roll, pitch and heading from raw readings through the calibration. Eq. 2, 9 and 10 in [1].

    Parameters
    ----------
    mag : (N, 3) array
        Magnetometer readings. [nT]
    acc : (N, 3) array
        Accelerometer readings. [g]
    declination_deg : float
        Added to the magnetic heading to give true heading. [deg]
    """
    mag = _check_vectors(mag, "magnetometer", 1)
    acc = _check_vectors(acc, "accelerometer", 1)
    if len(mag) != len(acc):
        raise InputError(f"got {len(mag)} magnetometer and {len(acc)} accelerometer samples")
    if not np.isfinite(declination_deg):
        raise InputError("the declination must be a finite number of degrees")
    b, a = calibration.apply(mag, acc)
    roll, pitch, heading = model.attitude_from_vectors(a, b, np.radians(declination_deg))  # Eq. 10
    pitch_deg = np.degrees(pitch)
    near = int(np.sum(np.abs(pitch_deg) > NEAR_VERTICAL_DEG))
    warnings = []
    if near:
        warnings.append(f"{near} sample(s) have |pitch| > {NEAR_VERTICAL_DEG:g} degrees, where "
                        f"roll and heading are undefined (only their sum or difference is); treat "
                        f"those values with caution")
    return Attitude(np.degrees(roll), pitch_deg, np.degrees(heading), near, warnings)


def wrap_deg(angle):
    """Angle difference wrapped to [-180, 180). [deg]"""
    return np.mod(np.asarray(angle, dtype=float) + 180.0, 360.0) - 180.0


def _stats(errors) -> dict:
    if len(errors) == 0:
        return {"max_abs": None, "rms": None, "mean": None}
    return {"max_abs": float(np.max(np.abs(errors))), "rms": float(np.sqrt(np.mean(errors ** 2))),
            "mean": float(np.mean(errors))}


def evaluate(estimate, truth, *, pitch_bands=DEFAULT_PITCH_BANDS,
             remove_heading_offset: bool = False) -> dict:
    """Attitude error statistics overall and per band of |true pitch|, like Table 2 of [1].

    Parameters
    ----------
    estimate, truth : (N, 3) arrays
        Roll, pitch, heading. [deg]
    pitch_bands : sequence
        Increasing edges of |true pitch|; the last band includes its upper edge. [deg]
    remove_heading_offset : bool
        Subtract the circular mean heading error first (a reference whose north is arbitrary). 

    Returns a dict with the count, per angle max |error|, RMS and mean [deg], overall and per band;
    errors are estimate - truth wrapped to [-180, 180).
    """
    estimate = np.atleast_2d(np.asarray(estimate, dtype=float))
    truth = np.atleast_2d(np.asarray(truth, dtype=float))
    if estimate.shape != truth.shape or estimate.shape[1:] != (3,):
        raise InputError(f"estimate and truth must both be (N, 3) roll, pitch, heading; got "
                         f"{estimate.shape} and {truth.shape}")
    valid = np.isfinite(estimate).all(axis=1) & np.isfinite(truth).all(axis=1)
    if not valid.any():
        raise InputError("no row has finite estimated and true roll, pitch and heading")
    edges = np.asarray(pitch_bands, dtype=float)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0) or edges[0] < 0:
        raise InputError(f"pitch bands must be at least two increasing non-negative edges, got "
                         f"{list(pitch_bands)}")
    errors = wrap_deg(estimate[valid] - truth[valid])
    offset = None
    if remove_heading_offset:
        offset = float(np.degrees(np.angle(np.mean(np.exp(1j * np.radians(errors[:, 2]))))))
        errors[:, 2] = wrap_deg(errors[:, 2] - offset)
    pitch = np.abs(truth[valid, 1])

    def block(mask):
        e = errors[mask]
        return {"n": int(mask.sum()), "roll": _stats(e[:, 0]), "pitch": _stats(e[:, 1]),
                "heading": _stats(e[:, 2])}

    bands = []
    for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        last = i == len(edges) - 2
        mask = (pitch >= lo) & ((pitch <= hi) if last else (pitch < hi))
        bands.append({"pitch_min_deg": float(lo), "pitch_max_deg": float(hi), **block(mask)})
    return {"overall": block(np.ones(len(errors), dtype=bool)), "bands": bands,
            "heading_offset_deg": offset, "rows_skipped": int((~valid).sum())}


# --------------------------------------------------------------------------------------------------
# Replica of the paper's experiment


#: Noise of the replica per axis at noise=None: magnetometer [nT], accelerometer [g].
REPLICA_MAG_NOISE_NT = 10.0
REPLICA_ACC_NOISE_G = 0.2e-3


def qiu2017_replica(*, seed: int = 0, noise: float | None = None, n: int | None = None) -> dict:
    """The paper's four turns (48 samples) and `n` random attitudes, with known errors and noise.

    Turns (a sample every 30 degrees, starting level at heading 30 degrees): about housing x, y,
    z; then the housing rolled 90 degrees and turned about the table's horizontal axis, which is
    then the housing z axis (label z2): the paper's "table X set to 90 degrees, one turn about Y".
    That turn is what gives the accelerometer's z-axis mounting (the level turn about z does not
    move gravity).

    Parameters
    ----------
    seed : int
        Random seed of the errors, attitudes and noise.
    noise : float, optional
        Magnetometer noise per axis [nT], default 10; the accelerometer's is 0.2 mg per 10 nT.
    n : int, optional
        Number of random test attitudes (pitch within +-85 degrees), default 2000.
    """
    rng = np.random.default_rng(seed)
    mag_noise = REPLICA_MAG_NOISE_NT if noise is None else float(noise)
    if not (np.isfinite(mag_noise) and mag_noise >= 0):
        raise InputError(f"noise must be a non-negative number of nT, got {noise}")
    acc_noise = REPLICA_ACC_NOISE_G * mag_noise / REPLICA_MAG_NOISE_NT
    n = 2000 if n is None else int(n)
    if n < 1:
        raise InputError(f"n must be a positive number of test attitudes, got {n}")
    field_total, dip_deg = 54000.0, 58.5
    truth = {
        "magnetometer": {"mounting_deg": rng.uniform(-1.5, 1.5, 6), "sensitivity":
                         rng.uniform(-0.03, 0.03, 3), "bias": rng.uniform(-2000, 2000, 3)},
        "accelerometer": {"mounting_deg": rng.uniform(-1.5, 1.5, 6), "sensitivity":
                          rng.uniform(-0.03, 0.03, 3), "bias": rng.uniform(-0.03, 0.03, 3)},
    }
    B = model.field_ned(field_total, np.radians(dip_deg))

    def readings(C, noise_rng):
        f_body, b_body = model.body_vectors(C, B)
        out = {}
        for name, v, sd in (("magnetometer", b_body, mag_noise),
                            ("accelerometer", f_body, acc_noise)):
            t = truth[name]
            out[name] = model.sensor_reading(v, np.radians(t["mounting_deg"]), t["sensitivity"],
                                             t["bias"]) + noise_rng.normal(0, sd, v.shape)
        return out

    steps = np.radians(np.arange(0, 360, 30))
    C0 = model.attitude_matrix(0.0, 0.0, np.radians(30.0))
    turn_C = {"x": model.rotation_x(steps) @ C0, "y": model.rotation_y(steps) @ C0,
              "z": model.rotation_z(steps) @ C0,
              "z2": model.rotation_z(steps) @ model.rotation_x(np.pi / 2) @ C0}
    C_turns = np.concatenate(list(turn_C.values()))
    labels = np.repeat(list(turn_C), len(steps))
    roll = rng.uniform(-180, 180, n)
    pitch = rng.uniform(-85, 85, n)
    heading = rng.uniform(0, 360, n)
    C_test = model.attitude_matrix(np.radians(roll), np.radians(pitch), np.radians(heading))
    r_turn = readings(C_turns, rng)
    r_test = readings(C_test, rng)

    def frame(r, C, extra):
        ro, pi_, he = (np.degrees(v) + 0.0 for v in model.euler_from_matrix(C))  # no "-0"
        data = dict(extra)
        for name, prefix, unit in (("magnetometer", "m", "nT"), ("accelerometer", "a", "g")):
            for i, axis in enumerate(model.AXES):
                data[f"{prefix}{axis}_{unit}"] = r[name][:, i]
        data.update(true_roll_deg=ro, true_pitch_deg=pi_, true_heading_deg=he)
        return pd.DataFrame(data)

    turns = frame(r_turn, C_turns, {"turn": labels, "step_deg": np.tile(np.degrees(steps), 4)})
    test = frame(r_test, C_test, {})
    doc = {
        "preset": "qiu2017", "seed": int(seed),
        "field": {"total_nT": field_total, "dip_deg": dip_deg},
        "noise": {"magnetometer_nT": mag_noise, "accelerometer_g": acc_noise},
        "conventions":
        "NED world, housing x forward y right z down, C = R_x(roll) R_y(pitch) R_z(heading); "
        "reading = diag(1 + s) E v_body + bias, E from the six angles (Eq. 3)",
        "files": {"turns.csv": "the four turns, 12 samples each, turn label in column 'turn'",
                  "test.csv": f"{n} random attitudes, |pitch| <= 85 deg, true_* columns"},
        "truth": {name: {"mounting_deg": dict(zip(model.ANGLE_NAMES,
                                                  map(float, t["mounting_deg"]))),
                         "sensitivity": [float(v) for v in t["sensitivity"]],
                         "bias": [float(v) for v in t["bias"]],
                         "unit": "nT" if name == "magnetometer" else "g"}
                  for name, t in truth.items()},
    }
    return {"turns": turns, "test": test, "truth": doc}


def write_qiu2017_replica(out_dir, *, seed: int = 0, noise: float | None = None,
                          n: int | None = None) -> list:
    """Write turns.csv, test.csv and truth.json of `qiu2017_replica` into out_dir (atomically).

    Returns the paths written. Suggested use:
    nlpcal compass calibrate DIR/turns.csv --mag-columns mx_nT my_nT mz_nT --acc-columns ax_g
    ay_g az_g --turn-column turn -o compass.json.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a folder")
    out_dir.mkdir(parents=True, exist_ok=True)
    replica = qiu2017_replica(seed=seed, noise=noise, n=n)
    paths = [out_dir / "turns.csv", out_dir / "test.csv", out_dir / "truth.json"]
    io.write_csv_atomic(paths[0], replica["turns"])
    io.write_csv_atomic(paths[1], replica["test"])
    io.write_json_atomic(paths[2], replica["truth"])
    return paths
