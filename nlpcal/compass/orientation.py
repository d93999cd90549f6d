"""Roll, pitch and heading through a compass calibration (Eq. 2, 9 and 10 of Qiu et al. 2017),
and their errors against a reference, overall and per band of pitch (like Table 2).

References
----------
[1] Qiu et al. (2017), see `nlpcal.models.qiu2017`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import validation
from ..errors import InputError
from ..models import qiu2017 as model
from .result import CompassCalibration

#: Pitch above which roll and heading become ill-defined and `attitude` warns. [deg]
NEAR_VERTICAL_DEG = 89.0
#: Default pitch bands for `evaluate`, edges of |true pitch|. [deg]
DEFAULT_PITCH_BANDS = (0.0, 30.0, 60.0, 85.0, 90.0)


@dataclass
class Attitude:
    """Roll, pitch and heading [deg] per sample, and warnings."""

    roll_deg: np.ndarray
    pitch_deg: np.ndarray
    heading_deg: np.ndarray
    near_vertical: int
    warnings: list


def attitude(
    calibration: CompassCalibration, mag, acc, *, declination_deg: float = 0.0
) -> Attitude:
    """Roll, pitch and heading from raw readings through the calibration. Eq. 2, 9 and 10 in [1].

    Parameters
    ----------
    calibration : CompassCalibration
        The sensors' corrections.
    mag : array_like, shape (N, 3)
        Magnetometer readings. [nT]
    acc : array_like, shape (N, 3)
        Accelerometer readings. [g]
    declination_deg : float
        Added to the magnetic heading to give true heading (`--declination-deg`). [deg]

    Returns
    -------
    Attitude
        roll_deg, pitch_deg, heading_deg per sample [deg], and warnings (attitudes near vertical,
        where heading is undefined).

    Raises
    ------
    InputError
        Unusable readings.

    References
    ----------
    [1] Qiu et al. (2017), see `nlpcal.models.qiu2017`.

    Examples
    --------
    >>> import nlpcal
    >>> from nlpcal.simulation.qiu2017 import replica
    >>> data = replica(seed=0, n=200)
    >>> turns, test = data["turns"], data["test"]
    >>> mag, acc = ["mx_nT", "my_nT", "mz_nT"], ["ax_g", "ay_g", "az_g"]
    >>> calibration = nlpcal.calibrate_turns(
    ...     turns[mag].to_numpy(), turns[acc].to_numpy(), turns["turn"].tolist()
    ... )
    >>> estimate = nlpcal.attitude(calibration, test[mag].to_numpy(), test[acc].to_numpy())
    >>> estimate.heading_deg.shape
    (200,)
    """
    mag = validation.finite_vectors(mag, "magnetometer readings", minimum=1)
    acc = validation.finite_vectors(acc, "accelerometer readings", minimum=1)
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
        warnings.append(
            f"{near} sample(s) have |pitch| > {NEAR_VERTICAL_DEG:g} degrees, where "
            f"roll and heading are undefined (only their sum or difference is); treat "
            f"those values with caution"
        )
    return Attitude(np.degrees(roll), pitch_deg, np.degrees(heading), near, warnings)


def wrap_deg(angle):
    """Angle difference wrapped to [-180, 180). [deg]"""
    return np.mod(np.asarray(angle, dtype=float) + 180.0, 360.0) - 180.0


def _stats(errors) -> dict:
    if len(errors) == 0:
        return {"max_abs": None, "rms": None, "mean": None}
    return {
        "max_abs": float(np.max(np.abs(errors))),
        "rms": float(np.sqrt(np.mean(errors**2))),
        "mean": float(np.mean(errors)),
    }


def evaluate(
    estimate, truth, *, pitch_bands=DEFAULT_PITCH_BANDS, remove_heading_offset: bool = False
) -> dict:
    """Attitude error statistics overall and per band of |true pitch|, like Table 2 of [1].

    Errors are estimate - truth wrapped to [-180, 180).

    Parameters
    ----------
    estimate : array_like, shape (N, 3)
        Estimated roll, pitch, heading. [deg]
    truth : array_like, shape (N, 3)
        True roll, pitch, heading (`--truth-columns`). [deg]
    pitch_bands : sequence of float
        Increasing edges of |true pitch|; the last band includes its upper edge. [deg]
    remove_heading_offset : bool
        Subtract the circular mean heading error first (a reference whose north is arbitrary).

    Returns
    -------
    dict
        The count, and per angle max |error|, RMS and mean [deg], overall and per band.

    Raises
    ------
    InputError
        Estimate and truth of different shapes, or bands not increasing.

    References
    ----------
    [1] Qiu et al. (2017), see `nlpcal.models.qiu2017`.

    Examples
    --------
    >>> import numpy as np
    >>> import nlpcal
    >>> truth = np.array([[0.0, 10.0, 359.0], [5.0, 40.0, 90.0]])
    >>> estimate = truth + [0.1, -0.1, 2.0]  # heading wraps: 361 deg is 1 deg
    >>> errors = nlpcal.evaluate(estimate, truth)
    >>> errors["overall"]["n"], round(errors["overall"]["heading"]["max_abs"], 6)
    (2, 2.0)
    """
    estimate = np.atleast_2d(np.asarray(estimate, dtype=float))
    truth = np.atleast_2d(np.asarray(truth, dtype=float))
    if estimate.shape != truth.shape or estimate.shape[1:] != (3,):
        raise InputError(
            f"estimate and truth must both be (N, 3) roll, pitch, heading; got "
            f"{estimate.shape} and {truth.shape}"
        )
    valid = np.isfinite(estimate).all(axis=1) & np.isfinite(truth).all(axis=1)
    if not valid.any():
        raise InputError("no row has finite estimated and true roll, pitch and heading")
    edges = np.asarray(pitch_bands, dtype=float)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0) or edges[0] < 0:
        raise InputError(
            f"pitch bands must be at least two increasing non-negative edges, got "
            f"{list(pitch_bands)}"
        )
    errors = wrap_deg(estimate[valid] - truth[valid])
    offset = None
    if remove_heading_offset:
        offset = float(np.degrees(np.angle(np.mean(np.exp(1j * np.radians(errors[:, 2]))))))
        errors[:, 2] = wrap_deg(errors[:, 2] - offset)
    pitch = np.abs(truth[valid, 1])

    def block(mask):
        e = errors[mask]
        return {
            "n": int(mask.sum()),
            "roll": _stats(e[:, 0]),
            "pitch": _stats(e[:, 1]),
            "heading": _stats(e[:, 2]),
        }

    bands = []
    for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        last = i == len(edges) - 2
        mask = (pitch >= lo) & ((pitch <= hi) if last else (pitch < hi))
        bands.append({"pitch_min_deg": float(lo), "pitch_max_deg": float(hi), **block(mask)})
    return {
        "overall": block(np.ones(len(errors), dtype=bool)),
        "bands": bands,
        "heading_offset_deg": offset,
        "rows_skipped": int((~valid).sum()),
    }


def format_evaluation(stats) -> str:
    """The statistics of `evaluate` as a table for a terminal (the layout of Table 2 in [1])."""

    def cell(entry):
        if entry["max_abs"] is None:
            return f"{'-':>17}"
        return f"{entry['max_abs']:8.3f} {entry['rms']:8.3f}"

    lines = [
        f"{'|pitch| [deg]':>14} {'n':>6} {'roll max/rms':>17} {'pitch max/rms':>17} "
        f"{'heading max/rms':>17}"
    ]
    rows = [(f"{b['pitch_min_deg']:g}-{b['pitch_max_deg']:g}", b) for b in stats["bands"]]
    rows.append(("all", stats["overall"]))
    for label, block in rows:
        lines.append(
            f"{label:>14} {block['n']:>6} {cell(block['roll'])} {cell(block['pitch'])} "
            f"{cell(block['heading'])}"
        )
    if stats["heading_offset_deg"] is not None:
        lines.append(f"heading offset removed: {stats['heading_offset_deg']:.3f} deg")
    return "\n".join(lines)
