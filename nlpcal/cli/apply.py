"""`nlpcal apply` and `nlpcal stats`: a log corrected with the parameters of `nlpcal calibrate`
(Eq. 4), optionally divided by a temperature factor first (Liu et al. 2022, Eq. 9), and the |B|
statistics before and after (the rows of Table 1 of Zhou et al. 2010).

    nlpcal apply PARAMS.json LOG [--drift drift.json] [--temperature-column COL] [-o out.csv]
    nlpcal stats LOG [--params PARAMS.json] [--reference-column COL]
                     [--drift drift.json] [--temperature-column COL] [--json]

`apply --drift` divides the raw vector by k(t) (Eq. 9) before Eq. 4; `stats --reference-column`
adds the RMSE of Eq. 10 to every row, so `stats LOG --reference-column F --params P --drift D`
prints the paper's three rows. Parameters with a "temperature_model" object (from `calibrate
--temperature-column`) use the log's temperature column.
"""

from __future__ import annotations

from .common import (
    CALIBRATED_LOG_UNIT,
    LOG_HELP,
    acknowledge,
    add_command,
    add_lag_argument,
    add_log_arguments,
    add_params_argument,
    add_plot_argument,
    add_precision_argument,
    add_reference_log_arguments,
    add_reference_model_arguments,
    check_plot,
    emit_json,
    log_options,
    report_log,
    show_progress,
    table_options,
    tell,
    tell_written,
    warn,
    warning,
    write_plot,
)

#: The columns `apply` adds (the names `nlpcal.correction` writes; here for the help alone).
TOTAL_COLUMN = "b_total"
VALID_COLUMN = "valid"
OUTLIER_COLUMN = "outlier"


def register(sub):
    _register_apply(sub)
    _register_stats(sub)


def add_correction_arguments(parser):
    """PARAMS.json, the LOG to correct with it and how to read that log, and the temperature
    options: the arguments of every command that corrects a log."""
    add_params_argument(parser)
    parser.add_argument("log", metavar="LOG", help=LOG_HELP)
    add_log_arguments(parser, CALIBRATED_LOG_UNIT)
    add_temperature_arguments(parser)
    add_aux_argument(parser)


def add_aux_argument(parser):
    """--aux-columns NEW=OLD: where the calibration's aux channels are in the log."""
    parser.add_argument(
        "--aux-columns",
        nargs="+",
        type=aux_source,
        metavar="NEW=OLD",
        help="read the calibration's aux channel OLD from the log's column NEW (default: each "
        "channel from the column of its own name)",
    )


def add_temperature_arguments(parser):
    parser.add_argument(
        "--drift",
        metavar="DRIFT.json",
        help="output of 'nlpcal drift fit': divide the raw vector by the temperature factor "
        "k(t) (Liu et al. 2022, Eq. 9) before the correction",
    )
    parser.add_argument(
        "--temperature-column",
        metavar="COL",
        help="column of temperatures [degC] for --drift or for parameters with "
        "a temperature model (default: the column they were fitted with)",
    )


def _register_apply(sub):
    parser = add_command(
        sub,
        "apply",
        help="correct a log with a calibration (writes the log back, field columns corrected)",
        description=f"""\
Correct the field columns of a log with the parameters of 'nlpcal calibrate' (Eq. 4) and add
their magnitude '{TOTAL_COLUMN}' and a column '{VALID_COLUMN}' as last columns. Every row of numbers
is written, in its place: rows that are not readings (exactly (0, 0, 0), and with --drop-invalid
repeats of the row before) keep their raw values and have {VALID_COLUMN} 0. With --drop-invalid,
rows with missing or non-numeric values are left out, counted and their data rows named on
stderr. An output named *.parquet is a Parquet file; any other output is text in the layout the
log was read in (delimiter, header row or not, decimal mark, leading comment lines), every other
column passing through unchanged, character for character, and the numbers written with one
significant digit more than the log's carry (every digit from Parquet; or --precision). The log
is read and written in chunks, in bounded memory whatever its size (with --plot or
--flag-outliers it is also read whole first); a progress line shows on a terminal.""",
        examples=(
            "nlpcal apply params.json log.csv -o corrected.csv",
            "nlpcal apply params.json log.csv -o corrected.parquet",
            "nlpcal apply params.json mag.txt > corrected.txt     # whitespace in, whitespace out",
            "nlpcal apply params.json log.csv --drift drift.json --temperature-column temp_c",
        ),
    )
    add_correction_arguments(parser)
    parser.add_argument(
        "--flag-outliers",
        action="store_true",
        help=f"add a boolean column '{OUTLIER_COLUMN}': |B1| further from its centre than 4 "
        "robust standard deviations (1.4826 MAD) of the calibration's residuals",
    )
    parser.add_argument(
        "-o",
        "--output",
        metavar="CORRECTED",
        help="write the corrected log here: Parquet for *.parquet, else text in the log's "
        "layout (stdout when absent)",
    )
    add_precision_argument(parser)
    add_plot_argument(parser)
    add_reference_model_arguments(parser)
    parser.set_defaults(func=run_apply, log_time_column=True)  # --time-column: a time drift's


def aux_source(text: str) -> tuple:
    """(log column, calibration channel) of an --aux-columns NEW=OLD (NAME alone: NAME=NAME)."""
    import argparse

    new, sep, old = text.partition("=")
    new, old = new.strip(), (old.strip() if sep else new.strip())
    if not new or not old:
        raise argparse.ArgumentTypeError(f"expected NEW=OLD (e.g. curr=current), got {text!r}")
    return new, old


def correction_for(args, columns, require_temperature: bool):
    """The Correction that --params/PARAMS.json, --drift and --temperature-column ask for, to
    be applied to a log with these `columns`."""
    from ..correction import Correction, load_parameters
    from ..drift.fit import DriftFit
    from ..results import distinct

    params_path = getattr(args, "params", None)
    parameters = load_parameters(params_path) if params_path else None
    drift = DriftFit.load(args.drift) if args.drift else None
    acknowledge(parameters)
    return Correction.plan(
        parameters,
        drift,
        args.temperature_column,
        log_columns=columns,
        require_temperature=require_temperature,
        time_column=getattr(args, "time_column", None),
        aux_columns=distinct(getattr(args, "aux_columns", None) or (), "--aux-columns", "column"),
    )


def run_apply(args) -> int:
    import numpy as np

    from ..correction import corrected_chunks, extra_columns_for, outlier_bounds, read_log_for
    from ..errors import InputError
    from ..io import Outputs, check_output_path
    from ..io.output import Precision, check_table_output, is_parquet_output, write_frames
    from ..io.stream import LogStream

    check_output_path(args.output, args.log, args.params, args.drift)
    check_plot(args)
    check_table_output(args.output)
    precision = Precision(args.precision)
    progress = show_progress(f"applying {args.log}", args.output)
    with LogStream(args.log, **table_options(args), progress=progress) as stream:
        correction = correction_for(args, stream.table_columns, require_temperature=True)
        if args.plot and correction.parameters is None:
            raise InputError("--plot needs parameters (PARAMS.json), not a drift file alone")
        stream.open(
            args.columns,
            unit=args.unit,
            fallback_unit=correction.fallback_unit,
            extra_columns=extra_columns_for(correction),
            drop_invalid=args.drop_invalid,
        )
        report_log(stream)
        log = bounds = None
        if args.plot or args.flag_outliers:  # the whole log first, in memory
            log = read_log_for(stream.readable, correction, **log_options(args))
            corrected = correction.apply(log)
            if args.flag_outliers:
                bounds = outlier_bounds(correction, np.linalg.norm(corrected, axis=1))
        chunks = corrected_chunks(stream, correction, precision, bounds)
        flagged = FlagCount(chunks, OUTLIER_COLUMN if args.flag_outliers else None)
        with progress, Outputs() as outputs:
            write_frames(outputs, args.output, flagged, stream.layout, precision)
            if log is not None:
                write_plot(outputs, args, log, correction.parameters, corrected)
    tell(stream.summary())
    tell(correction.notes)
    if args.flag_outliers:
        warn(f"{flagged.flags} of {stream.readings} readings flagged as outliers")
    if args.output:
        what = "Parquet" if is_parquet_output(args.output) else stream.layout.describe()
        warn(f"wrote {stream.rows} rows to {args.output} ({what})")
    tell_written(args.plot)
    return 0


class FlagCount:
    """The chunks of a corrected log passed on, the True values of their `column` counted."""

    def __init__(self, chunks, column: str | None):
        self.chunks, self.column, self.flags = chunks, column, 0

    def __iter__(self):
        for chunk in self.chunks:
            if self.column is not None:
                self.flags += int(chunk[self.column].sum())
            yield chunk


# --- stats --------------------------------------------------------------------------------------


def _register_stats(sub):
    parser = add_command(
        sub,
        "stats",
        help="|B| statistics of a log, before and after a calibration",
        description="""\
Print max, min, mean, std (ddof = 0) and range of the total field |B|: the measured row, and the
corrected row with --params (the rows of Table 1 of Zhou et al. 2010). The spread of |B| over a
log of many orientations in a steady field is what a calibration removes: a good one leaves
little more than the sensor noise. With --reference-column every row also gets the RMSE against
the reference (Eq. 10 of Liu et al. 2022), and delta F = |B| - F (mean and std, by UTC day
when --time-column spans days) is printed before and after; --lag auto estimates the lag of the
reference per period (exit 1 when a period leaves it undetermined), --lag SECONDS or the lag in
PARAMS.json takes it out. A fixed sensor's log (no attitude change) is recognised: delta F and
the lag are computed, the nine parameters cannot be.""",
        examples=(
            "nlpcal stats log.csv",
            "nlpcal stats log.csv --params params.json",
            "nlpcal stats log.csv --params params.json --reference-column proton_nT --json",
            "nlpcal stats obs.csv --reference-column F --time-column time --lag auto",
        ),
    )
    parser.add_argument("log", metavar="LOG", help=LOG_HELP)
    add_log_arguments(parser, CALIBRATED_LOG_UNIT)
    parser.add_argument(
        "--params",
        metavar="PARAMS.json",
        help="parameters written by 'nlpcal calibrate': add the corrected row",
    )
    add_temperature_arguments(parser)
    add_aux_argument(parser)
    parser.add_argument(
        "--reference-column",
        metavar="COL",
        help="column of reference magnitudes (name or position; its unit from its name, "
        "else the field columns'): add the RMSE of Eq. 10 (Liu et al. 2022) to every row; "
        "with --reference-log, the column of that log",
    )
    add_reference_log_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print the rows as JSON on stdout")
    add_lag_argument(parser)
    add_reference_model_arguments(parser)
    parser.set_defaults(func=run_stats)


def run_stats(args) -> int:
    import numpy as np

    from ..correction import read_log_for, statistics_rows
    from ..delta_f import (
        aligned_log,
        check_lags,
        fixed_sensor_message,
        format_report,
        log_delta_f,
        report_warnings,
    )
    from ..io import read_log, read_table
    from ..statistics import format_table

    table = read_table(args.log, **table_options(args))
    if args.params or args.drift or args.temperature_column:
        correction = correction_for(args, table.columns, require_temperature=False)
        log = read_log_for(table, correction, **log_options(args))
    else:
        correction = None
        log = read_log(table, **log_options(args))
    report_log(log)
    parameters = correction.parameters if correction is not None else None
    lag_block = getattr(parameters, "lag", None)
    aligned = aligned_log(log, args.lag, lag_block)
    tell(aligned.notes[len(log.notes) :])  # the rows a lag left without a reference
    rows, extra = statistics_rows(aligned, correction)
    if correction is not None:
        tell(correction.notes)
    document = {"unit": log.base_unit, "std_ddof": 0, "rows": rows}
    report = None
    if args.lag is not None or isinstance(log.reference, np.ndarray):
        report = log_delta_f(log, parameters, args.lag, lag_block, args.lag_tolerance)
        if report["fixed_sensor"]:
            tell([fixed_sensor_message(report["attitude_spread_deg"])])
        for message in report_warnings(report):
            warning(message)
        document["delta_f"] = report
    if args.json:
        emit_json(document, None)
    else:
        print(format_table(rows, log.base_unit, extra=extra))
        if report is not None:
            print(format_report(report, log.base_unit))
    if report is not None:
        check_lags(report)
    return 0
