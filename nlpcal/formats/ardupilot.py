"""ArduPilot: a .param file with COMPASS_OFS, COMPASS_DIA, COMPASS_ODI and COMPASS_SCALE.

ArduPilot corrects every compass sample in AP_Compass_Backend::correct_field (libraries/
AP_Compass/AP_Compass_Backend.cpp), in milligauss, before motor compensation:

    m' = D (k (m + OFS))                    OFS = (COMPASS_OFS_X, _Y, _Z), added [mGauss]
    D = [[DIA_X, ODI_X, ODI_Y],             k = COMPASS_SCALE, applied only within
         [ODI_X, DIA_Y, ODI_Z],                 [1/1.5, 1.5] (Compass::have_scale_factor);
         [ODI_Y, ODI_Z, DIA_Z]]                 0, the default, means no scaling
                                            D = identity when DIA is all zero

Instance 1 uses COMPASS_OFS_X, COMPASS_DIA_X, COMPASS_ODI_X, COMPASS_SCALE; instance 2 the same
names with a 2 (COMPASS_OFS2_X, COMPASS_DIA2_X, COMPASS_ODI2_X, COMPASS_SCALE2), instance 3 with a
3 (AP_Compass.cpp parameter table). The offsets are in mGauss (1 mG = 100 nT); DIA, ODI and SCALE
are dimensionless.

From B1 = R P (B_M - b): OFS = -b [mG], D = P, COMPASS_SCALE = 1, and ArduPilot computes R^T B1.
ArduPilot's own calibrator accepts diagonals in (0.2, 5.0) and off-diagonals with |ODI| < 1
(CompassCalibrator::fit_acceptable), and its pre-arm check refuses offsets longer than
COMPASS_OFFS_MAX (default 1800 mG): a calibration outside the first two cannot be exported, the
third is a warning. ArduPilot stores parameters as 32-bit floats (about 7 significant digits).

The compass an instance's calibration belongs to is named by COMPASS_DEV_ID (DEV_ID2, DEV_ID3 for
instances 2 and 3; "automatically detected, do not set manually", read-only, 0 = none), its
mounting by COMPASS_ORIENT (ORIENT2, ORIENT3; a number of ArduPilot's rotation list `ROTATIONS`,
relative to the frame for an external compass). An import carries both into the result
(`sensor_id`, `orientation`); an export writes COMPASS_DEV_ID when the result's sensor_id is a
device id, so that the file states the compass it was made for, and COMPASS_ORIENT when the
orientation came from ArduPilot.

Motor compensation (ArduPilot 4.x, the same correct_field): after the matrix, ArduPilot adds

    m'' = m' + MOT c,   MOT = (COMPASS_MOT_X, _Y, _Z)  [mGauss per A, or per full throttle]

with c the battery current [A] (COMPASS_MOTCT = 2) or the throttle, 0 to 1 (COMPASS_MOTCT = 1,
Compass::set_throttle); MOT2_*, MOT3_* for instances 2 and 3, COMPASS_MOTCT shared by all. An
aux channel of nlpcal (`nlpcal.auxiliary`) of kind current or throttle is that term:
R^T B1 = P (B_M - b - v c) = P (B_M - b) - P v c, so MOT = -P v [mG per channel unit]; an import
reads it back as v = -P^-1 MOT. Several channels, or one of kind other, ArduPilot cannot hold.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from . import autopilot
from .affine import AffineCorrection, Export, number_text
from .autopilot import check_range, parameters, rotation_lines, symmetric

UNIT = "mG"
#: (DIA low, DIA high, |ODI| limit) of CompassCalibrator::fit_acceptable. [1]
DIAGONAL_RANGE = (0.2, 5.0)
OFFDIAGONAL_LIMIT = 1.0
#: COMPASS_SCALE applied only within this range (Compass::have_scale_factor). [1]
SCALE_RANGE = (1.0 / 1.5, 1.5)
#: Default COMPASS_OFFS_MAX: the longest offset vector the pre-arm check accepts. [mG]
OFFSETS_MAX = 1800.0
#: The range of COMPASS_MOT_* in ArduPilot's parameter metadata. [mG per A or full throttle]
MOT_LIMIT = 1000.0
INSTANCES = (1, 2, 3)
#: The prefix of ArduPilot's compass parameters (the others are another subsystem's).
PREFIX = ("COMPASS_",)
#: ArduPilot's rotations: the values of COMPASS_ORIENT (AP_Compass.cpp, @Values of ORIENT).
# fmt: off
ROTATIONS = {
    0: "None", 1: "Yaw45", 2: "Yaw90", 3: "Yaw135", 4: "Yaw180", 5: "Yaw225", 6: "Yaw270",
    7: "Yaw315", 8: "Roll180", 9: "Yaw45Roll180", 10: "Yaw90Roll180", 11: "Yaw135Roll180",
    12: "Pitch180", 13: "Yaw225Roll180", 14: "Yaw270Roll180", 15: "Yaw315Roll180", 16: "Roll90",
    17: "Yaw45Roll90", 18: "Yaw90Roll90", 19: "Yaw135Roll90", 20: "Roll270", 21: "Yaw45Roll270",
    22: "Yaw90Roll270", 23: "Yaw135Roll270", 24: "Pitch90", 25: "Pitch270",
    26: "Yaw90Pitch180", 27: "Yaw270Pitch180", 28: "Pitch90Roll90", 29: "Pitch90Roll180",
    30: "Pitch90Roll270", 31: "Pitch180Roll90", 32: "Pitch180Roll270", 33: "Pitch270Roll90",
    34: "Pitch270Roll180", 35: "Pitch270Roll270", 36: "Yaw90Pitch180Roll90", 37: "Yaw270Roll90",
    38: "Yaw293Pitch68Roll180", 39: "Pitch315", 40: "Pitch315Roll90", 42: "Roll45",
    43: "Roll315", 100: "Custom 4.1 and older", 101: "Custom 1", 102: "Custom 2",
}
# fmt: on


def names(instance: int) -> dict:
    """Parameter names of a compass instance (1, 2 or 3)."""
    if instance not in INSTANCES:
        raise InputError(f"ArduPilot compass instances are 1, 2 and 3, got {instance}")
    n = "" if instance == 1 else str(instance)
    return {
        "OFS": [f"COMPASS_OFS{n}_{a}" for a in "XYZ"],
        "DIA": [f"COMPASS_DIA{n}_{a}" for a in "XYZ"],
        "ODI": [f"COMPASS_ODI{n}_{a}" for a in "XYZ"],
        "SCALE": f"COMPASS_SCALE{n}",
        "MOT": [f"COMPASS_MOT{n}_{a}" for a in "XYZ"],
        "MOTCT": "COMPASS_MOTCT",
        "DEV_ID": f"COMPASS_DEV_ID{n}",
        "ORIENT": f"COMPASS_ORIENT{n}",
    }


def write(correction: AffineCorrection, instance: int = 1, max_rotation_deg=None) -> Export:
    p, rotation, b, angle = symmetric(correction, UNIT, "ArduPilot", max_rotation_deg)
    keys = names(instance)
    dia = np.diag(p)
    odi = np.array([p[0, 1], p[0, 2], p[1, 2]])  # D = [[X, oX, oY], [oX, Y, oZ], [oY, oZ, Z]]
    for name, value in zip(keys["DIA"], dia):
        check_range(name, value, *DIAGONAL_RANGE, "ArduPilot", "what its CompassCalibrator accepts")
    for name, value in zip(keys["ODI"], odi):
        check_range(
            name,
            value,
            -OFFDIAGONAL_LIMIT,
            OFFDIAGONAL_LIMIT,
            "ArduPilot",
            "CompassCalibrator accepts |ODI| < 1",
        )
    motor = autopilot.motor_channel(correction, "ArduPilot")
    offsets = -b  # ArduPilot adds its offsets: m + OFS = m - b
    notes = []
    if np.linalg.norm(offsets) > OFFSETS_MAX:
        notes.append(
            f"the offsets are {np.linalg.norm(offsets):.0f} mG long, more than ArduPilot's default "
            f"COMPASS_OFFS_MAX of {OFFSETS_MAX:g} mG: its pre-arm check will refuse them unless "
            f"COMPASS_OFFS_MAX is raised (check the installation for magnetic parts first)"
        )
    lines = [
        f"# nlpcal calibration for ArduPilot compass {instance}: m' = D (COMPASS_SCALE (m + OFS)),"
        f" D = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]], in mGauss",
        *rotation_lines(rotation, angle, "#"),
    ]
    identity, dropped = autopilot.identity_lines(
        correction, "ardupilot", keys["DEV_ID"], keys["ORIENT"]
    )
    if identity and identity[0][0] == keys["DEV_ID"]:
        lines.append(
            f"# {keys['DEV_ID']} names the compass this calibration is for; ArduPilot detects "
            f"it (read-only): it must equal the vehicle's"
        )
    lines += [f"{k},{number_text(v)}" for k, v in zip(keys["OFS"], offsets)]
    lines += [f"{k},{number_text(v)}" for k, v in zip(keys["DIA"], dia)]
    lines += [f"{k},{number_text(v)}" for k, v in zip(keys["ODI"], odi)]
    lines.append(f"{keys['SCALE']},1.0")
    lines += [f"{k},{v}" for k, v in identity]
    if motor is not None:
        lines += _motor_lines(correction, p, keys, notes)
    return Export("\n".join(lines) + "\n", notes, angle, dropped)


def _motor_lines(correction: AffineCorrection, p: np.ndarray, keys: dict, notes: list) -> list:
    """COMPASS_MOTCT and COMPASS_MOT*_X/Y/Z of the correction's one motor channel: MOT = -P v,
    added after the matrix (correct_field). [mG per channel unit]"""
    (channel,) = correction.in_unit(UNIT).aux
    mot = -p @ channel.coefficients
    per = "A" if channel.kind == "current" else "full throttle"
    if np.abs(mot).max() > MOT_LIMIT:
        notes.append(
            f"{keys['MOT'][0][:-2]}_* reach {np.abs(mot).max():.0f} mG per {per}, beyond the "
            f"+/-{MOT_LIMIT:g} of ArduPilot's parameter range"
        )
    signal = "battery current [A]" if channel.kind == "current" else "throttle (0 to 1)"
    return [
        f"# motor compensation from aux channel {channel.name!r}: m'' = m' + MOT c, c the "
        f"{signal}; {keys['MOTCT']} is shared by every compass",
        f"{keys['MOTCT']},{autopilot.MOTOR_TYPES[channel.kind]}",
        *(f"{k},{number_text(v)}" for k, v in zip(keys["MOT"], mot)),
    ]


def read(text: str, source: str, instance: int = 1) -> AffineCorrection:
    """The correction ArduPilot applies with the file's parameters of one compass instance, its
    motor compensation as an aux channel (the module docstring)."""
    values = parameters(text, source)
    keys = names(instance)
    wanted = [*keys["OFS"], *keys["DIA"], *keys["ODI"], keys["SCALE"]]
    if not any(name in values for name in wanted):
        raise InputError(
            f"{source}: no {keys['OFS'][0]}, {keys['DIA'][0]}, ... for compass "
            f"instance {instance} (pass --instance)"
        )
    ofs = np.array([values.get(k, 0.0) for k in keys["OFS"]])
    dia = np.array([values.get(k, 0.0) for k in keys["DIA"]])
    odi = np.array([values.get(k, 0.0) for k in keys["ODI"]])
    if not dia.any():
        dia = np.ones(3)  # correct_field: all-zero diagonals mean the identity
    scale = values.get(keys["SCALE"], 0.0)
    if not SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]:
        scale = 1.0  # have_scale_factor: outside the range the scale is not applied
    d = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]], [odi[1], odi[2], dia[2]]])
    mot = np.array([values.get(k, 0.0) for k in keys["MOT"]])
    aux = autopilot.motor_aux(values.get(keys["MOTCT"], 0.0), mot, source, scale * d)
    motor = [*keys["MOT"], keys["MOTCT"]] if aux else []  # else named among the unused
    used = [*wanted, *motor, keys["DEV_ID"], keys["ORIENT"]]
    return AffineCorrection(
        matrix=scale * d,
        offsets=-ofs,
        unit=UNIT,
        source={"file": source, "format": "ardupilot", "instance": instance},
        aux=aux,
        **autopilot.identity(values, used, "ardupilot", ROTATIONS, PREFIX, source),
    )
