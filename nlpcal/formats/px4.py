"""PX4: CAL_MAG{n}_XOFF/YOFF/ZOFF, _XSCALE/YSCALE/ZSCALE, _XODIAG/YODIAG/ZODIAG.

PX4 corrects magnetometer data in calibration::Magnetometer::Correct (src/lib/
sensor_calibration/Magnetometer.hpp), in gauss, before rotating them into the body frame:

    m' = S (m - OFF)                        OFF = (CAL_MAGn_XOFF, _YOFF, _ZOFF), subtracted [gauss]
    S = [[XSCALE, XODIAG, YODIAG],
         [XODIAG, YSCALE, ZODIAG],           (Magnetometer::set_scale, set_offdiagonal)
         [YODIAG, ZODIAG, ZSCALE]]

n is the calibration slot, 0 to 3; the slot applies to the sensor whose device id CAL_MAGn_ID
holds, so keep that parameter of the vehicle. PX4's parameter metadata give the scales the range
0.1 .. 3.0. The file is QGroundControl's parameter file (vehicle 1, component 1, type 9 = float);
"NAME VALUE" and "param set NAME VALUE" lines are read too.

From B1 = R P (B_M - b): OFF = b [gauss], S = P, and PX4 computes R^T B1. PX4 stores parameters
as 32-bit floats (about 7 significant digits).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .affine import AffineCorrection, Export, number_text
from .autopilot import check_range, parameters, rotation_lines, symmetric

UNIT = "G"
#: Range of CAL_MAGn_XSCALE, _YSCALE, _ZSCALE in PX4's parameter metadata. [1]
SCALE_RANGE = (0.1, 3.0)
INSTANCES = (0, 1, 2, 3)
#: MAV_PARAM_TYPE_REAL32, the type column of QGroundControl's parameter files.
REAL32 = 9


def names(instance: int) -> dict:
    if instance not in INSTANCES:
        raise InputError(f"PX4 magnetometer calibration slots are 0 to 3, got {instance}")
    return {
        key: [f"CAL_MAG{instance}_{a}{key}" for a in "XYZ"] for key in ("OFF", "SCALE", "ODIAG")
    }


def write(correction: AffineCorrection, instance: int = 0, max_rotation_deg=None) -> Export:
    p, rotation, b, angle = symmetric(correction, UNIT, "PX4", max_rotation_deg)
    keys = names(instance)
    scale = np.diag(p)
    odiag = np.array([p[0, 1], p[0, 2], p[1, 2]])
    for name, value in zip(keys["SCALE"], scale):
        check_range(name, value, *SCALE_RANGE, "PX4", "the range of PX4's parameter metadata")
    lines = [
        f"# nlpcal calibration for PX4 magnetometer slot {instance}: m' = S (m - OFF), "
        f"S = [[XSCALE, XODIAG, YODIAG], [XODIAG, YSCALE, ZODIAG], [YODIAG, ZODIAG, ZSCALE]], "
        f"in gauss",
        *rotation_lines(rotation, angle, "#"),
        f"# keep CAL_MAG{instance}_ID of the vehicle: the slot applies to the sensor it names",
        "#",
        "# Vehicle-Id Component-Id Name Value Type",
    ]
    rows = [*zip(keys["OFF"], b), *zip(keys["SCALE"], scale), *zip(keys["ODIAG"], odiag)]
    lines += [f"1\t1\t{name}\t{number_text(value)}\t{REAL32}" for name, value in rows]
    return Export("\n".join(lines) + "\n", [], angle)


def read(text: str, source: str, instance: int = 0) -> AffineCorrection:
    """The correction PX4 applies with the file's parameters of one calibration slot."""
    values = parameters(text, source)
    keys = names(instance)
    if not any(name in values for group in keys.values() for name in group):
        raise InputError(f"{source}: no CAL_MAG{instance}_XOFF, ... found (pass --instance)")
    off = np.array([values.get(k, 0.0) for k in keys["OFF"]])
    scale = np.array([values.get(k, 1.0) for k in keys["SCALE"]])
    o = np.array([values.get(k, 0.0) for k in keys["ODIAG"]])
    s = np.array([[scale[0], o[0], o[1]], [o[0], scale[1], o[2]], [o[1], o[2], scale[2]]])
    return AffineCorrection(
        matrix=s,
        offsets=off,
        unit=UNIT,
        source={"file": source, "format": "px4", "instance": instance},
    )
