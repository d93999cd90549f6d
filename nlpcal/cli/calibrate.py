"""`nlpcal calibrate`: the nine-parameter model on a log, with the temperature options of Liu et
al. (2022); `nlpcal apply` and `nlpcal stats` use its result (`nlpcal.cli.apply`).

    nlpcal calibrate LOG [--columns X Y Z] [--unit U] [--reference-field F | --reference-column COL]
                     [--temperature-column COL [--temperature-model common|per-axis]
                     [--base-temperature T0]] [--allow-unidentifiable] [-o params.json]
    nlpcal apply PARAMS.json LOG [--drift drift.json] [--temperature-column COL] [-o out.csv]
    nlpcal stats LOG [--params PARAMS.json] [--reference-column COL]
                     [--drift drift.json] [--temperature-column COL] [--json]

LOG is any delimited text log, or `-` for stdin. Temperatures are in degC. `calibrate
--temperature-column` estimates the nine parameters and the temperature coefficients together;
its parameters file carries a "temperature_model" object that `apply` and `stats` use with the
log's temperature column. `apply --drift` divides the raw vector by k(t) (Eq. 9) before Eq. 4;
`stats --reference-column` adds the RMSE of Eq. 10 to every row, so
`stats LOG --reference-column F --params P --drift D` prints the paper's three rows.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from ..defaults import CYCLES_DEFAULT, RTOL_DEFAULT
from .common import (
    LOG_HELP,
    add_command,
    add_lag_argument,
    add_log_arguments,
    add_loss_arguments,
    add_plot_argument,
    add_reference_arguments,
    add_scheduler_arguments,
    add_sensor_id_argument,
    add_threads_argument,
    check_plot,
    log_options,
    progress,
    report_log,
    say,
    show_progress,
    solver_log,
    tell,
    tell_written,
    warn,
    warning,
    write_plot,
)

if TYPE_CHECKING:
    from ..calibration import CalibrationResult
    from ..drift.temperature import TemperatureCalibrationResult

TEMPERATURE_MODELS = ("common", "per-axis", "full")
TIME_DRIFTS = ("none", "common", "per-axis")  # the library's nlpcal.models.time_drift.TIME_DRIFTS
#: The flags of the library's overrides of a quality check.
OVERRIDE_FLAGS = {
    "require_identifiable": "--allow-unidentifiable",
    "allow_unconverged": "--allow-unconverged",
}
#: The forms of Eq. 4 `--model` takes (`nlpcal.calibration.MODEL_CHOICES`).
MODEL_CHOICES = ("full", "diagonal", "offset", "auto")
#: Table 1 rows printed without -v: the measured row, the first cycles, a few, the last two.
SUMMARY_ROWS = 10


def register(sub):
    _register_calibrate(sub)


# --- calibrate ----------------------------------------------------------------------------------


def _register_calibrate(sub):
    parser = add_command(
        sub,
        "calibrate",
        help="estimate a magnetometer's calibration from a log of many orientations",
        description="""\
Estimate the nine parameters that turn the raw readings B_M into the corrected field
B1 = O S (B_M - Z) (Zhou et al. 2010, Eq. 4):
  Z = z_x, z_y, z_z      offsets (hard iron, sensor bias), in the unit of the field columns
  s_x, s_y, s_z          scale errors of the axes (0.01 = 1 % too large)
  alpha, beta, gamma     angles by which the axes miss being perpendicular [deg]
The log should hold readings taken while the sensor was turned through many orientations in a
steady field. Without a reference field the parameters make |B1| as constant as possible; the
overall scale is then fixed by s_x + s_y + s_z = 0. The |B| statistics (measured, then after
each cycle: the paper's Table 1) are printed on stderr with what the data cannot determine, and
the parameters are written as JSON for 'nlpcal apply'. Exit 1 when the data cannot determine
them (say, the sensor was never turned over); --allow-unidentifiable writes them anyway.""",
        examples=(
            "nlpcal calibrate log.csv -o params.json",
            "nlpcal calibrate mag.txt --unit raw -o params.json     # counts, no header row",
            "nlpcal calibrate log.csv --columns 4 5 6 --unit uT     # columns by position",
            "nlpcal calibrate log.csv --reference-field 48500       # a known |B| in nT",
            "logger | nlpcal calibrate - --unit G -o params.json    # from stdin",
        ),
    )
    parser.add_argument("log", metavar="LOG", help=LOG_HELP)
    add_log_arguments(parser)
    parser.add_argument(
        "--method",
        choices=("staged", "joint"),
        default="staged",
        help="staged: the paper's cycle, angles -> scales -> offsets, repeated (default); "
        "joint: all nine in one solve (same optimum, fewer iterations)",
    )
    parser.add_argument(
        "--model",
        choices=MODEL_CHOICES,
        default="full",
        help="full: the nine parameters (default, the paper's); diagonal: offsets and scales, "
        "no angles; offset: the offsets alone (with a reference field, and one common scale); "
        "auto: the richest of them the attitudes determine, and why. The parameters a model "
        "does not estimate are fixed at zero",
    )
    parser.add_argument(
        "--cycles",
        type=int,
        default=CYCLES_DEFAULT,
        metavar="K",
        help=f"most cycles of the staged method (default {CYCLES_DEFAULT})",
    )
    parser.add_argument(
        "--target-std",
        type=float,
        metavar="F",
        help="stop the cycle when the std of |B1| <= F, in the unit of the field columns",
    )
    parser.add_argument(
        "--target-range",
        type=float,
        metavar="F",
        help="stop the cycle when max - min of |B1| <= F, in the unit of the field columns",
    )
    parser.add_argument(
        "--rtol",
        type=float,
        default=RTOL_DEFAULT,
        metavar="R",
        help="stop the cycle when the objective improves by less than this "
        f"fraction (default {RTOL_DEFAULT:g})",
    )
    add_reference_arguments(parser)
    add_lag_argument(parser)
    parser.add_argument(
        "--temperature-column",
        metavar="COL",
        help="column of temperatures [degC] (name or position): estimate the nine parameters "
        "and how they drift with temperature together (Liu et al. 2022; needs "
        "--reference-column; --method, --cycles and the targets do not apply)",
    )
    parser.add_argument(
        "--temperature-model",
        choices=TEMPERATURE_MODELS,
        help="common: one factor k(t) on scale and offset of all axes (Liu et "
        "al. 2022, Eq. 9; the default); per-axis: linear scale and "
        "offset drift per axis, angles temperature-free; full: per-axis, and a linear drift "
        "of each angle (non-orthogonality)",
    )
    parser.add_argument(
        "--time-drift",
        choices=TIME_DRIFTS,
        default="none",
        help="scale factors linear in time, one slope for all axes (common) or one per axis "
        "(per-axis), per day from the middle of the log, fitted against --reference-column "
        "with or without --temperature-column; needs --time-column (default: none)",
    )
    parser.add_argument(
        "--base-temperature",
        type=float,
        metavar="T0",
        help="with --temperature-column: the temperature at which the nine parameters are "
        "reported [degC], e.g. 20 (default: the log's mean temperature)",
    )
    parser.add_argument(
        "--low-memory",
        action="store_true",
        help="stream the log into a memory-mapped temporary file in chunks, so "
        "that logs larger than memory can be calibrated (the default for text and Parquet "
        "files, unless --plot or a geomagnetic model with position or time columns needs the "
        "whole table; stdin and recorded formats are read whole); with --scheduler, leave the "
        "log in its files, read in every pass, rather than keep it in the cluster's memory "
        "where it fits",
    )
    add_loss_arguments(parser)
    add_threads_argument(parser)
    parser.add_argument(
        "--ipopt-option",
        action="append",
        type=ipopt_option,
        metavar="KEY=VALUE",
        help="an IPOPT option for every solve, e.g. max_iter=50 or mu_strategy=adaptive "
        "(repeatable; the value is an integer, a number or a word, as IPOPT types the option; "
        "IPOPT checks it). The result records every IPOPT option under solver.ipopt_options",
    )
    parser.add_argument(
        "--allow-unidentifiable",
        action="store_true",
        help="write the result even when the data cannot determine some parameters (exit 0, "
        "with the warning in the output); default: exit 1 and write nothing",
    )
    parser.add_argument(
        "--allow-unconverged",
        action="store_true",
        help="write a staged result that stopped at its cycle limit or away from the joint "
        "optimum of the same data (with a warning and without standard errors) instead of "
        "failing the quality check",
    )
    parser.add_argument(
        "--aux-columns",
        nargs="+",
        metavar="COL",
        help="auxiliary channels (motor current, throttle, heater power): estimate with the "
        "nine parameters a stray field v_k c_k per channel, B1 = O_p S_p (B_M - Z_p - "
        "sum_k v_k c_k); written under 'aux' [field unit per channel unit]",
    )
    parser.add_argument(
        "--aux-kind",
        nargs="+",
        metavar="KIND",
        choices=("current", "throttle", "other"),
        help="what each --aux-columns channel is: current [A], throttle [fraction 0..1] or "
        "other; one for all or one per column (default: other)",
    )
    add_scheduler_arguments(parser)
    add_sensor_id_argument(parser)
    parser.add_argument(
        "-o",
        "--output",
        metavar="PARAMS.json",
        help="write the parameters here (stdout when absent)",
    )
    add_plot_argument(parser)
    parser.set_defaults(func=run_calibrate)


def run_calibrate(args) -> int:
    from ..cluster import scheduler

    if args.scheduler:
        _refuse_with_scheduler(args)  # before a cluster starts for nothing
    with scheduler(args.scheduler, args.workers), _dask_progress(args.scheduler):
        return _run_calibrate(args)


def _refuse_with_scheduler(args) -> None:
    """InputError for the options that need the log in memory, with --scheduler."""
    from ..errors import InputError

    if args.plot or args.lag is not None:
        flag = "--plot" if args.plot else "--lag"
        raise InputError(
            f"{flag} and --scheduler exclude each other: with --scheduler the log is read "
            f"block by block on the cluster"
        )
    if args.aux_columns:
        raise InputError(
            "--aux-columns reads its channels with the log in memory; drop --scheduler (the "
            "Python API takes a Dask DataFrame with aux_columns)"
        )


def _dask_progress(spec):
    """Dask's progress bar on stderr for its own schedulers, when stderr is a terminal."""
    import contextlib
    import sys

    from . import common

    if spec not in ("threads", "processes") or common.VERBOSITY < 0 or not sys.stderr.isatty():
        return contextlib.nullcontext()
    from dask.diagnostics import ProgressBar

    return ProgressBar(out=sys.stderr)


def _read_for_calibration(args, extra):
    """The log: in this process (read_log), or for --scheduler read block by block on the
    cluster, kept in its memory where it fits unless --low-memory (read_lazy_log)."""
    from ..cluster import describe
    from ..io import read_log
    from ..io.lazy import read_lazy_log
    from ..io.recorders import is_recorded

    if not args.scheduler:
        options = log_options(args)
        model = options["reference_model"]
        per_sample = "time_column" in options or (
            model is not None and (model.numeric_columns() or model.time_column)
        )
        # the lean chunked reading by default: as fast, a fraction of the memory; the whole
        # table for what needs it (a figure's time axis, a model's position and time columns)
        # and for logs read whole anyway (recorded formats; stdin, which may be one)
        whole = per_sample or args.plot or args.log == "-" or is_recorded(args.log)
        whole = whole or "reference_log" in options  # interpolated onto the log's times
        whole = whole or args.time_drift != "none"  # the times of a time drift
        lean = args.low_memory or not whole
        with show_progress(f"reading {args.log}") as bar:
            return read_log(args.log, **options, extra_columns=extra, low_memory=lean, progress=bar)
    # kept in the cluster's memory where it fits, unless --low-memory leaves it in its files
    keep = not args.low_memory
    log = read_lazy_log(args.log, **log_options(args), extra_columns=extra, keep=keep)
    log.notes.append(f"running on {describe(args.scheduler)}")
    return log


def _times(args, log) -> dict:
    """The time drift's options of `calibrate_temperature_log`: the drift, the log's times and
    their column (none without a time drift)."""
    from ..io.reference import log_times

    if args.time_drift == "none":
        return {}
    column, times = log_times(log, args.time_column, f"--time-drift {args.time_drift}")
    return {"time_drift": args.time_drift, "times": times, "time_column": column}


def _run_calibrate(args) -> int:
    from .. import validation
    from ..calibration import calibrate_log
    from ..drift.temperature import TemperatureCalibrationResult, calibrate_temperature_log
    from ..errors import InputError, QualityError
    from ..io import Outputs, check_output_path

    check_output_path(args.output, args.log)
    check_plot(args)
    sensor_id = None if args.sensor_id is None else validation.sensor_id(args.sensor_id)
    # the joint calibration of drift terms: a temperature model, a time drift, or both
    temperature = args.temperature_column or args.temperature_model or args.time_drift != "none"
    if args.temperature_model and not args.temperature_column:
        raise InputError("--temperature-model needs --temperature-column COL")
    if temperature and args.model != "full":
        raise InputError(
            "--model applies to the nine-parameter calibration; the temperature calibration "
            "estimates the full model"
        )
    if temperature and args.ipopt_option:
        raise InputError(
            "--ipopt-option applies to the nine-parameter calibration; the temperature "
            "calibration takes IPOPT's settings of its own"
        )
    if temperature and args.lag is not None:
        raise InputError(
            "--lag applies to the nine-parameter calibration, not to the temperature one"
        )
    if temperature and not args.reference_column:
        raise InputError(
            "the temperature calibration needs --reference-column COL, a reference "
            "magnitude per sample (for example a proton magnetometer)"
        )
    check_aux_arguments(args, temperature)
    warn_ignored(args, joint=args.method == "joint" or bool(temperature))
    started = time.perf_counter()
    extra = {"--temperature-column": args.temperature_column} if args.temperature_column else {}
    extra.update({f"--aux-columns ({name})": name for name in args.aux_columns or ()})
    log = _read_for_calibration(args, extra)
    report_log(log)
    told = len(log.notes)  # a log left in its files has its rows checked by the first pass
    read_s = time.perf_counter() - started
    started = time.perf_counter()
    result: CalibrationResult | TemperatureCalibrationResult
    try:
        with solver_log():
            if temperature:
                result = calibrate_temperature_log(
                    log,
                    args.temperature_column,
                    model=args.temperature_model or "common" if args.temperature_column else None,
                    base_temperature=args.base_temperature,
                    **_times(args, log),
                )
            else:
                result = calibrate_log(
                    log,
                    **calibration_options(args),
                    verbose=args.verbose,
                    progress=lambda cycle, row: progress(
                        f"cycle {cycle}: std of |B1| {row['std']:.6g} {log.base_unit}"
                    ),
                )
    except QualityError as failure:
        progress("")
        if failure.result is not None:
            say_verdict(failure.result)
            say(failure.result.table(most=table_rows()))
        flags = [OVERRIDE_FLAGS[name] for name in failure.overrides if name in OVERRIDE_FLAGS]
        if not flags:
            raise
        raise QualityError(
            f"{failure.reason.rstrip('.')}. {' '.join(flags)} writes the result anyway, with "
            f"{'these warnings' if len(flags) > 1 else 'this warning'}.",
            failure.status,
            result=failure.result,
        ) from None
    progress("")
    tell(log.notes[told:])
    if isinstance(result, TemperatureCalibrationResult):
        result.calibration.sensor_id = sensor_id
    else:
        result.sensor_id = sensor_id
    say_verdict(result)
    warn(
        f"read {log.n} rows in {read_s:.2f} s ({log.read_by}); calibrated in "
        f"{time.perf_counter() - started:.2f} s"
    )
    say(result.table(most=table_rows()))
    robust = getattr(result, "robust", {})
    if robust.get("loss", "l2") != "l2":
        warn(
            f"{robust['loss']} loss, scale {robust['scale']:.4g} {result.unit}: "
            f"{robust['downweighted']} of {log.n} samples down-weighted"
        )
    selection = getattr(result, "model_selection", None)
    if selection and selection["chosen"] == "full":  # a restricted choice is among the warnings
        warn(f"model auto chose full: {selection['reason']}")
    for message in result.warnings:
        if message not in log.warnings:  # said when the log was read
            warning(message)
    for message in result.notes:
        warn(f"note: {message}")
    corrected = None
    if args.plot and temperature:
        corrected = _apply_temperature(result, log, args.temperature_column)
    with Outputs() as outputs:
        outputs.json(args.output, result.to_dict())
        write_plot(outputs, args, log, result, corrected)
    tell_written(args.output, args.plot)
    return 0


def check_aux_arguments(args, temperature) -> None:
    """InputError for --aux-columns and --aux-kind with options they do not combine with."""
    from ..errors import InputError

    if args.aux_kind and not args.aux_columns:
        raise InputError("--aux-kind needs --aux-columns COL [COL ...]")
    if not args.aux_columns:
        return
    if temperature:
        raise InputError(
            "--aux-columns applies to the nine-parameter calibration, not to the temperature "
            "calibration; drop one of them"
        )


def say_verdict(result) -> None:
    """The verdict of a result (`nlpcal.verdict`) in one line, before the rest of the summary."""
    warn(f"verdict: {result.verdict.line()}")


def table_rows() -> int | None:
    """How many Table 1 rows the terminal shows: all with -v, else the first, a few and the
    last (SUMMARY_ROWS)."""
    from . import common

    return None if common.VERBOSITY >= 1 else SUMMARY_ROWS


def ipopt_option(text: str) -> tuple:
    """(name, value) of a --ipopt-option KEY=VALUE (`nlpcal.nlp.solver.ipopt_value` types the
    value)."""
    import argparse

    from ..nlp.solver import ipopt_value

    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE (e.g. max_iter=50), got {text!r}")
    return name.strip(), ipopt_value(value)


def calibration_options(args) -> dict:
    """The keyword arguments of `nlpcal.calibration.calibrate_log` that the options of
    `nlpcal calibrate` (and of `nlpcal batch calibrate`) give."""
    from ..nlp.solver import check_ipopt_options
    from ..results import distinct

    ipopt_options = distinct(args.ipopt_option or (), "--ipopt-option", "option") or None
    if ipopt_options:  # checked before any log is read (a batch would fail every log)
        check_ipopt_options(ipopt_options)
    return {
        "method": args.method,
        "model": args.model,
        "cycles": args.cycles,
        "rtol": args.rtol,
        "target_std": args.target_std,
        "target_range": args.target_range,
        "loss": args.loss,
        "loss_scale": args.loss_scale,
        "require_identifiable": not args.allow_unidentifiable,
        "allow_unconverged": args.allow_unconverged,
        "threads": args.threads,
        "ipopt_options": ipopt_options,
        **(
            {"aux_columns": list(args.aux_columns), "aux_kind": args.aux_kind}
            if getattr(args, "aux_columns", None)
            else {}
        ),
        **({"lag": args.lag} if getattr(args, "lag", None) is not None else {}),
        **(
            {"lag_tolerance": args.lag_tolerance}
            if getattr(args, "lag_tolerance", None) is not None
            else {}
        ),
    }


def warn_ignored(args, joint: bool) -> None:
    """Warn about the options of `nlpcal calibrate` that this run does not use."""
    staged_only = [
        flag
        for flag, value in (
            ("--cycles", args.cycles != CYCLES_DEFAULT),
            ("--target-std", args.target_std is not None),
            ("--target-range", args.target_range is not None),
            ("--rtol", args.rtol != RTOL_DEFAULT),
        )
        if value
    ]
    if joint and staged_only:
        warning(
            f"{', '.join(staged_only)} only steer the staged cycle; the joint solve ignores them"
        )
    if args.loss_scale is not None and args.loss == "l2":
        warning("--loss-scale only scales a robust loss (--loss huber or cauchy); ignored")
    if args.workers is not None and args.scheduler not in ("local", "processes"):
        warning("--workers only sizes --scheduler local or processes; ignored")


def _apply_temperature(result, log, temperature_column):
    """The log corrected by a temperature calibration (for its figure). [base unit]"""
    from ..correction import Correction

    columns = list(log.extras) if log.frame is None else [str(c) for c in log.frame.columns]
    correction = Correction.plan(
        result, None, temperature_column, log_columns=columns, time_column=result.time_column
    )
    return correction.apply(log)
