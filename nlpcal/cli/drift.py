"""`nlpcal drift fit` and the temperature options of calibrate, apply and stats (seed 002).

    nlpcal drift fit LOG.csv --temperature-column COL --reference-column COL
                     [--base-temperature T0] [--columns X Y Z] [--unit nT] [--drop-invalid]
                     [-o drift.json]
    nlpcal calibrate LOG.csv --reference-column COL --temperature-column COL
                     [--temperature-model common|per-axis] [--base-temperature T0] [-o params.json]
    nlpcal apply PARAMS.json LOG.csv [--drift drift.json] [--temperature-column COL] [-o out.csv]
    nlpcal stats LOG.csv [--params PARAMS.json] [--reference-column COL]
                     [--drift drift.json] [--temperature-column COL] [--json]

Temperatures are in degC. `drift fit` is the pipeline of Liu et al. (2022): diurnal correction,
the line |B_m| = a t + b (Eq. 1) and k(t) of Eq. 9; `apply --drift` divides the raw vector by k(t)
before Eq. 4; `stats --reference-column` adds the RMSE of Eq. 10 to every row, so that
`stats LOG --reference-column F --params P --drift D` prints the paper's three rows (raw ->
system -> system + temperature). `calibrate --temperature-column` estimates the nine parameters and
the temperature coefficients in one NLP; its parameters file carries a "temperature_model" object
that `apply` and `stats` use with the log's temperature column. Exit status: 0 success (also with
warnings), 1 IPOPT failed, 2 bad usage or input.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..drift import (DriftFit, TemperatureCalibrationResult, calibrate_temperature,
                     evaluation_row, fit_drift, has_temperature_model)
from ..errors import InputError
from ..io import check_output_path, check_reference, csv_engine, read_json
from ..models.liu2022 import TEMPERATURE_MODELS, rmse
from . import emit_json, warn
from .core import add_log_arguments, read_log, reference_from_args, report_calibration

#: Note when a log's temperatures lie further than this outside the fitted range. [degC]
EXTRAPOLATION_NOTE_DEGC = 1.0


def register(sub):
    parser = sub.add_parser(
        "drift", help="temperature drift of Liu et al. (2022): fit k(t) against a proton reference",
        description="Temperature drift (Liu et al. 2022): the line |B_m| = a t + b (Eq. 1) of a "
                    "static sensor against a proton reference, and the factor k(t) of Eq. 9.")
    inner = parser.add_subparsers(dest="drift_command", metavar="SUBCOMMAND")
    inner.required = True
    fit = inner.add_parser(
        "fit", help="fit |B_m| = a t + b (Eq. 1) on a static log with temperature and reference",
        description="The paper's pipeline on a static-sensor log: diurnal correction (base = the "
                    "first reference value, -(F_i - F_1) added to the fluxgate modulus), least-"
                    "squares line |B_m| = a t + b (Eq. 1) and k(t) = (a t + b)/(a t0 + b) (Eq. 9)."
                    " Warns when the temperature span is too small for a meaningful slope.")
    fit.add_argument("log", metavar="LOG.csv")
    fit.add_argument("--temperature-column", required=True, metavar="COL",
                     help="column of temperatures [degC]")
    fit.add_argument("--reference-column", required=True, metavar="COL",
                     help="column of reference magnitudes, e.g. a proton magnetometer [unit]")
    fit.add_argument("--base-temperature", type=float, metavar="T0",
                     help="temperature of the system calibration, where k = 1 [degC] (default: "
                          "the log's mean, with a warning)")
    add_log_arguments(fit)
    fit.add_argument("-o", "--output", metavar="DRIFT.json",
                     help="write the fit here (stdout when absent)")
    fit.set_defaults(func=run_fit)


def _read_with_temperature(args):
    """The log with its reference and temperature columns: (log, reference, temperature)."""
    check_output_path(args.output)
    _check_distinct(args.temperature_column, args.reference_column)
    log = read_log(args.log, args.columns, args.unit, args.drop_invalid,
                   [args.reference_column, args.temperature_column])
    _check_not_field(log, args.temperature_column, args.reference_column)
    return log, reference_from_args(args, log), column_values(log, args.temperature_column)


def run_fit(args) -> int:
    log, reference, temperature = _read_with_temperature(args)
    fit = fit_drift(log.samples, temperature, reference, base_temperature=args.base_temperature,
                    unit=log.base_unit)
    fit.input = {"log": str(args.log), "columns": log.columns, "log_unit": log.unit,
                 "temperature_column": args.temperature_column,
                 "reference_column": args.reference_column, "csv_engine": csv_engine(),
                 "rows_dropped": int((~log.kept).sum())}
    print(f"|B_m| = a t + b (Eq. 1): a = {fit.a:.6g} +/- {fit.a_standard_error:.2g} nT/degC, "
          f"b = {fit.b:.8g} +/- {fit.b_standard_error:.2g} nT, fit RMSE {fit.fit_rmse:.4g} nT, "
          f"n = {fit.n}, t = {fit.temperature_range[0]:g} .. {fit.temperature_range[1]:g} degC; "
          f"k(t) = 1 + {fit.k_slope:.6g} (t - {fit.base_temperature:g}) (Eq. 9)", file=sys.stderr)
    for message in fit.warnings:
        warn(f"warning: {message}")
    emit_json(fit.to_dict(), args.output)
    return 0


# --- shared helpers ----------------------------------------------------------------------------

def _check_distinct(temperature_column, reference_column) -> None:
    if temperature_column and reference_column and temperature_column == reference_column:
        raise InputError(f"--temperature-column and --reference-column are both "
                         f"{temperature_column!r}; they must be different columns")


def _check_not_field(log, *columns) -> None:
    for name in columns:
        if name and name in log.columns:
            raise InputError(f"column {name!r} is one of the field columns "
                             f"({', '.join(log.columns)}); pass the temperature or reference "
                             f"column, or --columns X Y Z")


def column_values(log, column) -> np.ndarray:
    """A numeric column of the log, on the rows behind log.samples (read_log has validated it)."""
    return pd.to_numeric(log.frame[column], errors="coerce").to_numpy(float)[log.kept]


def _header(path):
    """The column names of a CSV file, or None when it cannot be read (read_log reports that)."""
    try:
        return [str(c).strip() for c in pd.read_csv(path, nrows=0).columns]
    except Exception:  # noqa: BLE001 - any failure is reported by read_log with its own message
        return None


def add_temperature_arguments(parser, command: str) -> None:
    """The temperature options of `calibrate`, `apply` and `stats` (called from nlpcal.cli.core)."""
    if command == "calibrate":
        parser.add_argument("--temperature-column", metavar="COL",
                            help="column of temperatures [degC]: estimate the nine parameters and "
                                 "temperature coefficients in one NLP (needs --reference-column; "
                                 "--method, --cycles and the targets do not apply)")
        parser.add_argument("--temperature-model", choices=TEMPERATURE_MODELS,
                            help="common: one factor k(t) on scale and offset of all axes (Liu et "
                                 "al. 2022, Eq. 9; the default); per-axis: linear scale and "
                                 "offset drift per axis. Angles stay temperature-free")
        parser.add_argument("--base-temperature", type=float, metavar="T0",
                            help="temperature at which the nine parameters are reported [degC] "
                                 "(default: the log's mean)")
        return
    parser.add_argument("--drift", metavar="DRIFT.json",
                        help="output of 'nlpcal drift fit': divide the raw vector by k(t) "
                             "(Eq. 9) before the correction")
    parser.add_argument("--temperature-column", metavar="COL",
                        help="column of temperatures [degC] for --drift or for parameters with "
                             "a temperature model (default: the column they were fitted with)")
    if command == "stats":
        parser.add_argument("--reference-column", metavar="COL",
                            help="column of reference magnitudes [unit]: add the RMSE of Eq. 10 "
                                 "(Liu et al. 2022) to every row")


# --- calibrate --temperature-column --------------------------------------------------------------

def run_temperature_calibrate(args) -> int:
    """`nlpcal calibrate LOG --reference-column F --temperature-column T [--temperature-model]`."""
    if not args.temperature_column:
        raise InputError("--temperature-model needs --temperature-column COL")
    if not args.reference_column:
        raise InputError("the temperature calibration needs --reference-column COL, a reference "
                         "magnitude per sample (for example a proton magnetometer)")
    log, reference, temperature = _read_with_temperature(args)
    result = calibrate_temperature(log.samples, temperature, reference,
                                   model=args.temperature_model or "common",
                                   base_temperature=args.base_temperature, unit=log.base_unit,
                                   temperature_column=args.temperature_column)
    document = result.to_dict()
    document["input"] = {"log": str(args.log), "columns": log.columns, "log_unit": log.unit,
                         "temperature_column": args.temperature_column,
                         "csv_engine": csv_engine(), "rows_dropped": int((~log.kept).sum())}
    document["reference"]["column"] = args.reference_column
    report_calibration(result, document, args.output)
    return 0


# --- apply and stats ---------------------------------------------------------------------------

@dataclass
class TemperatureCorrection:
    """What --drift, --temperature-column and a stored temperature model ask of apply and stats.

    drift : the k(t) of a drift file (Eq. 9), or None.
    calibration : parameters with a temperature model, or None.
    column : the temperature column to use, or None (no temperature correction).
    reference_column : stats only, the column for the RMSE of Eq. 10.
    """

    drift: DriftFit | None = None
    calibration: TemperatureCalibrationResult | None = None
    column: str | None = None
    reference_column: str | None = None

    @classmethod
    def from_args(cls, args, command: str) -> "TemperatureCorrection":
        drift_path = getattr(args, "drift", None)
        column = getattr(args, "temperature_column", None)
        calibration = None
        if getattr(args, "params", None):
            document = read_json(args.params, "nlpcal parameters file")
            if has_temperature_model(document):
                calibration = TemperatureCalibrationResult.from_dict(document)
        drift = DriftFit.load(drift_path) if drift_path else None
        if drift is not None and calibration is not None:
            raise InputError(f"{args.params} already carries a temperature model; --drift "
                             f"applies only to parameters without one, so drop --drift")
        if column and drift is None and calibration is None:
            raise InputError("--temperature-column needs --drift DRIFT.json or parameters with a "
                             "temperature model")
        reference_column = getattr(args, "reference_column", None)
        _check_distinct(column, reference_column)
        if column is None and (drift is not None or calibration is not None):
            source = "drift file" if drift is not None else "temperature model"
            stored = (drift.input.get("temperature_column") if drift is not None
                      else calibration.temperature_column)
            header = _header(args.log)
            if stored and (header is None or stored in header):
                column = stored
            elif command == "apply" or drift is not None:
                have = f", which {args.log} lacks" if stored else ""
                raise InputError(f"the {source} needs a temperature column (fitted with "
                                 f"{stored!r}{have}); pass --temperature-column COL")
            else:
                warn(f"note: {args.log} has no column {stored!r} for the temperature model; "
                     f"pass --temperature-column COL for the temperature row")
        return cls(drift=drift, calibration=calibration, column=column,
                   reference_column=reference_column)

    @property
    def columns(self) -> list:
        """Extra columns that read_log must find and validate."""
        return [c for c in dict.fromkeys([self.reference_column, self.column]) if c]

    def _temperature(self, log) -> np.ndarray:
        _check_not_field(log, self.column, self.reference_column)
        temperature = column_values(log, self.column)
        low, high = (self.drift.temperature_range if self.drift is not None
                     else self.calibration.temperature_range)
        what = "the drift fit" if self.drift is not None else "the temperature calibration"
        beyond = max(float(low) - float(temperature.min()), float(temperature.max()) - float(high))
        if np.isfinite(beyond) and beyond > EXTRAPOLATION_NOTE_DEGC:
            warn(f"note: the log's temperatures {temperature.min():g} .. {temperature.max():g} "
                 f"degC reach {beyond:.3g} degC beyond the range {low:g} .. {high:g} degC of "
                 f"{what}; the linear temperature model is extrapolated")
        return temperature

    def correct(self, result, log) -> np.ndarray:
        """Corrected samples in the log's base unit; `result` may be None for --drift alone."""
        if self.column is None:
            return result.apply(log.samples)
        temperature = self._temperature(log)
        if self.calibration is not None:
            return self.calibration.apply(log.samples, temperature)
        return self.drift.correct(log.samples, temperature,
                                  None if result is None else result.model)

    def stats_rows(self, args, log, result, rows):
        """Add the RMSE of Eq. 10 to the rows and the temperature row; returns (rows, extra)."""
        reference = None
        if self.reference_column:
            _check_not_field(log, self.reference_column)
            reference = check_reference(reference_from_args(args, log), log.samples.shape[0])
            rows[0]["rmse"] = rmse(np.linalg.norm(log.samples, axis=1), reference)  # Eq. 10
            if result is not None:
                corrected = result.apply(log.samples)
                rows[1]["rmse"] = rmse(np.linalg.norm(corrected, axis=1), reference)  # Eq. 10
        if self.column is not None:
            label = "corrected + temperature" if result is not None else "temperature"
            rows.append(evaluation_row(label, self.correct(result, log), reference))
        return rows, (("rmse",) if reference is not None else ())
