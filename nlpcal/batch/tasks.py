"""What a worker does for one log of a batch: read it, calibrate or correct it, write its output,
and turn whatever happened into a row of the summary."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..calibration import CalibrationResult, calibrate_log
from ..correction import (
    OUTLIER_COLUMN,
    TOTAL_COLUMN,
    Correction,
    load_parameters,
    outliers,
    read_log_for,
)
from ..drift.fit import DriftFit
from ..errors import InputError, QualityError, SolveError, WriteError
from ..io import read_log, read_table, write_bytes_atomic, write_table
from ..io.sources import is_parquet, write_parquet
from ..io.strict import finite_table
from ..statistics import field_statistics
from ..verdict import worst

#: Status of a log -> the exit status of the single command.
STATUSES = {"ok": 0, "quality-failed": 1, "solve-failed": 1, "bad-input": 2, "error": 1}
#: Joins the warnings of a log in one cell.
WARNING_SEPARATOR = " | "


def failure(exc: BaseException) -> tuple:
    """(status, message) of a log whose task raised `exc`."""
    message = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, QualityError):  # without the Python keywords that would override it
        return "quality-failed", " ".join(exc.reason.split())
    if isinstance(exc, SolveError):
        status = f" (solver status: {exc.status})" if exc.status else ""
        return "solve-failed", message + status
    if isinstance(exc, WriteError):
        return "error", message
    if isinstance(exc, InputError):
        return "bad-input", message
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if exc.filename else ""
        return "bad-input", f"{where}{exc.strerror or message}"
    if isinstance(exc, (MemoryError, RecursionError)):
        return "bad-input", f"the input is too large to process ({type(exc).__name__})"
    return "error", f"{type(exc).__name__}: {message} (a defect of nlpcal, or the worker died)"


def status_row(row: dict, status: str, message: str = "") -> dict:
    """The row with its status and exit status; a calibration's verdict (`nlpcal.verdict`) is
    "failed" unless the status is "ok", and at least "warnings" with warnings in the row."""
    row.update(status=status, exit_status=STATUSES[status], message=message)
    if status != "ok":
        row["verdict"] = "failed"
    elif "verdict" in row:  # a calibration's: warnings from reading the log count too
        row["verdict"] = worst(row["verdict"], "warnings" if row.get("warnings") else "ok")
    return row


def calibration_row(result: CalibrationResult) -> dict:
    """The summary columns a calibration result fills."""
    errors = result.standard_errors or {}
    row: dict = {"model": result.model_name}
    for name in result.estimated_parameters:  # those the model fixes stay empty
        row[name] = result.parameters[name]
        row[f"{name}_se"] = errors.get(name)
    coverage = result.identifiability.get("coverage", {})
    row.update(
        verdict=result.verdict.status,
        std_measured=result.statistics[0]["std"] if result.statistics else None,
        std_corrected=result.statistics[-1]["std"] if result.statistics else None,
        coverage_fraction=coverage.get("fraction"),
        warnings=WARNING_SEPARATOR.join(result.warnings),
        unit=result.unit,
        unit_source=result.unit_source,
        n_samples=result.n_samples,
    )
    return row


@dataclass(frozen=True)
class CalibrateTask:
    """Calibrate one log and write its parameters: what a worker runs for each log.

    read_options : keyword arguments of `nlpcal.io.read_log`.
    options : keyword arguments of `nlpcal.calibration.calibrate_log`.
    """

    read_options: dict = field(default_factory=dict)
    options: dict = field(default_factory=dict)

    def __call__(self, job: tuple) -> dict:
        log_path, output = job
        started = time.perf_counter()
        row: dict = {"log": str(log_path), "action": "run"}
        try:
            log = read_log(log_path, **self.read_options)
            result = calibrate_log(log, **self.options)
            row.update(calibration_row(result))
            result.save(output)
            row["output"] = str(output)
            status_row(row, "ok")
        except Exception as exc:
            if isinstance(exc, QualityError) and isinstance(exc.result, CalibrationResult):
                row.update(calibration_row(exc.result))
            status_row(row, *failure(exc))
        row["seconds"] = time.perf_counter() - started
        return row


@dataclass(frozen=True)
class ApplyTask:
    """Correct one log and write it: what a worker runs for each log of `apply_many`."""

    read_options: dict = field(default_factory=dict)
    flag_outliers: bool = False
    drift: str | None = None
    temperature_column: str | None = None

    def __call__(self, job: tuple) -> dict:
        log_path, params_path, output = job
        started = time.perf_counter()
        row: dict = {"log": str(log_path), "params": str(params_path or ""), "action": "run"}
        try:
            if params_path and not Path(params_path).exists():
                raise InputError(
                    f"no parameters for this log: {params_path} does not exist (its "
                    f"calibration failed, or it was not calibrated)"
                )
            parameters = load_parameters(params_path) if params_path else None
            options = {k: self.read_options.get(k) for k in ("header", "variable", "instance")}
            table = read_table(log_path, **options, text=True)
            correction = Correction.plan(
                parameters,
                DriftFit.load(self.drift) if self.drift else None,
                self.temperature_column,
                log_columns=table.columns,
            )
            log = read_log_for(table, correction, **self.read_options)
            corrected = correction.apply(log)
            extra = {}
            if self.flag_outliers:
                extra[OUTLIER_COLUMN] = flags = outliers(correction, corrected)
                row["outliers"] = int(flags.sum())
            frame = log.written_back(corrected, TOTAL_COLUMN, extra)
            if is_parquet(log_path):
                write_bytes_atomic(output, write_parquet(finite_table(frame)))
            else:  # in the layout of the log, as `nlpcal apply` writes it
                write_table(frame, log.layout, output)
            row.update(
                output=str(output),
                n_samples=log.n,
                std_measured=field_statistics(log.samples)["std"],
                std_corrected=float(np.std(np.linalg.norm(corrected, axis=1))),
                warnings=WARNING_SEPARATOR.join([*log.warnings, *log.notes, *correction.notes]),
                unit=log.base_unit,
            )
            status_row(row, "ok")
        except Exception as exc:
            status_row(row, *failure(exc))
        row["seconds"] = time.perf_counter() - started
        return row
