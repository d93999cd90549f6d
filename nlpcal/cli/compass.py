"""`nlpcal compass calibrate | attitude | evaluate`: the e-compass of Qiu et al. (2017).

calibrate: turn mode with --turn-column (the paper's protocol), free-rotation mode without it.
attitude: roll_deg, pitch_deg, heading_deg added to a log. evaluate: error statistics against true
attitude columns, overall and per pitch band (the paper's Table 2).
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd

from .. import compass
from ..errors import InputError
from ..io import (FIELD_UNITS_NT, check_output_path, numeric_columns, read_json, read_table,
                  resolve_columns, suggested_unit, unit_factor)
from . import emit_csv, emit_json, warn

#: Accelerometer column triples recognised without --acc-columns, tried case-insensitively.
ACC_COLUMN_TRIPLES = (("ax", "ay", "az"), ("acc_x", "acc_y", "acc_z"), ("accx", "accy", "accz"),
                      ("ax_g", "ay_g", "az_g"), ("ax_mps2", "ay_mps2", "az_mps2"))

#: Column-name suffixes that hint at an accelerometer unit.
ACC_UNIT_SUFFIXES = {"g": "g", "mg": "mg", "mps2": "m/s2", "ms2": "m/s2", "m/s2": "m/s2"}

ATTITUDE_COLUMNS = ("roll_deg", "pitch_deg", "heading_deg")


def register(sub):
    parser = sub.add_parser(
        "compass", help="e-compass (Qiu 2017): calibrate magnetometer + accelerometer, attitude",
        description=__doc__.splitlines()[0])
    actions = parser.add_subparsers(dest="compass_command", metavar="ACTION",
                                    parser_class=type(parser))
    actions.required = True

    cal = actions.add_parser(
        "calibrate", help="mounting angles, bias and sensitivity of both sensors",
        description="Turn mode (--turn-column): the paper's turns about the housing x, y and z "
                    "axes, then ellipsoid fits. Free-rotation mode (no --turn-column): ellipsoid "
                    "fits and the dip-angle constancy; the sensor pair's orientation relative to "
                    "the housing is then not identifiable.")
    cal.add_argument("log", metavar="LOG.csv")
    _add_sensor_arguments(cal, defaults_from_calibration=False)
    cal.add_argument("--turn-column", metavar="COL",
                     help="column naming each sample's turn axis: x, y, z, optionally with a "
                          "suffix for repeated turns (y2); absent selects free-rotation mode")
    cal.add_argument("--field-nt", type=float, metavar="NT",
                     help="local total field [nT] (default: estimated with det(correction) = 1)")
    cal.add_argument("--ellipsoid-seed", choices=("linear", "centroid"), default="linear",
                     help="start of the ellipsoid NLPs (default linear least squares)")
    cal.add_argument("--rest-tolerance", type=float, default=compass.DEFAULT_REST_TOLERANCE,
                     metavar="G",
                     help="free-rotation mode: samples whose calibrated |acc| differs from 1 g by "
                          "more than this [g] are treated as moving and left out of the "
                          "accelerometer fit and the alignment (default "
                          f"{compass.DEFAULT_REST_TOLERANCE:g}; 1 keeps every sample)")
    cal.add_argument("-o", "--output", metavar="COMPASS.json",
                     help="calibration JSON (stdout when absent)")
    cal.set_defaults(func=run_calibrate)

    att = actions.add_parser(
        "attitude", help="add roll_deg, pitch_deg, heading_deg to a log",
        description="Apply a compass calibration and compute roll, pitch and heading (Eq. 10).")
    att.add_argument("calibration", metavar="COMPASS.json")
    att.add_argument("log", metavar="LOG.csv")
    _add_sensor_arguments(att, defaults_from_calibration=True)
    att.add_argument("--declination-deg", type=float, default=0.0, metavar="DEG",
                     help="magnetic declination [deg], east positive, added to give true heading")
    att.add_argument("-o", "--output", metavar="ATTITUDE.csv",
                     help="output CSV (stdout when absent)")
    att.set_defaults(func=run_attitude)

    ev = actions.add_parser(
        "evaluate", help="attitude error statistics against true attitude columns",
        description="Max |error| and RMS of roll, pitch and heading, overall and per band of "
                    "|true pitch|; JSON to -o or stdout, a table on stderr.")
    ev.add_argument("attitude", metavar="ATTITUDE.csv")
    ev.add_argument("--truth-columns", nargs=3, required=True, metavar=("ROLL", "PITCH", "HEADING"),
                    help="true roll, pitch and heading columns [deg]")
    ev.add_argument("--estimate-columns", nargs=3, default=list(ATTITUDE_COLUMNS),
                    metavar=("ROLL", "PITCH", "HEADING"),
                    help="estimated columns [deg] (default roll_deg pitch_deg heading_deg)")
    ev.add_argument("--pitch-bands", nargs="+", type=float,
                    default=list(compass.DEFAULT_PITCH_BANDS), metavar="DEG",
                    help="edges of |true pitch| bands [deg] (default 0 30 60 85 90)")
    ev.add_argument("--remove-heading-offset", action="store_true",
                    help="subtract the circular mean heading error first (reference with an "
                         "arbitrary north)")
    ev.add_argument("-o", "--output", metavar="STATS.json",
                    help="statistics JSON (stdout when absent)")
    ev.set_defaults(func=run_evaluate)


def _add_sensor_arguments(parser, *, defaults_from_calibration: bool):
    unit_note = " (default: as in the calibration)" if defaults_from_calibration else ""
    parser.add_argument("--mag-columns", nargs=3, metavar=("MX", "MY", "MZ"),
                        help="magnetometer columns (default: detected, bx/by/bz, mx/my/mz, ...)")
    parser.add_argument("--acc-columns", nargs=3, metavar=("AX", "AY", "AZ"),
                        help="accelerometer columns (default: detected, ax/ay/az, acc_x/...)")
    parser.add_argument("--mag-unit", choices=[u for u in FIELD_UNITS_NT if u != "raw"],
                        default=None if defaults_from_calibration else "nT",
                        help="unit of the magnetometer columns" + (unit_note or " (default nT)"))
    parser.add_argument("--acc-unit", choices=list(compass.ACC_UNITS_G),
                        default=None if defaults_from_calibration else "g",
                        help="unit of the accelerometer columns" + (unit_note or " (default g)"))
    parser.add_argument("--drop-invalid", action="store_true",
                        help="skip rows with missing or non-numeric values (reporting how many) "
                             "instead of failing")


def _acc_columns(frame: pd.DataFrame, columns) -> list:
    if columns:
        return resolve_columns(frame, columns, what="accelerometer")
    lower = {c.lower(): c for c in frame.columns}
    matches = [[lower[n] for n in triple] for triple in ACC_COLUMN_TRIPLES
               if all(n in lower for n in triple)]
    if len(matches) == 1:
        return matches[0]
    found = ", ".join(frame.columns)
    if not matches:
        raise InputError(f"no accelerometer columns recognised (ax/ay/az, acc_x/acc_y/acc_z, ...); "
                         f"the log has columns: {found}; pass --acc-columns AX AY AZ")
    raise InputError(f"ambiguous accelerometer columns; the log has columns: {found}; pass "
                     f"--acc-columns AX AY AZ")


def _unit_hints(mag_columns, acc_columns, mag_unit, acc_unit):
    hinted = suggested_unit(mag_columns)
    if hinted and hinted != mag_unit:
        warn(f"the magnetometer columns ({', '.join(mag_columns)}) suggest {hinted}, but "
             f"--mag-unit is {mag_unit}")
    parts = acc_columns[0].lower().rsplit("_", 1)
    hinted = ACC_UNIT_SUFFIXES.get(parts[1]) if len(parts) == 2 else None
    if hinted and hinted != acc_unit:
        warn(f"the accelerometer columns ({', '.join(acc_columns)}) suggest {hinted}, but "
             f"--acc-unit is {acc_unit}")


def _read_sensors(args, mag_unit: str, acc_unit: str):
    """The log, its magnetometer [nT] and accelerometer [g] samples, and the rows kept."""
    frame = read_table(args.log)
    mag_columns = resolve_columns(frame, args.mag_columns, what="magnetometer")
    acc_columns = _acc_columns(frame, args.acc_columns)
    if set(mag_columns) & set(acc_columns):
        raise InputError(f"the magnetometer columns ({', '.join(mag_columns)}) and accelerometer "
                         f"columns ({', '.join(acc_columns)}) overlap; pass --mag-columns and "
                         f"--acc-columns")
    _unit_hints(mag_columns, acc_columns, mag_unit, acc_unit)
    numeric = numeric_columns(frame, mag_columns + acc_columns, drop_invalid=args.drop_invalid,
                              source=str(args.log))
    if numeric.dropped:
        warn(f"skipped {numeric.dropped} row(s) with missing or non-numeric values")
    mag = numeric.values[:, :3] * unit_factor(mag_unit)
    acc = numeric.values[:, 3:] * compass.ACC_UNITS_G[acc_unit]
    return frame, mag, acc, numeric.kept, mag_columns, acc_columns


def run_calibrate(args) -> int:
    check_output_path(args.output)
    frame, mag, acc, kept, mag_columns, acc_columns = _read_sensors(args, args.mag_unit,
                                                                    args.acc_unit)
    field_nt = args.field_nt
    if args.turn_column:
        if args.turn_column not in frame.columns:
            raise InputError(f"turn column {args.turn_column!r} not found; the log has columns: "
                             f"{', '.join(frame.columns)}")
        labels = frame[args.turn_column].to_numpy(dtype=object)[kept]
        result = compass.calibrate_turns(mag, acc, labels, field_nt=field_nt,
                                         ellipsoid_seed=args.ellipsoid_seed)
    else:
        warn("no --turn-column: free-rotation mode (the sensor pair's orientation relative to the "
             "housing cannot be found; attitudes refer to the accelerometer's axes)")
        result = compass.calibrate_free(mag, acc, field_nt=field_nt,
                                        ellipsoid_seed=args.ellipsoid_seed,
                                        rest_tolerance=args.rest_tolerance)
    result.input.update({
        "file": str(args.log), "mag_columns": mag_columns, "acc_columns": acc_columns,
        "mag_unit": args.mag_unit, "acc_unit": args.acc_unit, "turn_column": args.turn_column,
        "rows_skipped": int((~kept).sum()),
    })
    for message in result.warnings:
        warn(message)
    emit_json(result.to_dict(), args.output)
    summary = result.to_dict()
    for sensor in ("magnetometer", "accelerometer"):
        angles = summary[sensor]["mounting_deg"]
        warn(f"{sensor}: mounting [deg] " + ", ".join(f"{k} {v:+.4f}" for k, v in angles.items())
             + f"; |v| residual RMS {summary[sensor]['quality']['magnitude_residual_rms']:.3g} "
               f"{summary[sensor]['unit']}")
    return 0


def run_attitude(args) -> int:
    check_output_path(args.output)
    calibration = compass.CompassCalibration.from_dict(
        read_json(args.calibration, what="compass calibration"))
    recorded = calibration.input or {}
    mag_unit = args.mag_unit or recorded.get("mag_unit") or "nT"
    acc_unit = args.acc_unit or recorded.get("acc_unit") or "g"
    if mag_unit not in FIELD_UNITS_NT or mag_unit == "raw":
        raise InputError(f"the calibration records magnetometer unit {mag_unit!r}; pass --mag-unit")
    if acc_unit not in compass.ACC_UNITS_G:
        raise InputError(f"the calibration records accelerometer unit {acc_unit!r}; pass "
                         f"--acc-unit")
    if args.mag_columns is None and recorded.get("mag_columns"):
        args.mag_columns = recorded["mag_columns"]
    if args.acc_columns is None and recorded.get("acc_columns"):
        args.acc_columns = recorded["acc_columns"]
    frame, mag, acc, kept, _, _ = _read_sensors(args, mag_unit, acc_unit)
    result = compass.attitude(calibration, mag, acc, declination_deg=args.declination_deg)
    for message in result.warnings:
        warn(message)
    out = frame.copy()
    replaced = [c for c in ATTITUDE_COLUMNS if c in out.columns]
    if replaced:
        warn(f"the log already has {', '.join(replaced)}; replaced them")
    for name, values in zip(ATTITUDE_COLUMNS, (result.roll_deg, result.pitch_deg,
                                               result.heading_deg)):
        column = np.full(len(frame), np.nan)
        column[kept] = values
        out[name] = column
    emit_csv(out, args.output)  # exact values: the log's own columns pass through unchanged
    return 0


def _numeric_table(frame, columns, path) -> np.ndarray:
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise InputError(f"column {missing[0]!r} not found in {path}; it has columns: "
                         f"{', '.join(frame.columns)}")
    return frame[list(columns)].apply(pd.to_numeric, errors="coerce").to_numpy(dtype=float)


def run_evaluate(args) -> int:
    check_output_path(args.output)
    frame = read_table(args.attitude)
    truth = _numeric_table(frame, args.truth_columns, args.attitude)
    estimate = _numeric_table(frame, args.estimate_columns, args.attitude)
    stats = compass.evaluate(estimate, truth, pitch_bands=args.pitch_bands,
                             remove_heading_offset=args.remove_heading_offset)
    stats["input"] = {"file": str(args.attitude), "truth_columns": list(args.truth_columns),
                      "estimate_columns": list(args.estimate_columns)}
    if stats["rows_skipped"]:
        warn(f"skipped {stats['rows_skipped']} row(s) without finite estimated and true angles")
    emit_json(stats, args.output)
    print(_format_stats(stats), file=sys.stderr)
    return 0


def _format_stats(stats) -> str:
    def cell(entry):
        if entry["max_abs"] is None:
            return f"{'-':>17}"
        return f"{entry['max_abs']:8.3f} {entry['rms']:8.3f}"

    lines = [f"{'|pitch| [deg]':>14} {'n':>6} {'roll max/rms':>17} {'pitch max/rms':>17} "
             f"{'heading max/rms':>17}"]
    rows = [(f"{b['pitch_min_deg']:g}-{b['pitch_max_deg']:g}", b) for b in stats["bands"]]
    rows.append(("all", stats["overall"]))
    for label, block in rows:
        lines.append(f"{label:>14} {block['n']:>6} {cell(block['roll'])} {cell(block['pitch'])} "
                     f"{cell(block['heading'])}")
    if stats["heading_offset_deg"] is not None:
        lines.append(f"heading offset removed: {stats['heading_offset_deg']:.3f} deg")
    return "\n".join(lines)
