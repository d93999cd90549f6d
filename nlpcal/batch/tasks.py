"""What a worker does for one log of a batch: read it, calibrate or correct it, write its output,
and turn whatever happened into a row of the summary."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..calibration import CalibrationResult, calibrate_log
from ..correction import (
    Correction,
    corrected_chunks,
    load_parameters,
    outlier_bounds,
    read_log_for,
)
from ..drift.fit import DriftFit
from ..errors import InputError, QualityError, SolveError, WriteError
from ..io import Outputs, read_log
from ..io.output import Precision, write_frames
from ..io.stream import LogStream
from ..statistics import MagnitudeStats
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
            drift = DriftFit.load(self.drift) if self.drift else None
            options = dict(self.read_options)
            formats = {key: options.get(key) for key in ("header", "variable", "instance")}
            with LogStream(log_path, **formats) as stream:
                correction = Correction.plan(
                    parameters, drift, self.temperature_column, log_columns=stream.table_columns
                )
                column = correction.temperature_column
                role = {"the temperature column of the calibration": column} if column else {}
                stream.open(
                    options.get("columns"),
                    unit=options.get("unit"),
                    fallback_unit=correction.fallback_unit,
                    extra_columns=role,
                    drop_invalid=bool(options.get("drop_invalid")),
                )
                bounds = None
                if self.flag_outliers:  # the whole log first, for the centre and spread
                    log = read_log_for(stream.readable, correction, **self.read_options)
                    magnitude = np.linalg.norm(correction.apply(log), axis=1)
                    bounds = outlier_bounds(correction, magnitude)
                    row["outliers"] = int(np.sum(np.abs(magnitude - bounds[0]) > bounds[1]))
                measured, corrected = MagnitudeStats(), MagnitudeStats()

                def tally(before, after):
                    measured.add(before)
                    corrected.add(after)

                chunks = corrected_chunks(stream, correction, Precision(), bounds, tally)
                with Outputs() as outputs:  # in the layout of the log, as `nlpcal apply` writes
                    write_frames(outputs, output, chunks, stream.layout)
            row.update(
                output=str(output),
                n_samples=measured.n,
                std_measured=measured.result()["std"],
                std_corrected=corrected.result()["std"],
                warnings=WARNING_SEPARATOR.join(
                    [*stream.warnings, *stream.notes, *stream.summary(), *correction.notes]
                ),
                unit=stream.base_unit,
            )
            status_row(row, "ok")
        except Exception as exc:
            status_row(row, *failure(exc))
        row["seconds"] = time.perf_counter() - started
        return row
