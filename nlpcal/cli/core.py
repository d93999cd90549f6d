"""`nlpcal calibrate`, `nlpcal apply` and `nlpcal stats`: the nine-parameter model on CSV logs."""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..calibration import METHODS, CalibrationResult, calibrate, theta_from_parameters
from ..errors import InputError
from ..io import (FIELD_UNITS_NT, check_output_path, csv_engine, csv_to_memmap,
                  numeric_columns, read_json, read_table, read_table_header, resolve_columns,
                  suggested_unit, unit_factor, unit_in_name)
from ..statistics import field_statistics, format_table
from . import emit_csv, emit_json, warn

TOTAL_COLUMN = "b_total"
CYCLES_DEFAULT = 50
RTOL_DEFAULT = 1e-9


@dataclass
class Log:
    """A log read for calibration: the table, the chosen columns and the samples in base units."""

    frame: pd.DataFrame
    columns: list
    samples: np.ndarray  # (N, 3) [nT, or the log's own unit for --unit raw]
    kept: np.ndarray  # rows of `frame` behind `samples`
    unit: str  # the log's unit
    base_unit: str  # unit of `samples`: "nT", or "raw"


def add_log_arguments(parser, default_from: str = "the column names (mx_uT, \"X (uT)\", "
                                                    "_gauss, _counts ...), else nT"):
    """--columns, --unit and --drop-invalid, shared by every command that reads a field log."""
    parser.add_argument("--columns", nargs=3, metavar=("X", "Y", "Z"),
                        help="the three field columns (default: detected, bx/by/bz, x/y/z, ...)")
    parser.add_argument("--unit", choices=list(FIELD_UNITS_NT), default=None,
                        help=f"unit of the field columns and references (default: from "
                             f"{default_from}); 'raw' keeps counts or other non-field units")
    parser.add_argument("--drop-invalid", action="store_true",
                        help="drop rows with missing or non-numeric values (reporting how many) "
                             "instead of failing")


def log_unit(chosen, unit=None, fallback: str = "nT") -> str:
    """The unit of the field columns: `unit` (--unit), else the one their names carry, else
    `fallback` (nT, or the unit recorded with the parameters being applied)."""
    hinted = suggested_unit(chosen)
    if unit is None:
        if hinted:
            warn(f"unit {hinted} taken from the column names ({', '.join(chosen)})")
        return hinted or fallback
    if hinted and hinted != unit:
        warn(f"the column names ({', '.join(chosen)}) suggest {hinted}, but --unit is {unit}")
    return unit


def read_log(path, columns=None, unit=None, drop_invalid=False, extra_columns=(),
             fallback: str = "nT") -> Log:
    """Read, validate and convert a field log; `extra_columns` must be numeric too.

    unit : the unit of the field columns; None takes it from the column names, else `fallback`.
    """
    frame = read_table(path)
    chosen = resolve_columns(frame, columns)
    for name in extra_columns:
        if name not in frame.columns:
            raise InputError(f"column {name!r} not found; the log has columns: "
                             f"{', '.join(frame.columns)}")
    numeric = numeric_columns(frame, chosen + list(extra_columns), drop_invalid=drop_invalid,
                              source=str(path))
    if not numeric.kept.any():
        raise InputError(f"{path}: no data rows")
    if numeric.dropped:
        warn(f"dropped {numeric.dropped} row(s) with missing or non-numeric values")
    unit = log_unit(chosen, unit, fallback)
    factor = unit_factor(unit)
    return Log(frame=frame, columns=chosen, samples=numeric.values[:, :3] * factor,
               kept=numeric.kept, unit=unit, base_unit="raw" if unit == "raw" else "nT")


def reference_from_args(args, log: Log):
    """None, the --reference-field value or the --reference-column series, in base units.

    The reference is in the log's unit, unless the column's name carries its own ("proton_nT").
    """
    if getattr(args, "reference_field", None) is not None:
        return float(args.reference_field) * unit_factor(log.unit)
    column = getattr(args, "reference_column", None)
    if column:
        values = pd.to_numeric(log.frame[column], errors="coerce").to_numpy(float)[log.kept]
        return values * unit_factor(reference_unit(column, log.unit))
    return None


def reference_unit(column: str, log_unit_: str) -> str:
    """The unit of a reference column: the one its name carries, else the log's."""
    named = unit_in_name(column)
    if named and named != log_unit_:
        warn(f"reference column {column!r} read in {named}, the unit its name carries")
    return named or log_unit_


def _drift():
    """nlpcal.cli.drift (temperature options), imported late: it imports this module."""
    from . import drift
    return drift


# --- calibrate ----------------------------------------------------------------------------------

def _register_calibrate(sub):
    parser = sub.add_parser(
        "calibrate", help="estimate the nine parameters of Eq. 4 from a log",
        description="Estimate offsets, scale errors and non-orthogonality angles (Zhou et al. "
                    "2010, Eq. 4) by minimising the spread of |B1| (Eq. 8), or its distance to a "
                    "reference field. Prints the Table 1 rows to stderr.")
    parser.add_argument("log", metavar="LOG.csv")
    add_log_arguments(parser)
    parser.add_argument("--method", choices=METHODS, default="staged",
                        help="staged: the paper's cycle orthogonal -> scale -> offset (default); "
                             "joint: all nine at once")
    parser.add_argument("--cycles", type=int, default=CYCLES_DEFAULT, metavar="K",
                        help=f"most staged cycles (default {CYCLES_DEFAULT})")
    parser.add_argument("--target-std", type=float, metavar="F",
                        help="stop the cycle when std |B1| <= F [unit]")
    parser.add_argument("--target-range", type=float, metavar="F",
                        help="stop the cycle when max - min of |B1| <= F [unit]")
    parser.add_argument("--rtol", type=float, default=RTOL_DEFAULT,
                        help="stop the cycle when the objective improves by less than this "
                             f"fraction (default {RTOL_DEFAULT:g})")
    ref = parser.add_mutually_exclusive_group()
    ref.add_argument("--reference-field", type=float, metavar="F",
                     help="known field magnitude [unit], e.g. a proton reading")
    ref.add_argument("--reference-column", metavar="COL",
                     help="column of per-sample reference magnitudes [unit]")
    _drift().add_temperature_arguments(parser, "calibrate")
    parser.add_argument("--low-memory", action="store_true",
                        help="stream the log into a memory-mapped temporary file in chunks, so "
                             "that logs larger than memory can be calibrated")
    parser.add_argument("-o", "--output", metavar="PARAMS.json",
                        help="write the parameters here (stdout when absent)")
    parser.set_defaults(func=run_calibrate)


def run_calibrate(args) -> int:
    check_output_path(args.output)
    if args.temperature_column or args.temperature_model:
        if args.low_memory:
            raise InputError("--low-memory does not apply to the temperature calibration, whose "
                             "problem holds every sample; drop it or average the log first")
        return _drift().run_temperature_calibrate(args)
    staged_only = [flag for flag, value in (("--cycles", args.cycles != CYCLES_DEFAULT),
                                            ("--target-std", args.target_std is not None),
                                            ("--target-range", args.target_range is not None),
                                            ("--rtol", args.rtol != RTOL_DEFAULT)) if value]
    if args.method == "joint" and staged_only:
        warn(f"{', '.join(staged_only)} only steer the staged cycle; the joint solve ignores them")
    extra = [args.reference_column] if args.reference_column else []
    started = time.perf_counter()
    if args.low_memory:
        unit = log_unit(resolve_columns(read_table_header(args.log), args.columns), args.unit)
        factor = unit_factor(unit)
        mapped = csv_to_memmap(args.log, args.columns, extra, drop_invalid=args.drop_invalid,
                               scale=factor)
        samples, columns, dropped, engine = mapped.values[:, :3], mapped.columns[:3], \
            mapped.dropped, "c (chunked into a memory map)"
        reference = (mapped.values[:, 3] / factor
                     * unit_factor(reference_unit(args.reference_column, unit))
                     if args.reference_column
                     else None if args.reference_field is None else args.reference_field * factor)
        if dropped:
            warn(f"dropped {dropped} row(s) with missing or non-numeric values")
    else:
        log = read_log(args.log, args.columns, args.unit, args.drop_invalid, extra)
        samples, columns, dropped, engine = log.samples, log.columns, int((~log.kept).sum()), \
            csv_engine()
        reference = reference_from_args(args, log)
        unit, factor = log.unit, unit_factor(log.unit)
    read_s = time.perf_counter() - started
    targets = {k: (None if v is None else v * factor)
               for k, v in (("target_std", args.target_std), ("target_range", args.target_range))}
    started = time.perf_counter()
    result = calibrate(samples, method=args.method, reference_field=reference,
                       cycles=args.cycles, rtol=args.rtol,
                       unit="raw" if unit == "raw" else "nT", **targets)
    warn(f"read {len(samples)} rows in {read_s:.2f} s (pandas {engine} engine); calibrated in "
         f"{time.perf_counter() - started:.2f} s")
    document = result.to_dict()
    document["input"] = {"log": str(args.log), "columns": columns, "log_unit": unit,
                         "csv_engine": engine, "rows_dropped": dropped}
    if args.reference_column:
        document["reference"]["column"] = args.reference_column
    report_calibration(result, document, args.output)
    return 0


def report_calibration(result, document, output) -> None:
    """Table 1 rows and warnings to stderr, the parameters document to -o or stdout."""
    print(result.table(), file=sys.stderr)
    for message in result.warnings:
        warn(message)
    emit_json(document, output)


# --- apply --------------------------------------------------------------------------------------

def _register_apply(sub):
    parser = sub.add_parser(
        "apply", help="correct a log with calibrated parameters (Eq. 4)",
        description="Write the log with its field columns corrected by Eq. 4 and a total-field "
                    f"column '{TOTAL_COLUMN}' added; all other columns are kept.")
    parser.add_argument("params", metavar="PARAMS.json")
    parser.add_argument("log", metavar="LOG.csv")
    add_log_arguments(parser, "the parameters file, else the column names")
    _drift().add_temperature_arguments(parser, "apply")
    parser.add_argument("-o", "--output", metavar="CORRECTED.csv",
                        help="corrected log (stdout when absent)")
    parser.set_defaults(func=run_apply)


def read_log_for(args, result: CalibrationResult, document_unit: str | None,
                 extra_columns=()) -> Log:
    """Read a log to apply parameters to. Its unit: --unit, else its column names, else the unit
    of the log the parameters were estimated from. Counts and field units do not mix."""
    log = read_log(args.log, args.columns, args.unit, args.drop_invalid, extra_columns,
                   fallback=document_unit or result.unit)
    if (log.unit == "raw") != (result.unit == "raw"):
        raise InputError(f"the parameters are in {result.unit!r} but the log is in "
                         f"{log.unit!r}; pass --unit to match")
    return log


def _read_params(path):
    document = read_json(path, "nlpcal parameters file")
    result = CalibrationResult.from_dict(document)
    log_unit = (document.get("input") or {}).get("log_unit")
    return result, log_unit


def run_apply(args) -> int:
    check_output_path(args.output)
    result, document_unit = _read_params(args.params)
    temperature = _drift().TemperatureCorrection.from_args(args, "apply")
    log = read_log_for(args, result, document_unit, temperature.columns)
    factor = unit_factor(log.unit)
    corrected = temperature.correct(result, log) / factor
    frame = log.frame.loc[log.kept].copy()
    for k, column in enumerate(log.columns):
        frame[column] = corrected[:, k]
    frame[TOTAL_COLUMN] = np.linalg.norm(corrected, axis=1)
    emit_csv(frame, args.output)  # exact values: the other columns pass through unchanged
    if args.output:
        warn(f"wrote {len(frame)} corrected rows to {args.output}")
    return 0


# --- stats --------------------------------------------------------------------------------------

def _register_stats(sub):
    parser = sub.add_parser(
        "stats", help="Table 1 statistics of |B| (and of |B1| with --params)",
        description="Print max, min, mean, std (ddof=0) and range of the total field: the "
                    "measured row, and the corrected row when --params is given.")
    parser.add_argument("log", metavar="LOG.csv")
    add_log_arguments(parser, "the parameters file, else the column names")
    parser.add_argument("--params", metavar="PARAMS.json")
    _drift().add_temperature_arguments(parser, "stats")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    parser.set_defaults(func=run_stats)


def run_stats(args) -> int:
    temperature = _drift().TemperatureCorrection.from_args(args, "stats")
    if args.params:
        result, document_unit = _read_params(args.params)
        log = read_log_for(args, result, document_unit, temperature.columns)
    else:
        result = None
        log = read_log(args.log, args.columns, args.unit, args.drop_invalid, temperature.columns)
    rows = [{"label": "measured", **field_statistics(log.samples)}]
    if result is not None:
        theta = theta_from_parameters(result.model)
        rows.append({"label": "corrected", **field_statistics(log.samples, theta)})
    rows, extra = temperature.stats_rows(args, log, result, rows)  # Eq. 10, temperature row
    for row in rows:
        row.pop("max_abs_u", None)
    if args.json:
        sys.stdout.write(json.dumps({"unit": log.base_unit, "std_ddof": 0, "rows": rows},
                                    indent=2) + "\n")
    else:
        print(format_table(rows, log.base_unit, extra=extra))
    return 0


def register(sub):
    _register_calibrate(sub)
    _register_apply(sub)
    _register_stats(sub)
