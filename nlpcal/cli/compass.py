"""`nlpcal compass calibrate | attitude | evaluate`: the e-compass of Qiu et al. (2017).

calibrate: turn mode with --turn-column (the paper's protocol), free-rotation mode without it.
attitude: roll_deg, pitch_deg, heading_deg added to a log. evaluate: error statistics against true
attitude columns, overall and per pitch band (the paper's Table 2).
"""

from __future__ import annotations

from .common import (
    MODELS,
    add_command,
    add_field_argument,
    add_input_arguments,
    add_place_arguments,
    add_precision_argument,
    emit_json,
    report_log,
    say,
    solver_log,
    warn,
    warning,
)

ATTITUDE_COLUMNS = ("roll_deg", "pitch_deg", "heading_deg")
FIELD_UNITS = ("nT", "uT", "mT", "mG", "G", "T")
ACC_UNITS = ("g", "mg", "m/s2")
DEFAULT_REST_TOLERANCE = 0.02  # the library's nlpcal.compass.DEFAULT_REST_TOLERANCE [g]
DEFAULT_PITCH_BANDS = (0.0, 30.0, 60.0, 85.0, 90.0)  # nlpcal.compass.DEFAULT_PITCH_BANDS [deg]


def register(sub):
    parser = add_command(
        sub,
        "compass",
        help="e-compass (Qiu et al. 2017): calibrate a magnetometer + accelerometer, attitude",
        description="""\
An e-compass is a magnetometer and an accelerometer in one housing. Its calibration (Qiu et al.
2017) finds, for each sensor, the bias, the sensitivity of each axis and the small angles by
which it is mounted askew in the housing; then roll, pitch and heading follow from the two
vectors. Three actions: calibrate (from a log of many orientations), attitude (roll, pitch,
heading for a log) and evaluate (errors against true angles).""",
        examples=(
            "nlpcal compass calibrate log.csv -o compass.json",
            "nlpcal compass attitude compass.json log.csv -o attitude.csv",
            "nlpcal compass evaluate attitude.csv --truth-columns roll pitch yaw",
        ),
    )
    actions = parser.add_subparsers(
        dest="compass_command", metavar="ACTION", parser_class=type(parser), title="actions"
    )
    actions.required = True

    cal = add_command(
        actions,
        "calibrate",
        help="mounting angles, bias and sensitivity of both sensors",
        description="""\
Turn mode (--turn-column): the paper's protocol, one full turn of the housing about each of its
x, y and z axes (a sample every 30 deg is enough), then ellipsoid fits. Free-rotation mode (no
--turn-column): the sensors turned by hand through many orientations; ellipsoid fits and the
constancy of the dip angle between field and gravity. The sensor pair's orientation relative to
the housing is then not identifiable, and attitudes refer to the accelerometer's axes.
Units are read from the column names (mx_uT, "Accelerometer X (g)", ...) unless given, and
checked against Earth's field and gravity.""",
        examples=(
            "nlpcal compass calibrate log.csv -o compass.json",
            "nlpcal compass calibrate turns.csv --turn-column turn -o compass.json",
            "nlpcal compass calibrate log.csv --mag-columns 7 8 9 --acc-columns 1 2 3 "
            "--mag-unit uT --acc-unit m/s2",
        ),
    )
    cal.add_argument("log", metavar="LOG", help="the log: delimited text, or - for stdin")
    _add_sensor_arguments(cal, "nT", "g")
    cal.add_argument(
        "--turn-column",
        metavar="COL",
        help="column naming each sample's turn axis: x, y, z, optionally with a "
        "suffix for repeated turns (y2); absent selects free-rotation mode",
    )
    add_field_argument(
        cal,
        "known total field magnitude, in the magnetometer's unit (e.g. 48.5 for uT); default: "
        "estimated, with det(correction) = 1",
        legacy="--field-nt",
        legacy_dest="reference_field_nt",
    )
    cal.add_argument(
        "--ellipsoid-seed",
        choices=("linear", "centroid"),
        default="linear",
        help="start of the ellipsoid fits: linear least squares (default) or the centroid",
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

    att = add_command(
        actions,
        "attitude",
        help="add roll_deg, pitch_deg, heading_deg to a log",
        description="""\
Apply a compass calibration and compute roll, pitch and heading [deg] (Eq. 10 of Qiu et al.
2017) for every row; the log is written back in its own layout with the three columns added
(replacing columns of the same name).""",
        examples=("nlpcal compass attitude compass.json log.csv -o attitude.csv",),
    )
    att.add_argument(
        "calibration", metavar="COMPASS.json", help="written by 'nlpcal compass calibrate'"
    )
    att.add_argument("log", metavar="LOG", help="the log: delimited text, or - for stdin")
    _add_sensor_arguments(att, "the calibration's", "the calibration's")
    att.add_argument(
        "--declination-deg",
        type=float,
        metavar="DEG",
        help="magnetic declination [deg], east positive, added to give true heading (default 0; "
        "e.g. 2.5)",
    )
    att.add_argument(
        "--declination-model",
        choices=MODELS,
        help="take the declination from IGRF-14 or WMM2025 at --lat, --lon, --date (needs "
        "pip install 'nlpcal[geomag]')",
    )
    add_place_arguments(att, columns=False)
    att.add_argument(
        "-o",
        "--output",
        metavar="ATTITUDE",
        help="the log with the angles: Parquet for *.parquet, else text in the log's layout "
        "(stdout when absent)",
    )
    add_precision_argument(att)
    att.set_defaults(func=run_attitude)

    ev = add_command(
        actions,
        "evaluate",
        help="attitude error statistics against true attitude columns",
        description="""\
Max |error| and RMS of roll, pitch and heading, overall and per band of |true pitch| (Table 2 of
Qiu et al. 2017); JSON to -o or stdout, a table on stderr.""",
        examples=(
            "nlpcal compass evaluate attitude.csv --truth-columns true_roll true_pitch true_yaw",
        ),
    )
    ev.add_argument(
        "attitude", metavar="ATTITUDE", help="a log with estimated and true angles, or -"
    )
    add_input_arguments(ev)
    ev.add_argument(
        "--truth-columns",
        nargs=3,
        required=True,
        metavar=("ROLL", "PITCH", "HEADING"),
        help="true roll, pitch and heading columns [deg] (names or 0-based positions)",
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
        help="magnetometer columns, names or 0-based positions (default: recognised, bx/by/bz, "
        'mx/my/mz, mag_x/..., "Magnetometer X (uT)")',
    )
    parser.add_argument(
        "--acc-columns",
        nargs=3,
        metavar=("AX", "AY", "AZ"),
        help="accelerometer columns, names or 0-based positions (default: recognised, "
        "ax/ay/az, acc_x/...)",
    )
    parser.add_argument(
        "--mag-unit",
        choices=FIELD_UNITS,
        default=None,
        help=f"unit of the magnetometer columns (default: from their names, else {mag_fallback}); "
        "magnitudes far from Earth's field are warned about",
    )
    parser.add_argument(
        "--acc-unit",
        choices=ACC_UNITS,
        default=None,
        help=f"unit of the accelerometer columns (default: from their names, else {acc_fallback})",
    )
    add_input_arguments(parser)
    parser.add_argument(
        "--drop-invalid",
        action="store_true",
        help="skip rows with missing or non-numeric values, and rows repeating the row before "
        "(reporting how many), instead of failing",
    )


def _sensor_options(args) -> dict:
    return {
        "mag_columns": args.mag_columns,
        "acc_columns": args.acc_columns,
        "mag_unit": args.mag_unit,
        "acc_unit": args.acc_unit,
        "drop_invalid": args.drop_invalid,
        "header": args.header,
    }


def run_calibrate(args) -> int:
    from ..compass import calibrate_sensor_log
    from ..io import check_output_path, read_sensor_log

    check_output_path(args.output, args.log)
    legacy = getattr(args, "reference_field_nt", None)
    log = read_sensor_log(
        args.log,
        **_sensor_options(args),
        reference_field=legacy if legacy is not None else args.reference_field,
        reference_field_unit="nT" if legacy is not None else None,
    )
    report_log(log)
    if not args.turn_column:
        turns = [str(c) for c in log.frame.columns if "turn" in str(c).lower()]
        hint = (
            f"; the log has a column '{turns[0]}': --turn-column {turns[0]} selects turn mode, "
            f"the paper's protocol"
            if turns
            else ""
        )
        (warning if turns else warn)(
            "no --turn-column: free-rotation mode (the sensor pair's orientation relative to the "
            f"housing cannot be found; attitudes refer to the accelerometer's axes){hint}"
        )
    with solver_log():
        result = calibrate_sensor_log(
            log,
            turn_column=args.turn_column,
            ellipsoid_seed=args.ellipsoid_seed,
            rest_tolerance=args.rest_tolerance,
        )
    for message in result.warnings:
        warning(message)
    emit_json(result.to_dict(), args.output)
    if args.output:
        warn(f"wrote {args.output}")
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
    from ..io import Precision, check_output_path, read_sensor_log, read_table, write_table
    from ..io.output import check_table_output

    check_output_path(args.output, args.log, args.calibration)
    check_table_output(args.output)
    precision = Precision(args.precision)
    calibration = CompassCalibration.load(args.calibration)
    recorded = calibration.input
    options = _sensor_options(args)
    table = read_table(args.log, header=options.pop("header"), text=True)
    options["mag_columns"] = args.mag_columns or recorded.get("mag_columns")
    options["acc_columns"] = args.acc_columns or recorded.get("acc_columns")
    log = read_sensor_log(
        table,
        **options,
        mag_fallback=recorded.get("mag_unit", "nT"),
        acc_fallback=recorded.get("acc_unit", "g"),
    )
    report_log(log)
    result = attitude(calibration, log.mag, log.acc, declination_deg=_declination(args))
    for message in result.warnings:
        warning(message)
    frame, replaced = log.with_columns(
        dict(zip(ATTITUDE_COLUMNS, (result.roll_deg, result.pitch_deg, result.heading_deg)))
    )
    if replaced:
        warn(f"the log already has {', '.join(replaced)}; replaced them")
    precision.observe(table.frame[c] for c in [*log.mag_columns, *log.acc_columns])
    write_table(frame, log.layout, args.output, precision)  # the log's columns pass through
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
    from ..io import check_output_path
    from ..io.logs import read_role_columns

    check_output_path(args.output, args.attitude)
    truth, estimate = read_role_columns(
        args.attitude,
        {"--truth-columns": args.truth_columns, "--estimate-columns": args.estimate_columns},
        header=args.header,
    )
    stats = evaluate(
        estimate,
        truth,
        pitch_bands=args.pitch_bands,
        remove_heading_offset=args.remove_heading_offset,
    )
    stats["input"] = {
        "file": "stdin" if str(args.attitude) == "-" else str(args.attitude),
        "truth_columns": list(args.truth_columns),
        "estimate_columns": list(args.estimate_columns),
    }
    if stats["rows_skipped"]:
        warn(f"skipped {stats['rows_skipped']} row(s) without finite estimated and true angles")
    emit_json(stats, args.output)
    if args.output:
        warn(f"wrote {args.output}")
    say(format_evaluation(stats))
    return 0
