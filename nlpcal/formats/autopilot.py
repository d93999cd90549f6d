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
from ..auxiliary.model import AuxChannel
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


def unused_names(values: dict, used, own: tuple) -> list:
    """The names of a parameter file that an import does not use, in one list: the parameters
    of the compass (names starting with one of `own`) each named, those of the same group that
    differ only in a final axis letter or digit joined ("COMPASS_MOT_X/Y/Z"); the rest of a
    vehicle's parameters named by their group ("12 other parameters: ARMING_*, BATT_*")."""
    left = [name for name in values if name not in set(used)]
    compass = [name for name in left if name.startswith(own)]
    groups: dict = {}
    for name in compass:
        stem, _, last = name.rpartition("_")
        key = stem if stem and len(last) == 1 else name
        groups.setdefault(key, []).append(last if key == stem else name)
    named = [
        key if members == [key] else f"{key}_{'/'.join(members)}" for key, members in groups.items()
    ]
    others = [name for name in left if not name.startswith(own)]
    if others:
        families = sorted(
            {name.split("_", 1)[0] + ("_*" if "_" in name else "") for name in others}
        )
        named.append(f"{len(others)} other parameter(s): {', '.join(families)}")
    return named


def device_id(values: dict, name: str, source: str) -> int | str | None:
    """A device id parameter (ArduPilot's COMPASS_DEV_ID, PX4's CAL_MAGn_ID): None when absent
    or 0 (no device), else the id (`nlpcal.validation.sensor_id`)."""
    value = values.get(name)
    if value is None or value == 0:
        return None
    if not float(value).is_integer():
        raise InputError(f"{source}: {name} must be an integer device id, got {value:g}")
    return validation.sensor_id(int(value), f"{source}: {name}")


def orientation(values: dict, name: str, system: str, labels: dict, source: str):
    """The orientation record of a rotation parameter (COMPASS_ORIENT, CAL_MAGn_ROT), or None
    when the file does not have it: {"system", "parameter", "value"[, "name"]}."""
    if name not in values:
        return None
    value = values[name]
    if not float(value).is_integer() or value < -1:
        raise InputError(f"{source}: {name} must be a rotation number, got {value:g}")
    record = {"system": system, "parameter": name, "value": int(value)}
    if int(value) in labels:
        record["name"] = labels[int(value)]
    return record


def identity(values: dict, used: list, system: str, labels: dict, own: tuple, source: str):
    """What an import takes beside the correction: {"sensor_id", "orientation", "unused"}, from
    the device id and rotation parameters, the last two of `used` (`device_id`, `orientation`),
    and the names of the file it does not use (`unused_names`)."""
    id_name, rot_name = used[-2:]
    return {
        "sensor_id": device_id(values, id_name, source),
        "orientation": orientation(values, rot_name, system, labels, source),
        "unused": unused_names(values, used, own),
    }


def identity_lines(correction: AffineCorrection, system: str, id_name: str, rot_name: str):
    """(rows, dropped) for the sensor's identity: the device id and the orientation parameter
    when `correction` carries them in a form `system` takes, else a phrase each for the note."""
    rows, dropped = [], []
    sensor = correction.sensor_id
    if isinstance(sensor, int):
        rows.append((id_name, sensor))
    elif sensor is not None:
        dropped.append(f"sensor_id {sensor!r} (a name, not a device id)")
    mounting = correction.orientation
    if mounting is not None and mounting["system"] == system:
        rows.append((rot_name, mounting["value"]))
    elif mounting is not None:
        dropped.append(f"the orientation {mounting['parameter']} = {mounting['value']}")
    return rows, dropped


#: The kind of an aux channel an autopilot's motor compensation takes -> its type parameter's
#: value: ArduPilot's COMPASS_MOTCT and PX4's CAL_MAG_COMP_TYP (1 throttle, 2 current).
MOTOR_TYPES = {"throttle": 1, "current": 2}


def motor_channel(correction: AffineCorrection, system: str):
    """The one aux channel (`nlpcal.auxiliary`) an autopilot's motor compensation holds, or None
    without aux channels; InputError for several channels or one of kind "other", which it has
    no place for."""
    channels = list(correction.aux)
    if not channels:
        return None
    if len(channels) > 1:
        names = ", ".join(c.name for c in channels)
        raise InputError(
            f"{system}'s motor compensation follows one channel, a current or the throttle; "
            f"this calibration has {len(channels)} aux channels ({names}): calibrate with one"
        )
    (channel,) = channels
    if channel.kind not in MOTOR_TYPES:
        raise InputError(
            f"{system}'s motor compensation follows a current or the throttle; aux channel "
            f"{channel.name!r} is of kind {channel.kind!r} (calibrate with --aux-kind current or "
            f"throttle when it is one)"
        )
    return channel


def motor_aux(kind_value: float, compensation, source: str, matrix=None, kinds=None) -> list:
    """The aux channel (`nlpcal.auxiliary`) of an autopilot's motor compensation read from a
    file: none when its type is 0 (disabled) or the compensation all zero; v = -matrix^-1
    compensation where the compensation is added to the field after `matrix` (ArduPilot),
    v = -compensation where it is added before it (PX4). `kinds` : type value -> channel kind
    (default 1 throttle, 2 current); InputError for another type. [the file's unit per
    channel unit]"""
    kinds = kinds or {value: kind for kind, value in MOTOR_TYPES.items()}
    if kind_value == 0 or not np.any(compensation):
        return []
    if kind_value not in kinds:
        raise InputError(
            f"{source}: motor compensation type {kind_value:g} is not one of "
            f"{', '.join(f'{v} ({k})' for v, k in kinds.items())}"
        )
    kind = kinds[kind_value]
    compensation = np.asarray(compensation, dtype=float)
    if matrix is not None:
        compensation = np.linalg.solve(np.asarray(matrix, dtype=float), compensation)
    return [AuxChannel(kind, kind, -compensation)]


def check_range(name: str, value: float, low: float, high: float, system: str, why: str) -> None:
    """InputError when a value lies outside the open interval (low, high) a system accepts."""
    if not low < value < high:
        raise InputError(
            f"this calibration cannot be expressed in {system}: {name} = {value:.6g} lies outside "
            f"{low:g} .. {high:g} ({why})"
        )
