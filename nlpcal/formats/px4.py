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

CAL_MAGn_ID is the device id of the sensor the slot belongs to (Magnetometer::ParametersSave
writes it; FindCurrentCalibrationIndex matches it) and CAL_MAGn_ROT its rotation (-1: the
board's). An import carries them into the result (`sensor_id`, `orientation`); an export writes
CAL_MAGn_ID when the result's sensor_id is a device id, and CAL_MAGn_ROT when the orientation
came from PX4. CAL_MAGn_PRIO is named as unused.

Power compensation (Magnetometer::Correct, VehicleMagnetometer::UpdatePowerCompensation): PX4
adds COMP p to the raw data before the offsets, m' = S ((m + COMP p) - OFF), with
COMP = (CAL_MAGn_XCOMP, _YCOMP, _ZCOMP) and p the throttle, 0 to 1 (CAL_MAG_COMP_TYP = 1;
COMP in gauss), or the battery current in kA (CAL_MAG_COMP_TYP = 2 for battery instance 0, 3
for instance 1; COMP in gauss per kA). That is nlpcal's aux channel of kind throttle or current
exactly (`nlpcal.auxiliary`): COMP p = -v c, so COMP = -v [G per full throttle] or -1000 v
[G/kA, from v in G/A]. Several channels, or one of kind other, PX4 cannot hold.

Thermal compensation (src/modules/temperature_compensation): with TC_M_ENABLE = 1, PX4 subtracts
from the sensor's readings, in the sensor frame and in gauss, before the calibration offsets,

    TC(T) = X0 + X1 dT + X2 dT^2 + X3 dT^3,  dT = T - TREF clipped to [TMIN - TREF, TMAX - TREF]

per axis (TC_Mn_X{0..3}_{0,1,2}; TemperatureCompensation::calc_thermal_offsets_3D), for the
sensor whose device id TC_Mn_ID holds; PX4's own calibration (temperature_calibration/mag.cpp)
fits X1..X3 to the raw readings against dT and sets X0 = 0, the correction being zero at TREF.
The result is m' = S (m - TC(T) - OFF) (sensor_correction.msg: "applied before the sensor data is
rotated into body frame"). nlpcal's drift B1 = A diag(1 / (1 + sigma dT)) (B_M - b - zeta dT)
(`TemperatureDrift`) is that form exactly when sigma = 0: X1 = zeta [gauss/degC], X0 = X2 = X3 =
0, TREF = t0, TMIN and TMAX the calibration log's temperatures (outside them PX4 holds the
offsets constant, nlpcal extrapolates). A drift of the gains (sigma != 0, as Liu et al.'s common
model has) PX4 cannot represent: the export refuses it unless the temperature model is dropped.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from . import autopilot
from .affine import AffineCorrection, Export, number_text
from .autopilot import check_range, parameters, rotation_lines, symmetric

UNIT = "G"
#: Range of CAL_MAGn_XSCALE, _YSCALE, _ZSCALE in PX4's parameter metadata. [1]
SCALE_RANGE = (0.1, 3.0)
INSTANCES = (0, 1, 2, 3)
#: MAV_PARAM_TYPE_REAL32 and _INT32, the type column of QGroundControl's parameter files.
REAL32 = 9
INT32 = 6
#: CAL_MAG_COMP_TYP -> the kind of the aux channel (2 and 3: the current of battery 0 or 1).
COMPENSATION_KINDS = {1: "throttle", 2: "current", 3: "current"}
#: What one unit of a channel is in PX4's power signal p: the throttle itself, the current in
#: kA (bat_stat.current_a * 0.001f). [p per channel unit]
POWER_PER_UNIT = {"throttle": 1.0, "current": 1e-3}
#: The prefixes of PX4's magnetometer parameters (the others are another subsystem's).
PREFIX = ("CAL_MAG", "TC_M", "SENS_MAG")


def names(instance: int) -> dict:
    if instance not in INSTANCES:
        raise InputError(f"PX4 magnetometer calibration slots are 0 to 3, got {instance}")
    return {
        **{
            key: [f"CAL_MAG{instance}_{a}{key}" for a in "XYZ"] for key in ("OFF", "SCALE", "ODIAG")
        },
        "COMP": [f"CAL_MAG{instance}_{a}COMP" for a in "XYZ"],
        "COMP_TYP": "CAL_MAG_COMP_TYP",
        "ID": f"CAL_MAG{instance}_ID",
        "ROT": f"CAL_MAG{instance}_ROT",
    }


def thermal_names(instance: int) -> dict:
    """The thermal compensation parameters of slot `instance` (temp_comp_params_mag_n.yaml):
    X[p][i] is TC_Mn_Xp_i, the coefficient of dT^p on axis i."""
    t = f"TC_M{instance}_"
    return {
        "ENABLE": "TC_M_ENABLE",
        "ID": f"{t}ID",
        "TREF": f"{t}TREF",
        "TMIN": f"{t}TMIN",
        "TMAX": f"{t}TMAX",
        "X": [[f"{t}X{power}_{axis}" for axis in range(3)] for power in range(4)],
    }


def write(
    correction: AffineCorrection,
    instance: int = 0,
    max_rotation_deg=None,
    drop_temperature: bool = False,
) -> Export:
    """The parameter file of slot `instance`; a temperature drift as TC_M* parameters when
    they represent it exactly, else InputError unless `drop_temperature`."""
    p, rotation, b, angle = symmetric(correction, UNIT, "PX4", max_rotation_deg)
    motor = autopilot.motor_channel(correction, "PX4")
    keys = names(instance)
    scale = np.diag(p)
    odiag = np.array([p[0, 1], p[0, 2], p[1, 2]])
    for name, value in zip(keys["SCALE"], scale):
        check_range(name, value, *SCALE_RANGE, "PX4", "the range of PX4's parameter metadata")
    identity, dropped = autopilot.identity_lines(correction, "px4", keys["ID"], keys["ROT"])
    has_id = bool(identity) and identity[0][0] == keys["ID"]
    lines = [
        f"# nlpcal calibration for PX4 magnetometer slot {instance}: m' = S (m - OFF), "
        f"S = [[XSCALE, XODIAG, YODIAG], [XODIAG, YSCALE, ZODIAG], [YODIAG, ZODIAG, ZSCALE]], "
        f"in gauss",
        *rotation_lines(rotation, angle, "#"),
        f"# {keys['ID']} names the sensor this slot is for: PX4 applies the slot to that device"
        if has_id
        else f"# keep {keys['ID']} of the vehicle: the slot applies to the sensor it names",
    ]
    rows = [*zip(keys["OFF"], b), *zip(keys["SCALE"], scale), *zip(keys["ODIAG"], odiag)]
    rows += identity
    notes: list = []
    drift = correction.in_unit(UNIT).temperature
    if drift is not None and drift.offsets_only:
        thermal, comment, notes = _thermal_rows(drift, instance, correction.sensor_id)
        rows += thermal
        lines += comment
    elif drift is not None and not drop_temperature:
        raise InputError(
            f"PX4's thermal compensation (TC_M{instance}_*) subtracts offsets that drift with "
            f"temperature, but this temperature model also changes the axes' gains (scale "
            f"slopes {', '.join(f'{v:.3g}' for v in drift.scale_slope_per_degC)} /degC), which "
            f"PX4 cannot represent; pass --drop-temperature to export the calibration at "
            f"{drift.base_temperature_degC:g} degC without it"
        )
    elif drift is not None:
        dropped.append(
            f"the temperature model (--drop-temperature; the calibration holds at "
            f"{drift.base_temperature_degC:g} degC)"
        )
    if motor is not None:
        power, comment = _power_rows(correction, keys)
        rows += power
        lines += comment
    lines += ["#", "# Vehicle-Id Component-Id Name Value Type"]
    lines += [_row(name, value) for name, value in rows]
    return Export("\n".join(lines) + "\n", notes, angle, dropped)


def _power_rows(correction: AffineCorrection, keys: dict) -> tuple[list, list]:
    """(rows, comment lines) of the power compensation of the correction's one motor channel:
    CAL_MAG_COMP_TYP and COMP = -v / (p per channel unit) (the module docstring). [G per
    full throttle, or G/kA]"""
    (channel,) = correction.in_unit(UNIT).aux
    compensation = -channel.coefficients / POWER_PER_UNIT[channel.kind]
    rows: list = [(keys["COMP_TYP"], autopilot.MOTOR_TYPES[channel.kind])]
    rows += list(zip(keys["COMP"], map(float, compensation)))
    signal = "battery 0 current [kA]" if channel.kind == "current" else "throttle (0 to 1)"
    comment = [
        f"# power compensation from aux channel {channel.name!r}: m' = S ((m + COMP p) - OFF), "
        f"p the {signal}"
    ]
    return rows, comment


def _row(name: str, value) -> str:
    """One line of QGroundControl's parameter file; an int is an INT32 parameter."""
    if isinstance(value, int):
        return f"1\t1\t{name}\t{value}\t{INT32}"
    return f"1\t1\t{name}\t{number_text(value)}\t{REAL32}"


def _thermal_rows(drift, instance: int, sensor_id) -> tuple[list, list, list]:
    """(rows, comment lines, notes) of an offsets-only drift as TC_M* parameters (the module
    docstring): TC(T) = X1 (T - TREF), X1 = zeta [gauss/degC]."""
    t = thermal_names(instance)
    rows: list = [(t["ENABLE"], 1)]
    notes = []
    if isinstance(sensor_id, int):
        rows.append((t["ID"], sensor_id))
    else:
        notes.append(
            f"PX4 applies {t['TREF'][:-4]}* only to the sensor whose device id {t['ID']} holds: "
            f"set it to the vehicle's {names(instance)['ID']} (or calibrate with --sensor-id)"
        )
    low, high = drift.range_degC
    rows += [(t["TREF"], drift.base_temperature_degC), (t["TMIN"], low), (t["TMAX"], high)]
    coefficients = [np.zeros(3), drift.offset_slope_per_degC, np.zeros(3), np.zeros(3)]
    for power, values in enumerate(coefficients):
        rows += list(zip(t["X"][power], map(float, values)))
    comment = [
        f"# thermal compensation: TC(T) = X1 (T - TREF) gauss per axis, subtracted before OFF; "
        f"PX4 holds it constant outside TMIN .. TMAX ({low:g} .. {high:g} degC)"
    ]
    return rows, comment, notes


def read(text: str, source: str, instance: int = 0) -> AffineCorrection:
    """The correction PX4 applies with the file's parameters of one calibration slot."""
    values = parameters(text, source)
    keys = names(instance)
    used = [*keys["OFF"], *keys["SCALE"], *keys["ODIAG"], keys["ID"], keys["ROT"]]
    if not any(name in values for name in used[:9]):
        raise InputError(f"{source}: no CAL_MAG{instance}_XOFF, ... found (pass --instance)")
    off = np.array([values.get(k, 0.0) for k in keys["OFF"]])
    scale = np.array([values.get(k, 1.0) for k in keys["SCALE"]])
    o = np.array([values.get(k, 0.0) for k in keys["ODIAG"]])
    s = np.array([[scale[0], o[0], o[1]], [o[0], scale[1], o[2]], [o[1], o[2], scale[2]]])
    kind_value = values.get(keys["COMP_TYP"], 0.0)
    comp = np.array([values.get(k, 0.0) for k in keys["COMP"]])
    kind = COMPENSATION_KINDS.get(int(kind_value), "") if float(kind_value).is_integer() else ""
    comp = comp * POWER_PER_UNIT.get(kind, 1.0)  # [G per channel unit]
    aux = autopilot.motor_aux(kind_value, comp, source, kinds=COMPENSATION_KINDS)
    if aux:  # else named among the unused
        used[-2:-2] = [*keys["COMP"], keys["COMP_TYP"]]
    return AffineCorrection(
        matrix=s,
        offsets=off,
        unit=UNIT,
        source={"file": source, "format": "px4", "instance": instance},
        aux=aux,
        **autopilot.identity(values, used, "px4", {-1: "board"}, PREFIX, source),
    )
