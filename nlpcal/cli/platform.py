"""`nlpcal platform fit|apply`: Tolles-Lawson compensation of a scalar magnetometer for the field
of the platform it rides on, from a vector magnetometer's direction cosines.

    nlpcal platform fit LOG --scalar-column COL [--columns X Y Z] [--terms 18|16]
                        [--band LOW_HZ HIGH_HZ] [--aux-columns COL ...] [--time-column COL]
                        [--rate HZ] -o tl.json
    nlpcal platform apply tl.json LOG -o OUT.csv

The library does the work (`nlpcal.platform`); this module parses and prints.
"""

from __future__ import annotations

from .common import (
    FIELD_UNITS,
    LOG_HELP,
    add_command,
    add_input_arguments,
    emit_json,
    report_log,
    say,
    tell_written,
    warn,
)

#: `nlpcal.platform.terms.TERM_SETS` and `nlpcal.platform.bandpass.DEFAULT_BAND_HZ`, spelled out
#: so that the command line starts without numpy.
TERM_SETS = (18, 16)
DEFAULT_BAND_HZ = (0.1, 0.9)

DESCRIPTION = """\
Compensate a scalar magnetometer (a proton, Overhauser or optically pumped sensor measuring |B|)
for the field of the platform it rides on, the Tolles-Lawson model (Tolles and Lawson 1950;
Leliak 1961; Gnadt et al. 2022, MagNav.jl): 3 permanent terms in the direction cosines of the
Earth's field, which a vector magnetometer on the platform gives, 6 induced terms (times |B|)
and 9 eddy-current terms (times |B| and the cosines' rates); 16 without the two that the
identity cos^2 X + cos^2 Y + cos^2 Z = 1 makes collinear. The fit wants a record of manoeuvres
(the figure-of-merit box: pitch, roll and yaw on four headings) in a quiet field."""


def register(sub):
    parser = add_command(
        sub,
        "platform",
        help="Tolles-Lawson compensation of a scalar magnetometer for its platform's field",
        description=DESCRIPTION,
        examples=(
            "nlpcal platform fit box.csv --scalar-column mag_1_nT --columns flux_x flux_y flux_z "
            "--time-column t -o tl.json",
            "nlpcal platform apply tl.json survey.csv -o compensated.csv",
        ),
    )
    inner = parser.add_subparsers(
        dest="platform_command",
        metavar="SUBCOMMAND",
        parser_class=type(parser),
        title="subcommands",
    )
    inner.required = True
    _register_fit(inner)
    _register_apply(inner)


def _register_fit(inner):
    fit = add_command(
        inner,
        "fit",
        help="fit the Tolles-Lawson coefficients to a calibration flight (one pass, ridge)",
        description=f"""\
{DESCRIPTION}

The scalar and every term are band-passed (--band; a Butterworth filter of order 4 applied
twice, forwards: the magnitude response of MagNav's zero-phase filter, in one pass over the
log) and the band-passed scalar regressed on the band-passed terms by ridge regression, its
parameter chosen by generalised cross-validation. The document written gives the coefficients
with their names and units, the std of the band-passed scalar before and after
(improvement_ratio, compensated_std), the condition number and each coefficient's variance
inflation, and says whether the coefficients mean anything one by one (with 18 terms they never
do: only the compensation they give together does). Every row must be a reading, sampled
regularly: the rate comes from --time-column (irregular sampling is refused) or --rate.""",
        examples=(
            "nlpcal platform fit box.csv --scalar-column mag_1_nT --time-column t -o tl.json",
            "nlpcal platform fit box.csv --scalar-column mag_1_nT --columns flux_x flux_y flux_z "
            "--terms 16 --band 0.1 0.9 --rate 10 -o tl.json",
            "nlpcal platform fit box.csv --scalar-column mag_1_nT --aux-columns current_A "
            "--time-column t -o tl.json",
        ),
    )
    fit.add_argument("log", metavar="LOG", help=LOG_HELP)
    fit.add_argument(
        "--scalar-column",
        required=True,
        metavar="COL",
        help="column of the scalar magnetometer (name or 0-based position), in the unit its "
        "name carries (mag_1_nT), else the field columns'",
    )
    _add_vector_arguments(fit)
    fit.add_argument(
        "--terms",
        type=int,
        choices=TERM_SETS,
        default=18,
        help="18: 3 permanent, 6 induced, 9 eddy (default); 16: without cos^2 Z and "
        "cos Z d(cos Z)/dt, collinear with the others",
    )
    fit.add_argument(
        "--band",
        nargs=2,
        type=float,
        metavar=("LOW_HZ", "HIGH_HZ"),
        default=DEFAULT_BAND_HZ,
        help="the band-pass [Hz] (default 0.1 0.9, MagNav's at 10 Hz): above the geology and "
        "the diurnal variation, below the noise, about the manoeuvres",
    )
    fit.add_argument(
        "--aux-columns",
        nargs="+",
        default=(),
        metavar="COL",
        help="auxiliary channels taken as further regressors (motor current, heater), one "
        "coefficient each [scalar unit per channel unit]",
    )
    fit.add_argument(
        "--time-column",
        metavar="COL",
        help="column of times: seconds (Unix or from any start) or ISO 8601 text; gives the "
        "sample rate, which must be regular",
    )
    fit.add_argument(
        "--rate", type=float, metavar="HZ", help="the sample rate [Hz], without a time column"
    )
    fit.add_argument(
        "-o", "--output", metavar="TL.json", help="write the fit here (stdout when absent)"
    )
    fit.set_defaults(func=run_fit)


def _add_vector_arguments(parser):
    parser.add_argument(
        "--columns",
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="the vector magnetometer's three columns, by name or 0-based position (default: "
        "recognised from the names, as in 'nlpcal calibrate')",
    )
    parser.add_argument(
        "--unit",
        choices=FIELD_UNITS,
        help="unit of the vector magnetometer's columns (default: from their names, else nT)",
    )
    add_input_arguments(parser)


def _register_apply(inner):
    apply = add_command(
        inner,
        "apply",
        help="add the compensated scalar to a log",
        description="""\
Write the log with a column '<scalar column>_compensated' added last: the scalar less the
platform's field the fit's coefficients predict from the log's vector magnetometer (and
channels), less its mean (the band-pass cannot see a constant, so the scalar keeps its mean).
The log is read with the fit's columns, must have every row a reading, and is taken to be
sampled at the fit's rate (checked against the fit's time column when the log has it). An
output named *.parquet is a Parquet file; any other is text in the log's layout, every other
column passing through.""",
        examples=(
            "nlpcal platform apply tl.json survey.csv -o compensated.csv",
            "nlpcal platform apply tl.json survey.csv -o compensated.parquet",
        ),
    )
    apply.add_argument("fit", metavar="TL.json", help="the output of 'nlpcal platform fit'")
    apply.add_argument("log", metavar="LOG", help=LOG_HELP)
    apply.add_argument(
        "--unit",
        choices=FIELD_UNITS,
        help="unit of the vector magnetometer's columns (default: from their names, else the "
        "fitted log's)",
    )
    add_input_arguments(apply)
    apply.add_argument(
        "-o",
        "--output",
        metavar="OUT",
        help="write the log here: Parquet for *.parquet, else text in the log's layout "
        "(stdout when absent)",
    )
    apply.set_defaults(func=run_apply)


def run_fit(args) -> int:
    from ..io import check_output_path
    from ..platform import fit_platform_log, read_platform_log

    check_output_path(args.output, args.log)
    record = read_platform_log(
        args.log,
        args.scalar_column,
        columns=args.columns,
        unit=args.unit,
        aux_columns=args.aux_columns,
        time_column=args.time_column,
        header=args.header,
    )
    report_log(record.log)
    fit = fit_platform_log(
        record, rate_hz=args.rate, terms=args.terms, band_hz=args.band, time_column=args.time_column
    )
    warn(
        f"Tolles-Lawson, {fit.terms} terms"
        + (f" and {len(fit.aux_columns)} channel(s)" if fit.aux_columns else "")
        + f", {fit.band_hz[0]:g}-{fit.band_hz[1]:g} Hz at {fit.sample_rate_hz:.6g} Hz, "
        f"{fit.n} rows: band-passed std {fit.uncompensated_std:.4g} -> "
        f"{fit.compensated_std:.4g} {fit.unit} (improvement ratio "
        f"{fit.improvement_ratio:.4g}); ridge parameter {fit.ridge_parameter:.3g}"
    )
    say(fit.statement)
    emit_json(fit.to_dict(), args.output)
    tell_written(args.output)
    return 0


def run_apply(args) -> int:
    from ..io import Precision, check_output_path, write_table
    from ..io.output import check_table_output
    from ..platform import TollesLawsonFit, apply_platform_log

    check_output_path(args.output, args.log, args.fit)
    check_table_output(args.output)
    fit = TollesLawsonFit.load(args.fit)
    frame, record = apply_platform_log(fit, args.log, header=args.header, unit=args.unit)
    report_log(record.log)
    precision = Precision()
    precision.observe([record.table.frame[record.scalar_name]])
    write_table(frame, record.log.layout, args.output, precision)
    tell_written(args.output)
    return 0
