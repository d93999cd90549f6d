"""What every subcommand shares: the parser class, common arguments and output helpers.

Messages go to stderr at three levels, set once per run from -q/--quiet and -v/--verbose (every
command and subcommand has both, before or after its name): with -q nothing but errors; by
default `warn`/`tell` (what nlpcal did or decided on the user's behalf, "wrote ..."), `warning`
(what looks wrong: "nlpcal: warning: ...") and `say` (tables); with -v also `detail` (how the log
was read, timings) and, through `solver_log`, IPOPT's own log.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

#: Field units accepted by --unit (the library's `nlpcal.units.FIELD_UNITS_NT`).
FIELD_UNITS = ("nT", "uT", "mT", "mG", "G", "T", "raw")

#: -1 quiet, 0 normal, 1 verbose; set by `set_verbosity` at the start of a run.
VERBOSITY = 0


class UsageError(Exception):
    """A command line that argparse cannot parse; `prog` is the (sub)command it concerns."""

    def __init__(self, message: str, prog: str = "nlpcal"):
        super().__init__(message)
        self.prog = prog


class Parser(argparse.ArgumentParser):
    """argparse that raises instead of exiting, so that main() keeps the exit status."""

    def error(self, message):
        raise UsageError(f"{self.prog}: error: {message}", self.prog)


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and examples keep their line breaks; argument help is wrapped."""

    def __init__(self, prog):
        super().__init__(prog, max_help_position=30, width=100)


def add_command(sub, name: str, *, help: str, description: str, examples=(), **options):
    """A subcommand parser with the shared formatting and its examples (command lines, each a
    string) at the end of its help; -v/-q are added to every parser by `add_verbosity`.
    `options` go to argparse (`parents`, say)."""
    epilog = None
    if examples:
        epilog = "examples:\n" + "\n".join(f"  {line}" for line in examples)
    return sub.add_parser(
        name,
        help=help,
        description=description,
        epilog=epilog,
        formatter_class=HelpFormatter,
        **options,
    )


def at_least(minimum: int):
    """An argparse type: a whole number of at least `minimum`."""

    def whole_number(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected at least {minimum}, got {value}")
        return value

    return whole_number


#: A count (threads, workers, cycles ...). A 0-based index (a compass instance).
at_least_one, at_least_zero = at_least(1), at_least(0)


def add_verbosity(parser) -> None:
    """-v/--verbose and -q/--quiet on a parser and, recursively, on its subcommands; the value
    given anywhere on the command line wins (subcommands leave the default to the top)."""
    top = parser.prog == "nlpcal"
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        default=False if top else argparse.SUPPRESS,
        help="also say how the input was read, timings, and show IPOPT's log",
    )
    group.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        default=False if top else argparse.SUPPRESS,
        help="no messages on stderr but errors",
    )
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):
                add_verbosity(child)


def set_verbosity(args) -> None:
    global VERBOSITY
    ACKNOWLEDGED.clear()
    VERBOSITY = -1 if getattr(args, "quiet", False) else int(bool(getattr(args, "verbose", False)))


def warn(message: str) -> None:
    """A human message on stderr: what nlpcal did or decided (silent with -q)."""
    if VERBOSITY >= 0:
        print(f"nlpcal: {message}", file=sys.stderr)


def warning(message: str) -> None:
    """Something that looks wrong, on stderr (silent with -q)."""
    if VERBOSITY >= 0:
        print(f"nlpcal: warning: {message}", file=sys.stderr)


def detail(message: str) -> None:
    """A message on stderr with -v only."""
    if VERBOSITY >= 1:
        print(f"nlpcal: {message}", file=sys.stderr)


def say(text: str) -> None:
    """Human text (a table, say) on stderr, silent with -q."""
    if VERBOSITY >= 0:
        print(text, file=sys.stderr)


def progress(message: str, done: bool = False) -> None:
    """A progress line on stderr, rewritten in place: only when stderr is a terminal and not -q."""
    if VERBOSITY < 0 or not sys.stderr.isatty():
        return
    sys.stderr.write(f"\r\033[K{message}" + ("\n" if done else ""))
    sys.stderr.flush()


def show_progress(label: str, output=None):
    """The progress line of a pass (`nlpcal.io.progress`): on a terminal stderr, not with -q,
    and not while the data go to the same terminal on stdout."""
    from ..io.progress import Progress

    on_screen = (output is None or str(output) == "-") and sys.stdout.isatty()
    enabled = VERBOSITY >= 0 and sys.stderr.isatty() and not on_screen
    return Progress(label, enabled=enabled)


def add_sensor_id_argument(parser) -> None:
    """--sensor-id: the identity of the sensor, recorded in the result and in exports."""
    parser.add_argument(
        "--sensor-id",
        metavar="ID",
        help="the sensor calibrated: its autopilot device id (an integer, as in ArduPilot's "
        "COMPASS_DEV_ID or PX4's CAL_MAGn_ID) or a name; recorded as sensor_id in the result "
        "and written by the ardupilot and px4 exports",
    )


def tell_written(*paths) -> None:
    """ "wrote PATH" for each output written to a path (not stdout), silent with -q."""
    for path in paths:
        if path and str(path) != "-":
            warn(f"wrote {path}")


def tell(notes) -> None:
    """What the library decided on the user's behalf, one line each on stderr (not with -q)."""
    for note in notes:
        warn(note)


def report_log(log) -> None:
    """How a log was read (-v), what the reader decided and what looks wrong (not with -q), and
    the acknowledgement its data require (`acknowledge`)."""
    reading = log.reading() if hasattr(log, "reading") else log.layout.describe()
    detail(f"read {log.path}: {reading}")
    tell(log.notes)
    for message in log.warnings:
        warning(message)
    acknowledge(getattr(log, "observatory", None))


#: The terms of use printed by this run (each once).
ACKNOWLEDGED: set = set()


def acknowledge(source) -> None:
    """The acknowledgement a data set requires (an observatory file's terms of use), on stderr
    once per run wherever results from it are shown, -q or not: it is a condition of using the
    data, not a message. `source`: an `nlpcal.io.observatory.Observatory`, a result whose input
    came from one, or None."""
    from ..io.observatory import terms_of_use

    terms = terms_of_use(source)
    if terms and terms not in ACKNOWLEDGED:
        ACKNOWLEDGED.add(terms)
        print(f"nlpcal: terms of use of the data: {terms}", file=sys.stderr)


def solver_log():
    """IPOPT's log (printed through Python's stdout by CasADi: with -v, or a print_level given by
    --ipopt-option) goes to stderr, never into the data on stdout."""
    return contextlib.redirect_stdout(sys.stderr)


def add_input_arguments(parser) -> None:
    """--header / --no-header: force or deny a header row (default: detected)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--header",
        dest="header",
        action="store_const",
        const=True,
        default=None,
        help="the first line that is not a # comment names the columns (default: detected)",
    )
    group.add_argument(
        "--no-header",
        dest="header",
        action="store_const",
        const=False,
        help="the file has no header row: columns are 0, 1, 2, ... (default: detected)",
    )


def add_log_arguments(
    parser,
    default_from: str = 'the column names (mx_uT, "X (uT)", _gauss, _counts ...), else nT',
    choices=FIELD_UNITS,
) -> None:
    """--columns, --unit, --header/--no-header and --drop-invalid, shared by every command that
    reads a field log."""
    parser.add_argument(
        "--columns",
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="the three field columns, by name or 0-based position (e.g. --columns mx my mz, "
        "--columns 1 2 3); default: recognised from the names (bx/by/bz, x/y/z, mag_x/..., "
        "mx_uT/...), or, without a header row, the only three columns or the three after a "
        "leading time column",
    )
    parser.add_argument(
        "--unit",
        choices=choices,
        default=None,
        help=f"unit of the field columns, and of a reference whose name carries none "
        f"(default: from {default_from})"
        + ("; 'raw' keeps counts" if "raw" in choices else "")
        + ". Magnitudes far from Earth's 22 000-67 000 nT are warned about, with the units "
        "that would fit; a unit given here is used as given",
    )
    add_input_arguments(parser)
    add_recorded_arguments(parser)
    parser.add_argument(
        "--drop-invalid",
        action="store_true",
        help="drop rows with missing or non-numeric values, and rows repeating the field "
        "vector of the row before (a stuck or oversampling logger), reporting how many, "
        "instead of failing on the first and keeping the second. Rows reading exactly "
        "(0, 0, 0) are always left out",
    )


def add_recorded_arguments(parser) -> None:
    """--variable (a MATLAB .mat file) and --instance (an ArduPilot DataFlash log)."""
    parser.add_argument(
        "--variable",
        metavar="NAME",
        help="the variable of a MATLAB .mat file that holds the field: an N x 3 array or a "
        "struct with magnetometer fields (default: the only one, or the only one whose name "
        "says mag)",
    )
    parser.add_argument(
        "--instance",
        type=at_least_zero,
        metavar="N",
        help="the compass of an ArduPilot DataFlash .bin log, 0-based like the I field of its "
        "MAG messages (MAG2 is 1, MAG3 is 2 in older logs); needed when it has several",
    )


def table_options(args) -> dict:
    """The keyword arguments of `nlpcal.io.read_table` that the common arguments give."""
    return {
        "header": getattr(args, "header", None),
        "variable": getattr(args, "variable", None),
        "instance": getattr(args, "instance", None),
    }


def add_field_argument(
    parser,
    help: str,
    *,
    legacy: str | None = None,
    legacy_dest: str = "reference_field",
    required: bool = False,
):
    """--reference-field F, the one name of a known field magnitude in every command, in a
    mutually exclusive group (returned) with the hidden old name `legacy` (stored in
    `legacy_dest`: "reference_field" when it meant the same, "reference_field_nt" when it was in
    nT where the new name takes the field columns' unit)."""
    group = parser.add_mutually_exclusive_group(required=required)
    group.add_argument("--reference-field", type=float, metavar="F", help=help)
    if legacy:
        group.add_argument(legacy, dest=legacy_dest, type=float, help=argparse.SUPPRESS)
    return group


def add_reference_arguments(parser) -> None:
    """--reference-field F | --reference-column COL."""
    ref = add_field_argument(
        parser,
        "known total field magnitude, in the unit of the field columns (e.g. 48500 for nT, "
        "or a proton magnetometer reading): fits |B1| to it instead of only flattening it, "
        "which also fixes the absolute scale",
    )
    ref.add_argument(
        "--reference-column",
        metavar="COL",
        help="column of per-sample reference magnitudes (name or 0-based position), in the "
        "unit its name carries (proton_nT) or the field columns' unit; with --reference-log, "
        "the column of that log",
    )
    add_reference_log_arguments(parser)
    add_reference_model_arguments(parser)


def add_reference_log_arguments(parser) -> None:
    """--reference-log FILE, --reference-time-column COL, --interpolation linear|cubic."""
    group = parser.add_argument_group(
        "reference with its own time base (the log's times from --time-column, or an "
        "observatory file's)"
    )
    group.add_argument(
        "--reference-log",
        metavar="FILE",
        help="read the reference column (--reference-column) from this log, with its own "
        "times, and interpolate it onto the log's times; rows of the log outside its span, or "
        "inside a gap longer than 3 of its steps, are dropped and counted",
    )
    group.add_argument(
        "--reference-time-column",
        metavar="COL",
        help="the reference log's column of times: ISO 8601 or seconds, on the same clock as "
        "the log's (default: 'time' in an observatory file, else the log's --time-column name)",
    )
    group.add_argument(
        "--interpolation",
        choices=("linear", "cubic"),
        default="linear",
        help="how the reference is interpolated: linear, or a cubic spline (needs scipy: "
        "pip install 'nlpcal[spline]') (default: linear)",
    )


MODELS = ("igrf", "wmm")  # the library's nlpcal.geomagnetic.MODELS


def add_place_arguments(parser, columns: bool = True) -> None:
    """--lat, --lon, --alt-m, --date, and with `columns` their per-sample column forms."""
    parser.add_argument("--lat", type=float, metavar="DEG", help="geodetic latitude [deg], north +")
    parser.add_argument("--lon", type=float, metavar="DEG", help="longitude [deg], east +")
    parser.add_argument(
        "--alt-m",
        type=float,
        metavar="M",
        help="height above the WGS 84 ellipsoid [m] (default 0)",
    )
    parser.add_argument("--date", metavar="YYYY-MM-DD", help="date (UTC) of the measurement")
    if columns:
        parser.add_argument("--lat-column", metavar="COL", help="column of latitudes [deg]")
        parser.add_argument("--lon-column", metavar="COL", help="column of longitudes [deg]")
        parser.add_argument("--alt-column", metavar="COL", help="column of heights [m]")
        parser.add_argument(
            "--time-column",
            metavar="COL",
            help="column of UTC times: ISO 8601 text, or Unix seconds",
        )


def add_reference_model_arguments(parser) -> None:
    """--reference-model igrf|wmm with the place and date, constant or per sample."""
    group = parser.add_argument_group(
        "reference field from a geomagnetic model (pip install 'nlpcal[geomag]')"
    )
    group.add_argument(
        "--reference-model",
        choices=MODELS,
        help="the model's total field at the place and date becomes the reference: igrf "
        "(IGRF-14, 1900-2030) or wmm (WMM2025, 2025-2030); per sample with the column options",
    )
    add_place_arguments(group)


def reference_model(args):
    """The `nlpcal.geomagnetic.ReferenceModel` the arguments ask for, or None."""
    from ..errors import InputError
    from ..geomagnetic import ReferenceModel

    names = ("lat", "lon", "alt_m", "date", "lat_column", "lon_column", "alt_column", "time_column")
    given = {name: getattr(args, name, None) for name in names}
    model = getattr(args, "reference_model", None)
    if model is None:
        timed = getattr(args, "reference_log", None) is not None  # the log's times serve it too
        timed = timed or getattr(args, "time_drift", "none") != "none"
        timed = timed or hasattr(args, "lag")  # a command with --lag reads --time-column itself
        timed = timed or getattr(args, "log_time_column", False)  # apply: a time drift's times
        used = [
            f"--{name.replace('_', '-')}"
            for name, value in given.items()
            if value is not None and not (timed and name == "time_column")
        ]
        if used:
            raise InputError(f"{', '.join(used)} need --reference-model igrf|wmm")
        return None
    spec = ReferenceModel(
        model=model,
        lat_deg=given["lat"],
        lon_deg=given["lon"],
        alt_m=given["alt_m"],
        date=given["date"],
        lat_column=given["lat_column"],
        lon_column=given["lon_column"],
        alt_column=given["alt_column"],
        time_column=given["time_column"],
    )
    spec.check()
    return spec


def add_threads_argument(parser) -> None:
    """--threads N."""
    parser.add_argument(
        "--threads",
        type=at_least_one,
        metavar="N",
        help="threads of the passes over the data (default: the cores available to the "
        "process, within its CPU affinity and cgroup quota)",
    )


def add_loss_arguments(parser) -> None:
    """--loss l2|huber|cauchy and --loss-scale F."""
    parser.add_argument(
        "--loss",
        choices=("l2", "huber", "cauchy"),
        default="l2",
        help="l2: least squares (default, the paper's); huber or cauchy: robust to spikes and "
        "other outliers, which they down-weight",
    )
    parser.add_argument(
        "--loss-scale",
        type=float,
        metavar="F",
        help="residual of |B1| beyond which a sample is down-weighted [unit] (default: 1.345 "
        "(huber) or 2.385 (cauchy) times the robust standard deviation, 1.4826 MAD, of the "
        "residuals)",
    )


def add_scheduler_arguments(parser) -> None:
    """--scheduler and --workers: run on Dask (the `dask` extra) instead of in this process."""
    parser.add_argument(
        "--scheduler",
        metavar="ADDRESS|processes|threads|local",
        help="run on Dask (pip install 'nlpcal[dask]'): 'threads' or 'processes' (Dask's own "
        "schedulers in this process), 'local' (a cluster of this machine, one worker process "
        "per core), or the address of a running scheduler (tcp://host:8786) or its scheduler "
        "file; without it everything runs in this process",
    )
    parser.add_argument(
        "--workers",
        type=at_least_one,
        metavar="N",
        help="worker processes of --scheduler local or processes (default: one per core; at "
        "most 4 per core)",
    )


def log_options(args) -> dict:
    """The keyword arguments of `nlpcal.io.read_log` that the common arguments give."""
    options = {
        "columns": args.columns,
        "unit": args.unit,
        "drop_invalid": args.drop_invalid,
        **table_options(args),
        "reference_column": getattr(args, "reference_column", None),
        "reference_field": getattr(args, "reference_field", None),
        "reference_model": reference_model(args),
    }
    legacy = getattr(args, "reference_field_nt", None)
    if legacy is not None:
        options.update(reference_field=legacy, reference_field_unit="nT")
    spec = reference_log(args)
    if spec is not None:
        options.update(reference_column=None, reference_log=spec)
    if options["reference_model"] is None and own_time_column(args):
        options["time_column"] = args.time_column
    return options


def reference_log(args):
    """The `nlpcal.io.reference.ReferenceLog` that --reference-log and its options ask for, or
    None; InputError for its options without it."""
    from ..errors import InputError
    from ..io.reference import ReferenceLog

    path = getattr(args, "reference_log", None)
    if path is None:
        if getattr(args, "reference_time_column", None) is not None:
            raise InputError("--reference-time-column needs --reference-log FILE")
        if getattr(args, "interpolation", "linear") != "linear":
            raise InputError("--interpolation needs --reference-log FILE")
        return None
    if getattr(args, "reference_column", None) is None:
        raise InputError("--reference-log needs --reference-column COL, its column of values")
    return ReferenceLog(
        path=path,
        column=args.reference_column,
        time_column=args.reference_time_column,
        log_time_column=getattr(args, "time_column", None),
        interpolation=args.interpolation,
    )


def own_time_column(args) -> str | None:
    """--time-column of a command with --lag, read without a geomagnetic model or a reference
    log (which read it themselves)."""
    if not hasattr(args, "lag") or getattr(args, "reference_model", None) is not None:
        return None
    if getattr(args, "reference_log", None) is not None:
        return None
    return getattr(args, "time_column", None)


def add_lag_argument(parser) -> None:
    """--lag auto|SECONDS: the lag of a reference series (`nlpcal.lag`)."""
    parser.add_argument(
        "--lag",
        metavar="auto|SECONDS",
        help="lag of the reference series against the field columns [s], positive when the "
        "reference is late: 'auto' estimates it (with the nine parameters in calibrate) and "
        "reports its standard error, a number takes it out; needs --reference-column and "
        "--time-column (ISO 8601 text, or seconds from any origin)",
    )
    parser.add_argument(
        "--lag-tolerance",
        metavar="SECONDS",
        type=float,
        help="a lag 'auto' is estimated when it stands 3 standard errors from zero or its "
        "standard error is within this tolerance, else undetermined [s] (default: 0.01, the "
        "time-stamp accuracy of INTERMAGNET one-second data)",
    )


def emit_json(document, output) -> None:
    """JSON to -o or to stdout (`nlpcal.io.files.Outputs`); strict (`nlpcal.io.strict`:
    finite numbers, no null)."""
    from ..io.files import write_json_atomic
    from ..io.strict import strict

    write_json_atomic(output, strict(document))


def add_precision_argument(parser):
    parser.add_argument(
        "--precision",
        type=int,
        metavar="N",
        help="significant digits of the numbers written to a text output (default: one more "
        "than the input's numbers carry; every digit of a float64 from Parquet input)",
    )


def emit_table(frame, output, digits: int | None = None) -> None:
    """A table to -o or to stdout: Parquet for *.parquet, else CSV (`nlpcal.io.write_table`);
    every digit of a float64 unless `digits` (significant); finite (`nlpcal.io.strict`)."""
    from ..io import Precision, write_table
    from ..io.output import check_table_output

    check_table_output(output)
    write_table(frame, None, output, Precision(digits))


#: Where the unit of a log read with a calibration comes from by default (`add_log_arguments`).
CALIBRATED_LOG_UNIT = "the column names, else the unit of the calibrated log"


def add_params_argument(parser) -> None:
    """The PARAMS.json argument of a command that reads a calibration."""
    parser.add_argument(
        "params", metavar="PARAMS.json", help="the parameters written by 'nlpcal calibrate'"
    )


#: The help of a LOG argument.
LOG_HELP = (
    "the log: a delimited text file (comma, semicolon, tab or whitespace), a Parquet file, a "
    "quoted pattern or a folder of them, or - for stdin; or a MotionCal capture (Raw: lines), "
    "a MATLAB .mat file or an ArduPilot DataFlash .bin log"
)


def add_plot_argument(parser):
    parser.add_argument(
        "--plot",
        metavar="FIG.png",
        help="write a figure of the log before and after the correction: |B| against the "
        "sample, histograms of |B| - F, the covered field directions, the cycles (needs "
        "matplotlib: pip install 'nlpcal[plot]')",
    )


def write_plot(outputs, args, log, parameters, corrected=None) -> None:
    """The calibration figure of --plot (`add_plot_argument`), one of a command's `outputs`
    (`nlpcal.io.files.Outputs`)."""
    from ..report import figure_png

    if args.plot:
        png = figure_png(
            log, parameters, corrected, title=f"{Path(log.path).name} ({args.command})"
        )
        outputs.bytes(args.plot, png)


def check_plot(args) -> None:
    from ..io import check_distinct_outputs, check_output_path
    from ..plots import require_matplotlib

    plot = getattr(args, "plot", None)
    check_output_path(
        plot, *(getattr(args, name, None) for name in ("log", "params", "drift", "output"))
    )
    if plot:
        check_distinct_outputs(plot, getattr(args, "output", None))
        require_matplotlib()
