"""`nlpcal compass calibrate | attitude | evaluate`: the e-compass of Qiu et al. (2017).

calibrate: turn mode with --turn-column (the paper's protocol), free-rotation mode without it.
attitude: roll_deg, pitch_deg, heading_deg added to a log. evaluate: error statistics against true
attitude columns, overall and per pitch band (the paper's Table 2).
"""

from __future__ import annotations

import sys

from .common import MODELS, add_place_arguments, emit_csv, emit_json, tell, warn

ATTITUDE_COLUMNS = ("roll_deg", "pitch_deg", "heading_deg")
FIELD_UNITS = ("nT", "uT", "mT", "mG", "G", "T")
ACC_UNITS = ("g", "mg", "m/s2")
DEFAULT_REST_TOLERANCE = 0.02  # the library's nlpcal.compass.DEFAULT_REST_TOLERANCE [g]
DEFAULT_PITCH_BANDS = (0.0, 30.0, 60.0, 85.0, 90.0)  # nlpcal.compass.DEFAULT_PITCH_BANDS [deg]


def register(sub):
    parser = sub.add_parser(
        "compass",
        help="e-compass (Qiu 2017): calibrate magnetometer + accelerometer, attitude",
        description=__doc__.splitlines()[0],
    )
    actions = parser.add_subparsers(
        dest="compass_command", metavar="ACTION", parser_class=type(parser)
    )
    actions.required = True

    cal = actions.add_parser(
        "calibrate",
        help="mounting angles, bias and sensitivity of both sensors",
        description="Turn mode (--turn-column): the paper's turns about the housing x, y and z "
        "axes, then ellipsoid fits. Free-rotation mode (no --turn-column): ellipsoid "
        "fits and the dip-angle constancy; the sensor pair's orientation relative to "
        "the housing is then not identifiable.",
    )
    cal.add_argument("log", metavar="LOG.csv")
    _add_sensor_arguments(cal, "nT", "g")
    cal.add_argument(
        "--turn-column",
        metavar="COL",
        help="column naming each sample's turn axis: x, y, z, optionally with a "
        "suffix for repeated turns (y2); absent selects free-rotation mode",
    )
    cal.add_argument(
        "--field-nt",
        type=float,
        metavar="NT",
        help="local total field [nT] (default: estimated with det(correction) = 1)",
    )
    cal.add_argument(
        "--ellipsoid-seed",
        choices=("linear", "centroid"),
        default="linear",
        help="start of the ellipsoid NLPs (default linear least squares)",
    )
    cal.add_argument(
        "--rest-tolerance",
        type=float,
        default=DEFAULT_REST_TOLERANCE,
        metavar="G",
        help="free-rotation mode: samples whose calibrated |acc| differs from 1 g by "
        "more than this [g] are treated as moving and left out of the "
        "accelerometer fit and the alignment (default "
        f"{DEFAULT_REST_TOLERANCE:g}; 1 keeps every sample)",
    )
    cal.add_argument(
        "-o", "--output", metavar="COMPASS.json", help="calibration JSON (stdout when absent)"
    )
    cal.set_defaults(func=run_calibrate)

    att = actions.add_parser(
        "attitude",
        help="add roll_deg, pitch_deg, heading_deg to a log",
        description="Apply a compass calibration and compute roll, pitch and heading (Eq. 10).",
    )
    att.add_argument("calibration", metavar="COMPASS.json")
    att.add_argument("log", metavar="LOG.csv")
    _add_sensor_arguments(att, "the calibration's", "the calibration's")
    att.add_argument(
        "--declination-deg",
        type=float,
        metavar="DEG",
        help="magnetic declination [deg], east positive, added to give true heading (default 0)",
    )
    att.add_argument(
        "--declination-model",
        choices=MODELS,
        help="take the declination from IGRF-14 or WMM2025 at --lat, --lon, --date (needs "
        "pip install 'nlpcal[geomag]')",
    )
    add_place_arguments(att, columns=False)
    att.add_argument(
        "-o", "--output", metavar="ATTITUDE.csv", help="output CSV (stdout when absent)"
    )
    att.set_defaults(func=run_attitude)

    ev = actions.add_parser(
        "evaluate",
        help="attitude error statistics against true attitude columns",
        description="Max |error| and RMS of roll, pitch and heading, overall and per band of "
        "|true pitch|; JSON to -o or stdout, a table on stderr.",
    )
    ev.add_argument("attitude", metavar="ATTITUDE.csv")
    ev.add_argument(
        "--truth-columns",
        nargs=3,
        required=True,
        metavar=("ROLL", "PITCH", "HEADING"),
        help="true roll, pitch and heading columns [deg]",
    )
    ev.add_argument(
        "--estimate-columns",
        nargs=3,
        default=list(ATTITUDE_COLUMNS),
        metavar=("ROLL", "PITCH", "HEADING"),
        help="estimated columns [deg] (default roll_deg pitch_deg heading_deg)",
    )
    ev.add_argument(
        "--pitch-bands",
        nargs="+",
        type=float,
        default=list(DEFAULT_PITCH_BANDS),
        metavar="DEG",
        help="edges of |true pitch| bands [deg] (default 0 30 60 85 90)",
    )
    ev.add_argument(
        "--remove-heading-offset",
        action="store_true",
        help="subtract the circular mean heading error first (reference with an arbitrary north)",
    )
    ev.add_argument(
        "-o", "--output", metavar="STATS.json", help="statistics JSON (stdout when absent)"
    )
    ev.set_defaults(func=run_evaluate)


def _add_sensor_arguments(parser, mag_fallback: str, acc_fallback: str):
    parser.add_argument(
        "--mag-columns",
        nargs=3,
        metavar=("MX", "MY", "MZ"),
        help="magnetometer columns (default: detected, bx/by/bz, mx/my/mz, ...)",
    )
    parser.add_argument(
        "--acc-columns",
        nargs=3,
        metavar=("AX", "AY", "AZ"),
        help="accelerometer columns (default: detected, ax/ay/az, acc_x/...)",
    )
    parser.add_argument(
        "--mag-unit",
        choices=FIELD_UNITS,
        default=None,
        help=f"unit of the magnetometer columns (default: from their names, else {mag_fallback})",
    )
    parser.add_argument(
        "--acc-unit",
        choices=ACC_UNITS,
        default=None,
        help=f"unit of the accelerometer columns (default: from their names, else {acc_fallback})",
    )
    parser.add_argument(
        "--drop-invalid",
        action="store_true",
        help="skip rows with missing or non-numeric values (reporting how many) instead of failing",
    )


def _sensor_options(args) -> dict:
    return {
        "mag_columns": args.mag_columns,
        "acc_columns": args.acc_columns,
        "mag_unit": args.mag_unit,
        "acc_unit": args.acc_unit,
        "drop_invalid": args.drop_invalid,
    }


def run_calibrate(args) -> int:
    from ..compass import calibrate_sensor_log
    from ..io import check_output_path, read_sensor_log

    check_output_path(args.output, args.log)
    log = read_sensor_log(args.log, **_sensor_options(args))
    tell(log.notes)
    if not args.turn_column:
        warn(
            "no --turn-column: free-rotation mode (the sensor pair's orientation relative to the "
            "housing cannot be found; attitudes refer to the accelerometer's axes)"
        )
    result = calibrate_sensor_log(
        log,
        turn_column=args.turn_column,
        field_nt=args.field_nt,
        ellipsoid_seed=args.ellipsoid_seed,
        rest_tolerance=args.rest_tolerance,
    )
    tell(result.warnings)
    emit_json(result.to_dict(), args.output)
    for sensor in (result.magnetometer, result.accelerometer):
        angles = sensor.to_dict()["mounting_deg"]
        warn(
            f"{sensor.sensor}: mounting [deg] "
            + ", ".join(f"{k} {v:+.4f}" for k, v in angles.items())
            + f"; |v| residual RMS {sensor.quality['magnitude_residual_rms']:.3g} {sensor.unit}"
        )
    return 0


def run_attitude(args) -> int:
    from ..compass import CompassCalibration, attitude
    from ..io import check_output_path, read_sensor_log

    check_output_path(args.output, args.log, args.calibration)
    calibration = CompassCalibration.load(args.calibration)
    recorded = calibration.input
    options = _sensor_options(args)
    options["mag_columns"] = args.mag_columns or recorded.get("mag_columns")
    options["acc_columns"] = args.acc_columns or recorded.get("acc_columns")
    log = read_sensor_log(
        args.log,
        **options,
        mag_fallback=recorded.get("mag_unit", "nT"),
        acc_fallback=recorded.get("acc_unit", "g"),
    )
    tell(log.notes)
    result = attitude(calibration, log.mag, log.acc, declination_deg=_declination(args))
    tell(result.warnings)
    frame, replaced = log.with_columns(
        dict(zip(ATTITUDE_COLUMNS, (result.roll_deg, result.pitch_deg, result.heading_deg)))
    )
    if replaced:
        warn(f"the log already has {', '.join(replaced)}; replaced them")
    emit_csv(frame, args.output)  # exact values: the log's own columns pass through unchanged
    return 0


def _declination(args) -> float:
    """--declination-deg, or the declination of --declination-model at the place and date."""
    from ..errors import InputError
    from ..geomagnetic import declination

    place = [args.lat, args.lon, args.alt_m, args.date]
    if args.declination_model is None:
        if any(v is not None for v in place):
            raise InputError("--lat, --lon, --alt-m and --date need --declination-model igrf|wmm")
        return args.declination_deg or 0.0
    if args.declination_deg is not None:
        raise InputError("give --declination-deg or --declination-model, not both")
    if args.lat is None or args.lon is None or args.date is None:
        raise InputError("--declination-model needs --lat DEG --lon DEG --date YYYY-MM-DD")
    value, block = declination(
        args.declination_model, args.lat, args.lon, args.alt_m or 0.0, args.date
    )
    warn(
        f"declination {value:+.3f} deg east from {block['name']} ({block['package']} "
        f"{block['package_version']}) at {args.lat:g}, {args.lon:g}, {args.date}"
    )
    return value


def run_evaluate(args) -> int:
    from ..compass import evaluate, format_evaluation
    from ..io import check_output_path, read_columns

    check_output_path(args.output, args.attitude)
    truth = read_columns(args.attitude, args.truth_columns)
    estimate = read_columns(args.attitude, args.estimate_columns)
    stats = evaluate(
        estimate,
        truth,
        pitch_bands=args.pitch_bands,
        remove_heading_offset=args.remove_heading_offset,
    )
    stats["input"] = {
        "file": str(args.attitude),
        "truth_columns": list(args.truth_columns),
        "estimate_columns": list(args.estimate_columns),
    }
    if stats["rows_skipped"]:
        warn(f"skipped {stats['rows_skipped']} row(s) without finite estimated and true angles")
    emit_json(stats, args.output)
    print(format_evaluation(stats), file=sys.stderr)
    return 0
