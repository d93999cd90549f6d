"""What the autopilot formats share: the symmetric matrix, parameter files and range checks.

ArduPilot and PX4 store a symmetric soft-iron matrix P and offsets. nlpcal's A = O_p S_p is upper
triangular; the polar decomposition A = R P (`nlpcal.formats.affine.polar`) gives the symmetric
factor, and the autopilot then computes R^T B1: |B1| exactly, in axes turned by the rotation R.
The rotation is written into the file's comments and must be small (`MAX_ROTATION_DEG`).
"""

from __future__ import annotations

import re

import numpy as np

from .. import validation
from ..errors import InputError
from ..results import distinct
from .affine import AffineCorrection, rotation_angle_deg

#: Largest rotation R accepted between nlpcal's axes and those of the symmetric matrix. [deg]
MAX_ROTATION_DEG = 5.0
_LINE = re.compile(r"^\s*(?:param\s+set\s+)?([A-Za-z][A-Za-z0-9_]*)\s*[,\s]\s*([^\s,]+)")
_QGC_LINE = re.compile(r"^\s*\d+\s+\d+\s+([A-Za-z][A-Za-z0-9_]*)\s+(\S+)\s+\d+\s*$")


def symmetric(
    correction: AffineCorrection, unit: str, system: str, max_rotation_deg: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(P, R, b in `unit`, rotation angle [deg]) of a correction for an autopilot.

    Raises InputError for counts (the autopilot's unit is a field unit) and when the rotation
    exceeds `max_rotation_deg` (default MAX_ROTATION_DEG).
    """
    if correction.unit == "raw":
        raise InputError(
            f"{system} stores its calibration in {unit}; a calibration in raw counts cannot be "
            f"converted; calibrate the log in a field unit (--unit nT, uT, ...)"
        )
    limit = MAX_ROTATION_DEG if max_rotation_deg is None else float(max_rotation_deg)
    rotation, p = correction.polar()
    angle = rotation_angle_deg(rotation)
    if angle > limit:
        raise InputError(
            f"{system} takes a symmetric matrix; the symmetric factor of this calibration turns "
            f"the axes by {angle:.3g} deg (more than {limit:g} deg): the non-orthogonality is too "
            f"large for {system}'s form (use the matrix or c-header export, or raise "
            f"--max-rotation-deg)"
        )
    return p, rotation, correction.in_unit(unit).offsets, angle


def rotation_lines(rotation, angle: float, comment: str) -> list:
    """Comment lines that state the rotation the symmetric matrix does not carry."""
    rows = "; ".join(" ".join(f"{v:.9f}" for v in row) for row in np.asarray(rotation))
    return [
        f"{comment} nlpcal's A = R P; this file holds the symmetric P, so the autopilot's "
        f"corrected field is R^T B1 (same magnitude).",
        f"{comment} R turns the axes by {angle:.6f} deg: R = [{rows}]",
    ]


def parameters(text: str, source: str) -> dict:
    """Parameter names and values of a parameter file: "NAME,VALUE" (Mission Planner),
    "NAME VALUE" (MAVProxy), "param set NAME VALUE" (PX4 shell) or QGroundControl's tab-separated
    "VEHICLE COMPONENT NAME VALUE TYPE"; '#' starts a comment."""
    pairs = []
    for number, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        match = _QGC_LINE.match(line) or _LINE.match(line)
        if not match:
            raise InputError(f"{source}: line {number} is not 'NAME,VALUE': {line[:60]!r}")
        name = match.group(1).upper()
        value = validation.number(match.group(2), f"{source}: line {number}: {name}")
        pairs.append((name, value))
    return distinct(pairs, source, "parameter")


def check_range(name: str, value: float, low: float, high: float, system: str, why: str) -> None:
    """InputError when a value lies outside the open interval (low, high) a system accepts."""
    if not low < value < high:
        raise InputError(
            f"this calibration cannot be expressed in {system}: {name} = {value:.6g} lies outside "
            f"{low:g} .. {high:g} ({why})"
        )
