"""The platform commands' logs: the vector, the scalar, the channels and the sample rate of a
log, and the log written back with the compensated scalar (`nlpcal platform fit|apply`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import units
from ..errors import InputError
from ..geomagnetic import parse_times
from ..io import Log, column_name, read_log, read_table
from ..io.logs import reference_unit
from ..io.tables import Table
from . import bandpass
from .fit import TollesLawsonFit, fit_tolles_lawson

#: Sampling counts as regular when every interval is within this fraction of the mean. [1]
REGULAR_SPREAD = 0.05
#: The column `apply` adds: the scalar's name and this suffix.
COMPENSATED_SUFFIX = "_compensated"


@dataclass
class PlatformLog:
    """A log read for the platform fit.

    log : the vector magnetometer's log (`nlpcal.io.Log`), its samples in the base unit.
    scalar : the scalar readings. [scalar_unit converted to its base unit]
    scalar_name, scalar_unit : the scalar's column and the unit it is written in.
    aux : the auxiliary channels (N, k), as read. [channel units]
    aux_names : their columns.
    rate_hz : the rate of the time column, None without one. [Hz]
    table : the table read, its cells as text when read to be written back.
    """

    log: Log
    scalar: np.ndarray
    scalar_name: str
    scalar_unit: str
    aux: np.ndarray | None
    aux_names: list
    rate_hz: float | None
    table: Table


def read_platform_log(
    path,
    scalar_column,
    *,
    columns=None,
    unit: str | None = None,
    aux_columns=(),
    time_column=None,
    header: bool | None = None,
    fallback_unit: str = "nT",
    text: bool = False,
) -> PlatformLog:
    """Read a log with a vector magnetometer, a scalar, channels and times; every row must be a
    reading, the record being a time series."""
    table = read_table(path, header=header, text=text)
    roles = {"--scalar-column": scalar_column}
    roles.update({f"--aux-columns {k + 1}": c for k, c in enumerate(aux_columns)})
    if time_column is not None:
        roles["--time-column"] = time_column
    log = read_log(table, columns, unit=unit, extra_columns=roles, fallback_unit=fallback_unit)
    if log.dropped:
        raise InputError(
            f"{log.path}: {log.dropped} row(s) are not readings (missing values or a (0, 0, 0) "
            f"vector); the band-pass needs every row of a regular record: fix or cut them"
        )
    scalar_name = log.column(scalar_column)
    scalar_unit = reference_unit(scalar_name, log.unit, log.notes)
    aux_names = [log.column(c) for c in aux_columns]
    rate = None
    if time_column is not None:
        rate = sample_rate(table.frame[column_name(table.frame, time_column)], str(time_column))
    return PlatformLog(
        log=log,
        scalar=units.to_base(log.values(scalar_name), scalar_unit),
        scalar_name=scalar_name,
        scalar_unit=scalar_unit,
        aux=np.column_stack([log.values(c) for c in aux_names]) if aux_names else None,
        aux_names=aux_names,
        rate_hz=rate,
        table=table,
    )


def sample_rate(times, name: str) -> float:
    """The rate of a regularly sampled time column (seconds, Unix or relative, or ISO 8601
    text), or InputError for irregular sampling. [Hz]"""
    series = pd.Series(times)
    seconds = np.full(len(series), np.nan)
    if not pd.api.types.is_datetime64_any_dtype(series):  # numbers, or numbers as text
        seconds = pd.to_numeric(series, errors="coerce").to_numpy(dtype=float)
    if not np.isfinite(seconds).all():
        parsed = parse_times(times)
        if np.isnat(parsed).any():
            raise InputError(f"the time column {name!r} holds cells that are not times")
        seconds = (parsed - parsed[0]) / np.timedelta64(1, "ns") * 1e-9
    steps = np.diff(seconds)
    if steps.size == 0:
        raise InputError(f"the time column {name!r} has a single row: no rate")
    mean = (seconds[-1] - seconds[0]) / steps.size
    if not mean > 0 or np.abs(steps - mean).max() > REGULAR_SPREAD * mean:
        raise InputError(
            f"the time column {name!r} is not regularly sampled (intervals from "
            f"{steps.min():.6g} to {steps.max():.6g} s about a mean of {mean:.6g} s); the "
            f"band-pass needs a regular rate: resample the log, or cut it at its gaps"
        )
    return 1.0 / mean


def one_rate(rate_hz, time_rate, stored=None) -> float:
    """The sample rate from --rate or the time column (not both), else the stored one. [Hz]"""
    if rate_hz is not None and time_rate is not None:
        raise InputError("give --rate or --time-column, not both")
    rate = rate_hz if rate_hz is not None else time_rate if time_rate is not None else stored
    if rate is None:
        raise InputError("the band-pass needs the sample rate: pass --time-column COL or --rate HZ")
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(f"--rate {rate!r}: expected a positive number of Hz")
    return float(rate)


def fit_platform_log(
    record: PlatformLog,
    *,
    rate_hz: float | None = None,
    terms: int = 18,
    band_hz=bandpass.DEFAULT_BAND_HZ,
    time_column=None,
) -> TollesLawsonFit:
    """The `TollesLawsonFit` of a log read by `read_platform_log` (`nlpcal platform fit`), at
    `rate_hz` or the rate of its `time_column`."""
    log = record.log
    fit = fit_tolles_lawson(
        log.samples,
        record.scalar,
        rate_hz=one_rate(rate_hz, record.rate_hz),
        terms=terms,
        band_hz=band_hz,
        aux=record.aux,
        aux_names=record.aux_names,
        unit=units.base_unit(record.scalar_unit),
        vector_unit=log.base_unit,
    )
    fit.scalar_column = record.scalar_name
    fit.time_column = None if time_column is None else str(time_column)
    fit.columns = list(log.columns)
    fit.input = log.metadata(scalar_unit=record.scalar_unit)
    return fit


def apply_platform_log(
    fit: TollesLawsonFit, path, *, header: bool | None = None, unit: str | None = None
) -> tuple:
    """(the log's table with the column '<scalar>_compensated' added, the `PlatformLog`) of a
    log compensated with `fit` (`nlpcal platform apply`); the log is read with the fit's
    columns, and its time column, if the fit had one, must give the fit's rate."""
    if fit.scalar_column is None:
        raise InputError("the platform fit names no scalar column; it was not fitted to a log")
    record = read_platform_log(
        path,
        fit.scalar_column,
        columns=fit.columns or None,
        unit=unit,
        aux_columns=fit.aux_columns,
        time_column=fit.time_column,
        header=header,
        fallback_unit=fit.input.get("log_unit", "nT"),
        text=True,
    )
    if record.rate_hz is not None and abs(record.rate_hz / fit.sample_rate_hz - 1) > REGULAR_SPREAD:
        raise InputError(
            f"the log is sampled at {record.rate_hz:.6g} Hz, the fit at {fit.sample_rate_hz:.6g} "
            f"Hz; the eddy terms and the band depend on the rate: fit at this rate"
        )
    compensated = fit.compensate(record.log.samples, record.scalar, record.aux)
    frame = record.table.frame.copy()
    frame[f"{record.scalar_name}{COMPENSATED_SUFFIX}"] = units.from_base(
        compensated, record.scalar_unit
    )
    return frame, record
