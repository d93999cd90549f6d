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
    add_command,
    add_log_arguments,
    add_params_argument,
    add_plot_argument,
    add_reference_model_arguments,
    check_plot,
    emit_json,
    log_options,
    report_log,
    table_options,
    tell,
    tell_written,
    warn,
    write_plot,
)

#: The columns `apply` adds (the names `nlpcal.correction` writes; here for the help alone).
TOTAL_COLUMN = "b_total"
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
their magnitude as a last column '{TOTAL_COLUMN}'. The log is written back in the layout it was
read in (delimiter, header row or not, decimal mark, leading comment lines); every other column
passes through unchanged, character for character. Rows reading exactly (0, 0, 0), and with
--drop-invalid rows with missing values, are left out (and counted on stderr).""",
        examples=(
            "nlpcal apply params.json log.csv -o corrected.csv",
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
        help="write the corrected log here (stdout when absent)",
    )
    add_plot_argument(parser)
    add_reference_model_arguments(parser)
    parser.set_defaults(func=run_apply)


def correction_for(args, table, require_temperature: bool):
    """The Correction that --params/PARAMS.json, --drift and --temperature-column ask for."""
    from ..correction import Correction, load_parameters
    from ..drift.fit import DriftFit

    params_path = getattr(args, "params", None)
    parameters = load_parameters(params_path) if params_path else None
    drift = DriftFit.load(args.drift) if args.drift else None
    return Correction.plan(
        parameters,
        drift,
        args.temperature_column,
        log_columns=table.columns,
        require_temperature=require_temperature,
    )


def run_apply(args) -> int:
    from ..correction import outliers, read_log_for
    from ..errors import InputError
    from ..io import Outputs, check_output_path, read_table, table_text
    from ..io.strict import finite_table

    check_output_path(args.output, args.log, args.params, args.drift)
    check_plot(args)
    table = read_table(args.log, **table_options(args), text=True)
    correction = correction_for(args, table, require_temperature=True)
    if args.plot and correction.parameters is None:
        raise InputError("--plot needs parameters (PARAMS.json), not a drift file alone")
    log = read_log_for(table, correction, **log_options(args))
    report_log(log)
    corrected = correction.apply(log)
    tell(correction.notes)
    extra = {}
    if args.flag_outliers:
        extra[OUTLIER_COLUMN] = flags = outliers(correction, corrected)
        warn(f"{int(flags.sum())} of {len(flags)} rows flagged as outliers")
    frame = log.written_back(corrected, TOTAL_COLUMN, extra)
    with Outputs() as outputs:
        outputs.text(args.output, table_text(finite_table(frame), log.layout))
        write_plot(outputs, args, log, correction.parameters, corrected)
    if args.output:
        warn(f"wrote {len(frame)} corrected rows to {args.output} ({log.layout.describe()})")
    tell_written(args.plot)
    return 0


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
the reference (Eq. 10 of Liu et al. 2022).""",
        examples=(
            "nlpcal stats log.csv",
            "nlpcal stats log.csv --params params.json",
            "nlpcal stats log.csv --params params.json --reference-column proton_nT --json",
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
    parser.add_argument(
        "--reference-column",
        metavar="COL",
        help="column of reference magnitudes (name or position; its unit from its name, "
        "else the field columns'): add the RMSE of Eq. 10 (Liu et al. 2022) to every row",
    )
    parser.add_argument("--json", action="store_true", help="print the rows as JSON on stdout")
    add_reference_model_arguments(parser)
    parser.set_defaults(func=run_stats)


def run_stats(args) -> int:
    from ..correction import read_log_for, statistics_rows
    from ..io import read_log, read_table
    from ..statistics import format_table

    table = read_table(args.log, **table_options(args))
    if args.params or args.drift or args.temperature_column:
        correction = correction_for(args, table, require_temperature=False)
        log = read_log_for(table, correction, **log_options(args))
    else:
        correction = None
        log = read_log(table, **log_options(args))
    report_log(log)
    rows, extra = statistics_rows(log, correction)
    if correction is not None:
        tell(correction.notes)
    if args.json:
        emit_json({"unit": log.base_unit, "std_ddof": 0, "rows": rows}, None)
    else:
        print(format_table(rows, log.base_unit, extra=extra))
    return 0
