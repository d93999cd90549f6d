"""The paper's protocol (Qiu et al. 2017): turns about the housing x, y and z axes give each
sensor axis its compensation angles (Eq. 4-8, one NLP per axis and sensor); then an axis-aligned
ellipsoid fit of the compensated outputs gives zero bias and sensitivity. Everything of the model
reading = diag(1 + s) E v_body + bias is identified, in the housing frame.

References
----------
[1] Qiu et al. (2017), see `nlpcal.models.qiu2017`.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd

from .. import inference, validation
from ..errors import InputError
from ..models import qiu2017 as model
from ..nlp.compass import compensation_nlp
from ..nlp.solver import solve
from .ellipsoids import fit_axis_ellipsoid
from .result import ESTIMATED_SCALE, GRAVITY_SCALE, CompassCalibration, SensorCalibration

#: Fewest samples accepted in one turn (a constant plus two compensation angles, and spares).
MIN_TURN_SAMPLES = 6
#: Bound on the compensation angles; reaching it means the turn labels do not fit the motion. [deg]
MAX_COMPENSATION_DEG = 20.0
#: A turn about axis k must move the other two components by at least this fraction of the field.
MIN_EXCITATION = 0.05
#: Warn when the calibrated component along a turn axis varies by more than this fraction. [1]
TURN_WARN_FRACTION = 0.02
#: Refuse the calibration when it varies by more than this fraction (mislabelled turns). [1]
TURN_ERROR_FRACTION = 0.10

_TURN_LABEL = re.compile(r"^([xyz])([a-z0-9_.\-]*)$")


def parse_turn_labels(labels) -> tuple:
    """Housing axis (0, 1, 2) and turn name of each sample from labels like x, y, z, y2, z_b.

    Raises InputError naming the first labels that are not an axis letter plus an optional suffix.
    """
    labels = pd.Series(labels, dtype=object)
    names = labels.map(
        lambda v: (
            "" if v is None or (isinstance(v, float) and np.isnan(v)) else str(v).strip().lower()
        )
    )
    matched = names.map(_TURN_LABEL.match)
    bad = names[matched.isna()]
    if len(bad):
        shown = ", ".join(repr(v) for v in pd.unique(bad)[:5])
        raise InputError(
            f"{len(bad)} sample(s) have a turn label that is not x, y or z with an optional suffix "
            f"(e.g. y2): {shown}; label each sample with the housing axis it was turned about"
        )
    axes = np.array([model.AXES.index(m.group(1)) for m in matched], dtype=int)
    return axes, names.to_numpy(dtype=object)


def _check_turns(axes, names) -> dict:
    """{turn name: sample indices}; every axis needs a turn, every turn MIN_TURN_SAMPLES samples."""
    turns = {name: np.flatnonzero(names == name) for name in pd.unique(names)}
    short = {name: len(idx) for name, idx in turns.items() if len(idx) < MIN_TURN_SAMPLES}
    if short:
        shown = ", ".join(f"{name} ({count})" for name, count in short.items())
        raise InputError(
            f"turn(s) with fewer than {MIN_TURN_SAMPLES} samples: {shown}; record a "
            f"full turn with a sample at least every 60 degrees"
        )
    missing = [model.AXES[k] for k in range(3) if not np.any(axes == k)]
    if missing:
        raise InputError(
            f"no turn about the housing {' and '.join(missing)} axis; the turn "
            f"protocol needs turns about x, y and z"
        )
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


def compensation_angles(
    readings, turns: dict, axis: int, *, sensor: str = "sensor", scale: float | None = None
) -> dict:
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
        scale = float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))
    smallest = float(np.linalg.eigvalsh(sub)[0])
    if not smallest > (MIN_EXCITATION * scale) ** 2 * count:
        raise InputError(
            f"the {sensor}'s {model.AXES[j]} and {model.AXES[l]} outputs hardly change over the "
            f"turns labelled {letter}, so its {letter}-axis mounting cannot be found; check that "
            f"they are full turns about the housing {letter} axis, and add one with that axis "
            f"away from the sensed field (for the accelerometer, {letter} horizontal)"
        )
    excitation = float(sub[0, 0] + sub[1, 1])
    bound = np.radians(MAX_COMPENSATION_DEG)
    out = solve(
        compensation_nlp(),
        x0=np.zeros(2),
        p=(S / excitation).ravel(order="F"),
        lbx=-bound,
        ubx=bound,
    ).checked(f"{sensor} {letter}-axis compensation (Eq. 6-8)")
    c = out.x
    if np.any(np.abs(c) > 0.999 * bound):
        raise InputError(
            f"the {sensor}'s {letter}-axis compensation angles reach the {MAX_COMPENSATION_DEG:g} "
            f"degree bound; the samples labelled {letter} are probably not turns about the housing "
            f"{letter} axis"
        )
    dof = count - lost - 2
    objective = max(out.f, 0.0)  # may round to -1e-20 on noiseless data
    # Gauss-Newton in tan(c): the information is the scatter of the two other outputs
    uncertainty = inference.estimate(
        sub, residual_variance=objective * excitation / max(dof, 1), dof=dof
    )
    std = (
        uncertainty.standard_errors * np.cos(c) ** 2  # d tan(c) / dc = 1 / cos^2(c)
        if uncertainty.standard_errors is not None
        else np.full(2, np.inf)
    )
    return {
        "angles": {model.AXES[j]: float(c[0]), model.AXES[l]: float(c[1])},
        "std": {model.AXES[j]: float(std[0]), model.AXES[l]: float(std[1])},
        "residual_rms": float(np.sqrt(objective * excitation / max(count - lost, 1))),
        "turns": names,
        "ipopt": out.record(),
    }


def _compensation_matrix(compensation: dict) -> np.ndarray:
    """W: row k = e_k - tan(c_kj) e_j - tan(c_kl) e_l (Eq. 4, 5 for each axis)."""
    W = np.eye(3)
    for k, letter in enumerate(model.AXES):
        for other, angle in compensation[letter].items():
            W[k, model.AXES.index(other)] = -np.tan(angle)  # Eq. 4, 5
    return W


def _calibrate_sensor_turns(
    readings, turns, *, sensor: str, unit: str, magnitude: float | None, seed: str
) -> tuple:
    warnings = []
    centred = readings - readings.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))
    compensation, compensation_std, quality_turns, ipopt = {}, {}, {}, {}
    for k, letter in enumerate(model.AXES):
        result = compensation_angles(readings, turns, k, sensor=sensor, scale=scale)
        compensation[letter] = result["angles"]
        compensation_std[letter] = result["std"]
        ipopt[f"compensation_{letter}"] = result["ipopt"]
    W = _compensation_matrix(compensation)
    u = readings @ W.T
    fit = fit_axis_ellipsoid(
        u, magnitude=1.0 if magnitude is None else magnitude, seed=seed, sensor=sensor
    )
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
                f"{100 * spread / magnitude:.2g}% of the field over it; check the turn labels"
            )
        if spread > TURN_WARN_FRACTION * magnitude:
            warnings.append(
                f"{sensor}: the calibrated {name[0]} component varies by {spread:.4g} {unit} RMS "
                f"over turn {name!r} ({100 * spread / magnitude:.2g}% of the field); is it really "
                f"a turn about the housing {name[0]} axis?"
            )
    calibration = SensorCalibration(
        sensor=sensor,
        unit=unit,
        correction=K,
        bias=bias,
        magnitude=float(magnitude),
        magnitude_source=source,
        frame="housing",
        compensation=compensation,
        compensation_std=compensation_std,
        quality={
            "turn_axis_residual_rms": quality_turns,
            "magnitude_residual_rms": float(np.sqrt(np.mean((norms - magnitude) ** 2))),
            "ellipsoid_seed": fit["seed"],
            "ipopt": ipopt,
        },
    )
    return calibration, warnings


TURN_IDENTIFIABILITY = (
    "turn mode: each sensor's six mounting angles (relative to the housing axes), zero bias and "
    "sensitivity are identified. The magnetometer's overall scale is not, unless the field is "
    "given: it is then fixed by det(correction_matrix) = 1; heading does not depend on it."
)


def calibrate_turns(
    mag,
    acc,
    turn_labels,
    *,
    reference_field: float | None = None,
    field_nt: float | None = None,
    ellipsoid_seed: str = "linear",
) -> CompassCalibration:
    """The paper's protocol: turns about the housing axes, then ellipsoid fits [1].

    Parameters
    ----------
    mag : array_like, shape (N, 3)
        Magnetometer readings (`--mag-columns`). [nT]
    acc : array_like, shape (N, 3)
        Accelerometer readings (`--acc-columns`). [g]
    turn_labels : sequence of N str
        Housing axis of each sample's turn, x, y or z plus an optional suffix separating repeated
        turns about one axis (y2) (`--turn-column`).
    reference_field : float, optional
        Local total field (`--reference-field`); default estimated under
        det(correction_matrix) = 1. [nT]
    field_nt : float, optional
        The former name of `reference_field`, still accepted. [nT]
    ellipsoid_seed : {"linear", "centroid"}
        Start of the ellipsoid NLPs.

    Returns
    -------
    CompassCalibration
        Both sensors' mounting angles, biases and sensitivities.

    Raises
    ------
    InputError
        Unusable readings or labels, or turns that cannot determine the mounting.
    SolveError
        IPOPT failed.

    References
    ----------
    [1] Qiu et al. (2017), see `nlpcal.models.qiu2017`.

    Examples
    --------
    >>> import nlpcal
    >>> from nlpcal.simulation.qiu2017 import replica  # `nlpcal simulate --preset qiu2017`
    >>> turns = replica(seed=0, n=10)["turns"]
    >>> mag, acc = turns[["mx_nT", "my_nT", "mz_nT"]], turns[["ax_g", "ay_g", "az_g"]]
    >>> calibration = nlpcal.calibrate_turns(mag.to_numpy(), acc.to_numpy(), turns["turn"].tolist())
    >>> calibration.mode, calibration.verdict.status
    ('turns', 'ok')
    """
    mag = validation.finite_vectors(mag, "magnetometer readings", minimum=3 * MIN_TURN_SAMPLES)
    acc = validation.finite_vectors(acc, "accelerometer readings", minimum=3 * MIN_TURN_SAMPLES)
    if len(mag) != len(acc) or len(turn_labels) != len(mag):
        raise InputError(
            f"got {len(mag)} magnetometer, {len(acc)} accelerometer samples and "
            f"{len(turn_labels)} turn labels; they must be the same rows"
        )
    field_nt = validation.renamed(reference_field, field_nt, "reference_field", "field_nt")
    if field_nt is not None and not (np.isfinite(field_nt) and field_nt > 0):
        raise InputError(f"the field must be a positive number of nT, got {field_nt}")
    axes, names = parse_turn_labels(turn_labels)
    turns = _check_turns(axes, names)
    mag_cal, mag_warn = _calibrate_sensor_turns(
        mag, turns, sensor="magnetometer", unit="nT", magnitude=field_nt, seed=ellipsoid_seed
    )
    acc_cal, acc_warn = _calibrate_sensor_turns(
        acc, turns, sensor="accelerometer", unit="g", magnitude=1.0, seed=ellipsoid_seed
    )
    acc_cal.magnitude_source = GRAVITY_SCALE
    return CompassCalibration(
        mode="turns",
        magnetometer=mag_cal,
        accelerometer=acc_cal,
        identifiability=TURN_IDENTIFIABILITY,
        warnings=mag_warn + acc_warn,
        input={"samples": len(mag), "turns": {name: len(idx) for name, idx in turns.items()}},
    )
