"""`read_log`: a magnetometer log as samples, reference and extra columns, in base units.

The unit of the field columns is the one asked for, else the one their names carry (mx_uT,
"Magnetometer X (uT)", _gauss, _counts for raw), else a fallback (nT, or the unit of the log the
parameters being applied were estimated from). A reference column is in the unit its name
carries ("proton_nT"), else in the log's unit; a reference number is in the log's unit unless its
own unit is given. What the reader decided on the user's behalf is said in `Log.notes`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .. import units, validation
from ..errors import InputError
from ..geomagnetic import ReferenceModel, parse_times
from .tables import (
    column_name,
    csv_engine,
    csv_to_memmap,
    numeric_columns,
    read_table,
    read_table_header,
    resolve_columns,
)


@dataclass
class Log:
    """A field log read for nlpcal.

    path : where it came from.
    columns : the three field columns.
    samples : (N, 3) field samples in the base unit (nT, or raw counts). [base unit]
    unit : the unit of the field columns in the file.
    reference : None, a number or (N,) values of the reference field magnitude. [base unit]
    reference_column : the column the reference came from, if any.
    extras : the other requested columns on the rows of `samples`, as read (temperature [degC]).
    frame : the whole table (None when streamed with low_memory).
    kept : boolean mask of the table's rows behind `samples` (None when streamed).
    dropped : rows dropped as invalid.
    engine : the pandas CSV engine that read it.
    notes : what the reader decided on the user's behalf, for the user to read.
    """

    path: str
    columns: list
    samples: np.ndarray
    unit: str
    reference: object = None
    reference_column: str | None = None
    reference_source: dict | None = None
    extras: dict = field(default_factory=dict)
    frame: pd.DataFrame | None = None
    kept: np.ndarray | None = None
    dropped: int = 0
    engine: str = "c"
    notes: list = field(default_factory=list)

    @property
    def base_unit(self) -> str:
        """The unit of `samples` and `reference`: "nT", or "raw" for counts."""
        return units.base_unit(self.unit)

    @property
    def n(self) -> int:
        return int(self.samples.shape[0])

    def metadata(self, **more) -> dict:
        """The "input" block of a result document (and `more` entries)."""
        return {
            "log": self.path,
            "columns": list(self.columns),
            "log_unit": self.unit,
            "csv_engine": self.engine,
            "rows_dropped": int(self.dropped),
            **more,
        }

    def written_back(self, corrected, total_column: str, extra=None) -> pd.DataFrame:
        """The log's table on the rows of `samples`, its field columns replaced by `corrected`
        [base unit] converted back to the log's unit, their magnitude in `total_column`, and the
        `extra` columns (name -> values on the rows of `samples`). Every other column passes
        through unchanged."""
        if self.frame is None:
            raise InputError(
                f"{self.path}: a log streamed into a memory map cannot be written "
                f"back; read it without low_memory"
            )
        values = units.from_base(corrected, self.unit)
        frame = self.frame.loc[self.kept].copy()
        for k, column in enumerate(self.columns):
            frame[column] = values[:, k]
        frame[total_column] = np.linalg.norm(values, axis=1)
        for name, column in (extra or {}).items():
            frame[name] = column
        return frame

    def values(self, column: str) -> np.ndarray:
        """An extra column on the rows of `samples`, as read."""
        return self.extras[column]


def log_unit(columns, unit=None, fallback: str = "nT", notes=None) -> str:
    """The unit of the field columns: `unit`, else the one their names carry, else `fallback`."""
    notes = [] if notes is None else notes
    hinted = units.suggested_unit(columns)
    if unit is None:
        if hinted:
            notes.append(f"unit {hinted} taken from the column names ({', '.join(columns)})")
        return hinted or fallback
    units.field_factor(unit)
    if hinted and hinted != unit:
        notes.append(
            f"the column names ({', '.join(columns)}) suggest {hinted}, but --unit is {unit}"
        )
    return unit


def reference_unit(column: str, log_unit_: str, notes) -> str:
    """The unit of a reference column: the one its name carries, else the log's."""
    named = units.unit_in_name(column)
    if named and named != log_unit_:
        notes.append(f"reference column {column!r} read in {named}, the unit its name carries")
    return named or log_unit_


def read_log(
    path,
    columns=None,
    *,
    unit: str | None = None,
    reference_column: str | None = None,
    reference_field=None,
    reference_field_unit: str | None = None,
    reference_model: ReferenceModel | None = None,
    extra_columns=(),
    drop_invalid: bool = False,
    low_memory: bool = False,
    fallback_unit: str = "nT",
) -> Log:
    """Read, validate and convert a field log.

    columns : the three field columns (None: detected).
    unit : the unit of the field columns (None: from their names, else `fallback_unit`).
    reference_column : a column of reference magnitudes, or reference_field : one number (in
        `reference_field_unit`, default the log's unit). The reference is converted to the base
        unit with the samples.
    reference_model : or the total field of a geomagnetic model at the log's place and date,
        constant or per sample from position and time columns (`nlpcal.geomagnetic`). [nT]
    extra_columns : further numeric columns to read and validate (temperatures, say).
    low_memory : stream the columns into a memory-mapped temporary file, O(chunk) memory.
    """
    given = [reference_column, reference_field, reference_model]
    if sum(value is not None for value in given) > 1:
        raise InputError("give one reference: a column, a field or a geomagnetic model")
    notes: list = []
    model_columns = reference_model.numeric_columns() if reference_model else []
    time_column = reference_model.time_column if reference_model else None
    extra = [c for c in dict.fromkeys([reference_column, *model_columns, *extra_columns]) if c]
    requested = list(extra)
    if low_memory and (model_columns or time_column):
        raise InputError(
            "a reference from position or time columns needs the log in memory; drop --low-memory"
        )
    if low_memory:
        header = read_table_header(path)
        chosen = resolve_columns(header, columns)
        extra = [column_name(header, c) for c in extra]
        unit = log_unit(chosen, unit, fallback_unit, notes)
        mapped = csv_to_memmap(
            path, chosen, extra, drop_invalid=drop_invalid, scale=units.field_factor(unit)
        )
        values, frame, kept = mapped.values, None, None
        dropped, engine = mapped.dropped, "c (chunked into a memory map)"
        samples = values[:, :3]
    else:
        frame = read_table(path)
        chosen = resolve_columns(frame, columns)
        extra = [column_name(frame, c) for c in extra]
        checked, time_name = frame, None
        if time_column:  # times enter the row checks as Unix seconds
            time_name = column_name(frame, time_column)
            checked = frame.assign(**{time_name: _unix_seconds(frame[time_name])})
        numeric = numeric_columns(
            checked,
            chosen + extra + ([time_name] if time_name else []),
            drop_invalid=drop_invalid,
            source=str(path),
        )
        if not numeric.kept.any():
            raise InputError(f"{path}: no data rows")
        unit = log_unit(chosen, unit, fallback_unit, notes)
        values, kept, dropped, engine = numeric.values, numeric.kept, numeric.dropped, csv_engine()
        samples = values[:, :3] * units.field_factor(unit)
    _check_distinct(chosen, extra)
    resolved = dict(zip(requested, extra))  # the names asked for -> the log's own names
    if dropped:
        notes.append(f"dropped {dropped} row(s) with missing or non-numeric values")
    extras = {name: np.asarray(values[:, 3 + k]) for k, name in enumerate(extra)}
    reference, name, source = None, None, None
    if reference_column is not None:
        name = extra[0]
        ref_unit = reference_unit(name, unit, notes)
        units.check_compatible(unit, ref_unit, f"reference column {name!r}")
        reference = units.to_base(
            validation.reference(extras[name], len(extras[name]), f"the reference column {name!r}"),
            ref_unit,
        )
    elif reference_model is not None:
        if unit == "raw":
            raise InputError(
                "a geomagnetic model gives the field in nT, and raw counts cannot be compared "
                "with it; give the log's unit (--unit)"
            )
        found = {c: extras[resolved[c]] for c in model_columns}
        times = None
        if time_column:
            times = (values[:, -1] * 1e9).astype("int64").astype("datetime64[ns]")
        reference, source = reference_model.field(found, times)
        if np.ndim(reference) == 0:
            notes.append(
                f"reference field {source['total_nT']:.1f} nT from {source['name']} "
                f"({source['package']} {source['package_version']})"
            )
    elif reference_field is not None:
        ref_unit = reference_field_unit or unit
        units.check_compatible(unit, ref_unit)
        reference = units.to_base(
            validation.number(reference_field, "the reference field", positive=True), ref_unit
        )
    return Log(
        path=str(path),
        columns=chosen,
        samples=samples,
        unit=unit,
        reference=reference,
        reference_column=name,
        reference_source=source,
        extras=extras,
        frame=frame,
        kept=kept,
        dropped=dropped,
        engine=engine,
        notes=notes,
    )


def _unix_seconds(column) -> np.ndarray:
    """A time column as Unix seconds (NaN where a cell is not a time). [s]"""
    times = parse_times(column)
    seconds = times.astype("int64") / 1e9
    return np.where(np.isnat(times), np.nan, seconds)


def _check_distinct(field_columns, extra_columns) -> None:
    for name in extra_columns:
        if name in field_columns:
            raise InputError(
                f"column {name!r} is one of the field columns "
                f"({', '.join(field_columns)}); pass the temperature or reference "
                f"column, or --columns X Y Z"
            )


@dataclass
class SensorLog:
    """A log of a magnetometer and an accelerometer in one housing (an e-compass).

    mag : (N, 3) field in nT; acc : (N, 3) specific force in g, on the same rows.
    frame, kept : the table and the rows behind the samples; notes : as in `Log`.
    """

    path: str
    frame: pd.DataFrame
    kept: np.ndarray
    mag: np.ndarray
    acc: np.ndarray
    mag_columns: list
    acc_columns: list
    mag_unit: str
    acc_unit: str
    dropped: int = 0
    notes: list = field(default_factory=list)

    def with_columns(self, columns: dict) -> tuple:
        """The table with `columns` (name -> values on the rows of the samples) added, NaN on the
        rows skipped; returns (frame, the names that replaced existing columns)."""
        out = self.frame.copy()
        replaced = [name for name in columns if name in out.columns]
        for name, values in columns.items():
            column = np.full(len(out), np.nan)
            column[self.kept] = values
            out[name] = column
        return out, replaced

    def metadata(self, **more) -> dict:
        return {
            "file": self.path,
            "mag_columns": list(self.mag_columns),
            "acc_columns": list(self.acc_columns),
            "mag_unit": self.mag_unit,
            "acc_unit": self.acc_unit,
            "rows_skipped": int(self.dropped),
            **more,
        }


def _sensor_unit(columns, unit, fallback, prefixes, suffixes, what, notes) -> str:
    hinted = units.suggested_unit(columns, prefixes, suffixes)
    if unit is None:
        if hinted:
            notes.append(f"{what} unit {hinted} taken from the column names ({', '.join(columns)})")
        return hinted or fallback
    if hinted and hinted != unit:
        notes.append(
            f"the {what} columns ({', '.join(columns)}) suggest {hinted}, but the "
            f"{what} unit given is {unit}"
        )
    return unit


def read_sensor_log(
    path,
    mag_columns=None,
    acc_columns=None,
    *,
    mag_unit: str | None = None,
    acc_unit: str | None = None,
    drop_invalid: bool = False,
    mag_fallback: str = "nT",
    acc_fallback: str = "g",
) -> SensorLog:
    """Read a magnetometer + accelerometer log; the field in nT, the specific force in g.

    Columns are detected unless given; each sensor's unit is the one given, else the one its
    column names carry, else the fallback (nT and g, or the units of a calibration).
    """
    frame = read_table(path)
    mag_cols = resolve_columns(frame, mag_columns, what="magnetometer")
    acc_cols = resolve_columns(frame, acc_columns, what="accelerometer")
    if set(mag_cols) & set(acc_cols):
        raise InputError(
            f"the magnetometer columns ({', '.join(mag_cols)}) and accelerometer "
            f"columns ({', '.join(acc_cols)}) overlap; pass --mag-columns and "
            f"--acc-columns"
        )
    notes: list = []
    mag_unit = _sensor_unit(
        mag_cols,
        mag_unit,
        mag_fallback,
        units.MAGNETIC_PREFIXES,
        units.FIELD_SUFFIXES,
        "magnetometer",
        notes,
    )
    acc_unit = _sensor_unit(
        acc_cols,
        acc_unit,
        acc_fallback,
        units.ACC_PREFIXES,
        units.ACC_SUFFIXES,
        "accelerometer",
        notes,
    )
    if mag_unit == "raw":
        raise InputError(
            "the e-compass needs the magnetometer in a field unit (nT, uT, ...), "
            "not raw counts; pass --mag-unit"
        )
    numeric = numeric_columns(
        frame, mag_cols + acc_cols, drop_invalid=drop_invalid, source=str(path)
    )
    if not numeric.kept.any():
        raise InputError(f"{path}: no data rows")
    if numeric.dropped:
        notes.append(f"skipped {numeric.dropped} row(s) with missing or non-numeric values")
    return SensorLog(
        path=str(path),
        frame=frame,
        kept=numeric.kept,
        mag=numeric.values[:, :3] * units.field_factor(mag_unit),
        acc=numeric.values[:, 3:] * units.acc_factor(acc_unit),
        mag_columns=mag_cols,
        acc_columns=acc_cols,
        mag_unit=mag_unit,
        acc_unit=acc_unit,
        dropped=numeric.dropped,
        notes=notes,
    )


def read_columns(path, columns) -> np.ndarray:
    """Named columns of a table as floats, NaN where a cell is not a number."""
    frame = read_table(path)
    names = [column_name(frame, c) for c in columns]
    return frame[names].apply(pd.to_numeric, errors="coerce").to_numpy(dtype=float)
