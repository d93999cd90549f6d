"""`read_log`: a magnetometer log as samples, reference and extra columns, in base units.

Any delimited text log is read (`nlpcal.io.tables`): comma, semicolon, tab or whitespace, with or
without a header row, `-` for stdin. The unit of the field columns is the one asked for, else the
one their names carry (mx_uT, "Magnetometer X (uT)", _gauss, _counts for raw), else a fallback
(nT, or the unit of the log the parameters being applied were estimated from). Whatever the unit's
source, the magnitudes are checked against Earth's field, and a unit that cannot be right is
warned about with the units that would fit (`nlpcal.units.unit_warning`). A reference column is
in the unit its name carries ("proton_nT"), else in the log's unit; a reference number is in the
log's unit unless its own unit is given. Rows that are not readings are screened
(`nlpcal.io.rows`). What the reader decided on the user's behalf is said in `Log.notes`, what
looks wrong in `Log.warnings`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .. import robust, units, validation
from ..errors import InputError
from ..geomagnetic import ReferenceModel, parse_times
from ..moments import Frame, sphere_frame
from ..passes import sample_stride
from .layout import Layout
from .mapped import csv_to_memmap
from .observatory import Observatory
from .recorders import ENGINES, check_options, declared_unit, is_recorded
from .reference import ReferenceLog, with_reference_log
from .rows import RowScreen
from .tables import (
    Table,
    column_name,
    numbers,
    numeric_columns,
    read_table,
    resolve_columns,
)


@dataclass
class Log:
    """A field log read for nlpcal (`read_log`).

    Attributes
    ----------
    path : str
        Where it came from ("stdin" for `-`).
    columns : list of str
        The three field columns.
    samples : numpy.ndarray, shape (N, 3)
        Field samples in the base unit (nT, or raw counts). [base unit]
    unit : str
        The unit of the field columns in the file ("raw" when an assumed unit was ruled out).
    unit_source : str
        Where the unit came from: "option", "format", "names" or "assumed".
    reference : None, float or numpy.ndarray
        None, a number or (N,) values of the reference field magnitude. [base unit]
    reference_column : str or None
        The column the reference came from, if any.
    reference_source : dict or None
        What a geomagnetic-model reference came from (model, package), if any.
    extras : dict
        The other requested columns on the rows of `samples`, as read (temperature [degC]).
    frame : pandas.DataFrame or None
        The whole table (None when streamed with low_memory).
    kept : numpy.ndarray or None
        Boolean mask of the table's rows behind `samples` (None when streamed).
    dropped : int
        Rows left out (missing values, zero vectors, repeats with drop_invalid).
    engine : str
        The pandas CSV engine that read it.
    notes : list of str
        What the reader decided on the user's behalf, for the user to read.
    warnings : list of str
        What looks wrong (a unit that does not fit the magnitudes), for the user to read.
    layout : Layout
        How the file is laid out, to write it back the same way.
    observatory : Observatory or None
        The header of an observatory file (station, sensor, units, terms of use), kept in the
        result's provenance ("input.observatory").
    reference_log : dict or None
        Where a reference with its own time base came from and how it was interpolated
        (`nlpcal.io.reference`), kept in the result's provenance ("input.reference_log").
    times : numpy.ndarray or None
        The rows' times from `time_column` (`--time-column`), Unix seconds (numbers in the
        column are taken as they are: seconds from any origin). [s]

    Examples
    --------
    >>> import os, tempfile
    >>> import nlpcal
    >>> path = os.path.join(tempfile.mkdtemp(), "log.csv")
    >>> nlpcal.simulate(200, seed=0).to_csv(path, index=False)
    >>> log = nlpcal.read_log(path)
    >>> log.unit_source, log.n
    ('assumed', 200)
    """

    path: str
    columns: list
    samples: np.ndarray
    unit: str
    unit_source: str = "assumed"
    reference: object = None
    reference_column: str | None = None
    reference_source: dict | None = None
    extras: dict = field(default_factory=dict)
    frame: pd.DataFrame | None = None
    kept: np.ndarray | None = None
    dropped: int = 0
    engine: str = "c"
    notes: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    layout: Layout = field(default_factory=Layout)
    observatory: Observatory | None = None
    reference_log: dict | None = None
    times: np.ndarray | None = None

    @property
    def base_unit(self) -> str:
        """The unit of `samples` and `reference`: "nT", or "raw" for counts."""
        return units.base_unit(self.unit)

    @property
    def read_by(self) -> str:
        """What read the log, for messages: "pandas c engine", "pymavlink DFReader" ..."""
        return self.engine if self.recorded else f"pandas {self.engine} engine"

    @property
    def recorded(self) -> bool:
        """Whether the log was read from a recorded format (`nlpcal.io.recorders`), not text."""
        return self.engine in ENGINES.values()

    def reading(self) -> str:
        """How the log was read, for messages: its layout (of text) and its reader."""
        return self.read_by if self.recorded else f"{self.layout.describe()} ({self.read_by})"

    @property
    def n(self) -> int:
        return int(self.samples.shape[0])

    def metadata(self, **more) -> dict:
        """The "input" block of a result document (and `more` entries)."""
        return {
            "log": self.path,
            "columns": list(self.columns),
            "log_unit": self.unit,
            "unit_source": self.unit_source,
            "layout": self.layout.to_dict(),
            "csv_engine": self.engine,
            "rows_dropped": int(self.dropped),
            **({"observatory": self.observatory.to_dict()} if self.observatory else {}),
            **({"reference_log": dict(self.reference_log)} if self.reference_log else {}),
            **more,
        }

    def written_back(self, corrected, total_column: str, extra=None) -> pd.DataFrame:
        """The log's table on the rows of `samples`, its field columns replaced by `corrected`
        [base unit] converted back to the log's unit, their magnitude in `total_column`
        (appended last), and the `extra` columns (name -> values on the rows of `samples`).
        Every other column passes through unchanged; write it with
        `nlpcal.io.write_table(frame, log.layout, ...)` to keep the file's layout."""
        if self.frame is None:
            raise InputError(
                f"{self.path}: a log streamed into a memory map cannot be written "
                f"back; read it without low_memory"
            )
        values = units.from_base(corrected, self.unit)
        frame = self.frame.loc[self.kept].copy()
        for k, column in enumerate(self.columns):
            frame[column] = values[:, k]
        if total_column in frame.columns:
            frame = frame.drop(columns=total_column)
        frame[total_column] = np.linalg.norm(values, axis=1)
        for name, column in (extra or {}).items():
            frame[name] = column
        return frame

    def column(self, name) -> str:
        """The name under which an extra column was read (`name` may be a 0-based position or
        differ in case)."""
        if name in self.extras:
            return name
        if self.frame is not None:
            resolved = column_name(self.frame, name)
            if resolved in self.extras:
                return resolved
        lower = {key.lower(): key for key in self.extras}
        if str(name).lower() in lower:
            return lower[str(name).lower()]
        raise InputError(f"column {name!r} was not read with the log")

    def values(self, column) -> np.ndarray:
        """An extra column on the rows of `samples`, as read."""
        return self.extras[self.column(column)]


def format_unit(chosen, notes: list, table: Table | None = None) -> str | None:
    """The unit the file format fixes for the field columns `chosen`: the table's
    (`Table.field_unit`) when they are the columns its format fixes (the unit of other columns
    is not), else a ROS column's (`nlpcal.io.recorders.declared_unit`, said in `notes`), else
    None."""
    if table is not None and table.field_unit and table.field_columns in (None, list(chosen)):
        return table.field_unit
    return declared_unit(chosen, notes)


def sensor_unit(
    columns, unit, fallback, notes, what="magnetometer", flag="--unit", declared=None
) -> tuple:
    """(unit, source) of a sensor's columns, the source one of `nlpcal.units.UNIT_SOURCES`:
    `unit` ("option"), else the unit the file format `declared` ("format"), else the one the
    column names carry ("names"), else `fallback` ("assumed")."""
    prefixes = units.MAGNETIC_PREFIXES if what == "magnetometer" else units.ACC_PREFIXES
    suffixes = units.FIELD_SUFFIXES if what == "magnetometer" else units.ACC_SUFFIXES
    hinted = units.suggested_unit(columns, prefixes, suffixes)
    if unit is None and declared is not None:
        units.field_factor(declared)
        if hinted and hinted != declared:
            notes.append(
                f"the {what} columns ({', '.join(columns)}) suggest {hinted}, but the file "
                f"format fixes {declared}"
            )
        return declared, "format"
    if unit is None:
        if hinted:
            notes.append(f"{what} unit {hinted} taken from the column names ({', '.join(columns)})")
            return hinted, "names"
        return fallback, "assumed"
    if what == "magnetometer":
        units.field_factor(unit)
    else:
        units.acc_factor(unit)
    if hinted and hinted != unit:
        notes.append(
            f"the {what} columns ({', '.join(columns)}) suggest {hinted}, but {flag} is {unit}"
        )
    return unit, "option"


def typical_magnitudes(samples, frame: Frame | None = None) -> list:
    """Two estimates of a sensor's typical magnitude [unit of the samples]: the median |v|, and
    the radius of a sphere fitted to the samples (free of hard-iron offsets when the attitudes
    vary; meaningless when they do not, hence both).

    frame : `nlpcal.moments.sphere_frame` of these samples, when the caller has fitted it (the
    same strided subsample, so the same sphere); else it is fitted here.
    """
    samples = np.asarray(samples[:: sample_stride(samples.shape[0])], dtype=float)
    if samples.shape[0] == 0:
        return []
    largest = float(np.max(np.abs(samples)))
    # values whose squares leave float64 (1e-300 or 1e300, refused later as out of range) are
    # scaled first, so that the warning names their size
    scale = 1.0 if not 0.0 < largest < np.inf or 1e-100 < largest < 1e100 else largest
    median = robust.median(validation.magnitudes(samples / scale)) * scale
    if samples.shape[0] < 10:
        return [median, median]
    return [median, float((frame or sphere_frame(samples)).radius)]


def reference_unit(column: str, log_unit_: str, notes) -> str:
    """The unit of a reference column: the one its name carries, else the log's."""
    named = units.unit_in_name(column)
    if named and named != log_unit_:
        notes.append(f"reference column {column!r} read in {named}, the unit its name carries")
    return named or log_unit_


def screened(table: Table, wanted: list, drop_invalid: bool, notes: list, frame=None) -> tuple:
    """(values, kept mask over the table's rows, rows left out) of the wanted columns (of
    `frame`, when given: the table's cells with some columns converted)."""
    numeric = numeric_columns(
        table.frame if frame is None else frame,
        wanted,
        drop_invalid=drop_invalid,
        source=table.source,
        decimal=table.layout.decimal,
    )
    if numeric.dropped:
        notes.append(f"dropped {numeric.dropped} row(s) with missing or non-numeric values")
    screen = RowScreen(drop_repeats=drop_invalid)
    valid_rows = np.flatnonzero(numeric.kept)
    keep = screen.keep(numeric.values[:, :3], valid_rows + 1)
    notes.extend(screen.notes())
    if not keep.any():
        raise InputError(f"{table.source}: no data rows")
    if keep.all():
        return numeric.values, numeric.kept, numeric.dropped
    kept = numeric.kept.copy()
    kept[valid_rows[~keep]] = False
    return numeric.values[keep], kept, numeric.dropped + int((~keep).sum())


def one_reference(column, field, model, log=None) -> None:
    """InputError unless at most one of a reference column, field, model and log is given."""
    if sum(value is not None for value in (column, field, model, log)) > 1:
        raise InputError(
            "give one reference: a column, a field, a geomagnetic model or a reference log"
        )


def constant_reference(field, field_unit: str | None, unit: str) -> float:
    """A known field magnitude in `field_unit` (default the log's `unit`), in the base unit."""
    ref_unit = field_unit or unit
    units.check_compatible(unit, ref_unit)
    return units.to_base(validation.number(field, "the reference field", positive=True), ref_unit)


def model_reference(model: ReferenceModel, unit: str, notes: list, columns=None, times=None):
    """(reference [nT], the record of its source) from a geomagnetic model: constant, or per
    sample from position `columns` and `times`; a note says the constant's value and source."""
    if unit == "raw":
        raise InputError(
            "a geomagnetic model gives the field in nT, and raw counts cannot be compared "
            "with it; give the log's unit (--unit)"
        )
    reference, source = model.field(columns or {}, times)
    if np.ndim(reference) == 0:
        notes.append(
            f"reference field {source['total_nT']:.1f} nT from {source['name']} "
            f"({source['package']} {source['package_version']})"
        )
    return reference, source


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
    header: bool | None = None,
    text: bool = False,
    variable: str | None = None,
    instance: int | None = None,
    progress=None,
    reference_log: ReferenceLog | None = None,
    time_column: str | None = None,
) -> Log:
    """Read, validate and convert a field log.

    Parameters
    ----------
    path : str, os.PathLike or Table
        A log (`nlpcal.io.tables.read_table`: delimited text, Parquet, a MotionCal capture, a
        MATLAB .mat file, an ArduPilot DataFlash log), a glob pattern or folder of them, "-" for
        stdin, or a `Table` already read.
    columns : sequence of str or int, optional
        The three field columns, names or 0-based positions (`--columns`; None: detected).
    unit : str, optional
        The unit of the field columns (`--unit`; None: the unit a file format fixes, else the one
        their names carry, else `fallback_unit`; an assumed unit under which the magnitudes are far
        from Earth's field gives way to raw counts).
    reference_column : str, optional
        A column of reference magnitudes (`--reference-column`).
    reference_field : float, optional
        Or one reference magnitude (`--reference-field`). [reference_field_unit]
    reference_field_unit : str, optional
        The unit of `reference_field` (default: the log's unit).
    reference_model : ReferenceModel, optional
        Or the total field of a geomagnetic model at the log's place and date (`--reference-model`).
    extra_columns : sequence of str
        Further numeric columns to read and validate (temperatures, say).
    drop_invalid : bool
        Drop rows with missing or non-numeric values, and field vectors repeating the row before,
        instead of failing or keeping them (`--drop-invalid`). Exact-zero vectors are always left
        out.
    low_memory : bool
        Stream the columns into a memory-mapped temporary file, O(chunk) memory (`--low-memory`;
        text and Parquet logs, a recorded format is read whole, with a note).
    progress : Progress, optional
        Told how far a `low_memory` read has come (`nlpcal.io.progress.Progress`).
    reference_log : ReferenceLog, optional
        Or a reference read from another log with its own time base, interpolated onto the
        log's times (`--reference-log`, `nlpcal.io.reference`); rows outside its span dropped.
    time_column : str, optional
        A column of times (ISO 8601 text, or seconds) read into `Log.times` for the lag of a
        reference (`--time-column` without a geomagnetic model).
    fallback_unit : str
        The unit assumed when nothing names one.
    header : bool, optional
        Force (True) or deny (False) a header row (`--header`, `--no-header`); None detects it.
    text : bool
        Keep the table's cells as text (for writing the log back unchanged).
    variable : str, optional
        The variable of a .mat file that holds the field (`--variable`; None: detected).
    instance : int, optional
        The compass of a DataFlash log, 0-based like its I field (`--instance`; None: the only
        one).

    Returns
    -------
    Log
        The samples in the base unit (nT, or raw counts), the reference converted with them, and
        what the reader decided.

    Raises
    ------
    InputError
        An unreadable file, ambiguous or missing columns, invalid values, an unknown unit.

    Examples
    --------
    >>> import os, tempfile
    >>> import nlpcal
    >>> path = os.path.join(tempfile.mkdtemp(), "log.csv")
    >>> nlpcal.simulate(200, seed=0).to_csv(path, index=False)
    >>> log = nlpcal.read_log(path, unit="uT")  # the file's numbers read as uT
    >>> log.columns, log.unit, log.samples.shape  # the samples in nT
    (['bx', 'by', 'bz'], 'uT', (200, 3))
    """
    one_reference(reference_column, reference_field, reference_model, reference_log)
    if reference_log is not None and low_memory:
        raise InputError("--reference-log needs the log in memory; drop --low-memory")
    notes: list = []
    model_columns = reference_model.numeric_columns() if reference_model else []
    own_time = None if reference_model and reference_model.time_column else time_column
    time_column = reference_model.time_column if reference_model else time_column
    roles = column_roles(reference_column, reference_model, extra_columns)
    roles += [(TIME_ROLE, own_time)] if own_time else []
    extra = list(dict.fromkeys(column for role, column in roles if role != TIME_ROLE))
    requested = list(extra)
    low_memory = _streamed(path, low_memory, bool(model_columns or time_column), notes)
    reading = _Reading(
        unit=unit,
        fallback_unit=fallback_unit,
        header=header,
        text=text,
        variable=variable,
        instance=instance,
        drop_invalid=drop_invalid,
        progress=progress,
    )
    if low_memory:
        mapped, unit, how = _read_mapped(path, columns, extra, reading, notes)
        chosen, extra = mapped.columns[:3], mapped.columns[3:]
        named = dict(zip(requested, extra))
        distinct_roles(chosen, [(role, named[column]) for role, column in roles])
        values, frame, kept, dropped = mapped.values, None, None, mapped.dropped
        engine, layout, source = "c (chunked into a memory map)", mapped.layout, mapped.source
        samples = values[:, :3]
        observatory = None
    else:
        table, chosen, extra, values, kept, dropped, unit, how = _read_whole(
            path, columns, extra, roles, time_column, reading, notes
        )
        observatory = table.observatory
        frame, engine, layout, source = table.frame, table.engine, table.layout, table.source
        samples = values[:, :3] * units.field_factor(unit)
    if samples.shape[0]:
        validation.sample_sizes(samples)
    samples, unit, check = settle_unit(samples, unit, how)
    warnings = [check] if check else []
    resolved = dict(zip(requested, extra))  # the names asked for -> the log's own names
    extras = {name: np.asarray(values[:, 3 + k]) for k, name in enumerate(extra)}
    reference, name, source_of_reference = None, None, None
    if reference_column is not None:
        name = extra[0]
        reference = _column_reference(name, extras[name], unit, notes)
    elif reference_model is not None:
        found = {c: extras[resolved[c]] for c in model_columns}
        times = None
        if time_column:
            times = (values[:, -1] * 1e9).astype("int64").astype("datetime64[ns]")
        reference, source_of_reference = model_reference(reference_model, unit, notes, found, times)
    elif reference_field is not None:
        reference = constant_reference(reference_field, reference_field_unit, unit)
    read = Log(
        path=source,
        columns=list(chosen),
        samples=samples,
        unit=unit,
        unit_source=how,
        reference=reference,
        reference_column=name,
        reference_source=source_of_reference,
        extras=extras,
        frame=frame,
        kept=kept,
        dropped=dropped,
        engine=engine,
        notes=notes,
        warnings=warnings,
        layout=layout,
        observatory=observatory,
        times=np.asarray(values[:, -1], dtype=float) if time_column else None,
    )
    return read if reference_log is None else with_reference_log(read, reference_log)


@dataclass(frozen=True)
class _Reading:
    """How `read_log` reads a log's columns (its arguments of the same names)."""

    unit: str | None
    fallback_unit: str
    header: bool | None
    text: bool
    variable: str | None
    instance: int | None
    drop_invalid: bool
    progress: object = None


def _streamed(path, low_memory: bool, needs_whole: bool, notes: list) -> bool:
    """Whether the log is streamed into a memory map (`low_memory`): InputError when a
    reference from position or time columns, or a time column, needs it whole (`needs_whole`);
    a recorded format is read whole, with a note."""
    if low_memory and needs_whole:
        raise InputError(
            "a reference from position or time columns, or a time column, needs the log in "
            "memory; drop --low-memory"
        )
    if low_memory and not isinstance(path, Table) and is_recorded(path):
        notes.append(f"{path} is read whole: --low-memory streams text and Parquet logs only")
        low_memory = False
    return low_memory


def _read_whole(path, columns, extra, roles, time_column, reading: _Reading, notes: list) -> tuple:
    """A log read into memory (`read_table`, or the `Table` given as `path`): the table, the
    field columns chosen, the `extra` columns' own names, the screened values of both (times
    as Unix seconds last), the rows kept and dropped, and the unit of the field columns with
    how it was decided."""
    table = (
        path
        if isinstance(path, Table)
        else read_table(
            path,
            header=reading.header,
            text=reading.text,
            variable=reading.variable,
            instance=reading.instance,
        )
    )
    notes.extend(table.notes)
    chosen = resolve_columns(
        table.frame,
        columns or table.field_columns,
        header=table.layout.header,
        decimal=table.layout.decimal,
        notes=notes,
    )
    distinct_roles(chosen, [(role, column_name(table.frame, c)) for role, c in roles])
    extra = [column_name(table.frame, c) for c in extra]
    checked, times_at = None, []
    if time_column:  # times enter the row checks as Unix seconds
        time_name = column_name(table.frame, time_column)
        checked = table.frame.assign(**{time_name: _unix_seconds(table.frame[time_name])})
        times_at = [time_name]
    values, kept, dropped = screened(
        table, chosen + extra + times_at, reading.drop_invalid, notes, checked
    )
    declared = format_unit(chosen, notes, table)
    unit, how = sensor_unit(chosen, reading.unit, reading.fallback_unit, notes, declared=declared)
    return table, chosen, extra, values, kept, dropped, unit, how


def _read_mapped(path, columns, extra, reading: _Reading, notes: list) -> tuple:
    """The field and `extra` columns of a text or Parquet log streamed into a memory map
    (`csv_to_memmap`), the field in the base unit: the unit is decided (`sensor_unit`) once the
    columns are known. Returns the `MappedColumns`, the unit and how it was decided; their
    notes are added to `notes`."""
    check_options(str(path), None, variable=reading.variable, instance=reading.instance)
    decided: dict = {}

    def scale(chosen) -> float:  # the unit, once the columns are known
        decided["unit"], decided["how"] = sensor_unit(
            chosen, reading.unit, reading.fallback_unit, notes, declared=format_unit(chosen, notes)
        )
        return units.field_factor(decided["unit"])

    mapped = csv_to_memmap(
        path,
        columns,
        extra,
        header=reading.header,
        drop_invalid=reading.drop_invalid,
        scale=scale,
        progress=reading.progress,
    )
    notes.extend(mapped.notes)
    return mapped, decided["unit"], decided["how"]


def _column_reference(name: str, values, unit: str, notes: list):
    """The reference magnitudes of column `name` in the base unit of a log in `unit`: its own
    unit from its name (`reference_unit`), which must be compatible. [nT or raw]"""
    ref_unit = reference_unit(name, unit, notes)
    units.check_compatible(unit, ref_unit, f"reference column {name!r}")
    return units.to_base(
        validation.reference(values, len(values), f"the reference column {name!r}"),
        ref_unit,
    )


def _unix_seconds(column) -> np.ndarray:
    """A time column as Unix seconds (NaN where a cell is not a time). [s]"""
    times = parse_times(column)
    seconds = times.astype("int64") / 1e9
    return np.where(np.isnat(times), np.nan, seconds)


def unit_check(
    samples,
    unit: str,
    how: str,
    sensor="magnetometer",
    flag="--unit",
    raw_allowed=True,
    frame: Frame | None = None,
) -> str | None:
    """`nlpcal.units.unit_warning` for samples in the base unit of `sensor` (`frame`: their
    sphere, when fitted already, `typical_magnitudes`)."""
    if unit == "raw" or samples.shape[0] == 0:
        return None
    factor = units.field_factor(unit) if sensor == "magnetometer" else units.acc_factor(unit)
    in_unit = [m / factor for m in typical_magnitudes(samples, frame)]
    return units.unit_warning(in_unit, unit, how, sensor=sensor, flag=flag, raw_allowed=raw_allowed)


def settle_unit(samples, unit: str, how: str, frame: Frame | None = None) -> tuple:
    """(samples, unit, warning or None) after the plausibility check of a field log's unit.

    samples : in the base unit of `unit`. [nT or raw]
    frame : `nlpcal.moments.sphere_frame` of the samples, when the caller has fitted it.
    An assumed unit (`how` "assumed") under which the magnitudes are far from Earth's field is
    not kept: the samples are taken back to the file's numbers and recorded as raw counts, so no
    result made from them claims a field unit. A unit given, fixed by the format or carried by the
    names is kept, with the warning.
    """
    warning = unit_check(samples, unit, how, frame=frame)
    if warning is None or how != "assumed":
        return samples, unit, warning
    factor = units.field_factor(unit)
    return (samples if factor == 1.0 else samples * (1.0 / factor)), "raw", warning


#: The role of the column of times, read apart from the numeric columns.
TIME_ROLE = "--time-column"


def column_roles(reference_column=None, reference_model=None, extra_columns=()) -> list:
    """(role, column) of every column a log is read with besides the field columns: the
    reference, the position and time columns of a geomagnetic model, and `extra_columns` (a
    mapping of role to column, say {"--temperature-column": "temp_c"}, or a list)."""
    if not isinstance(extra_columns, Mapping):
        extra_columns = {f"extra column {k + 1}": c for k, c in enumerate(extra_columns)}
    roles = [("--reference-column", reference_column)]
    if reference_model is not None:
        roles += [
            ("--lat-column", reference_model.lat_column),
            ("--lon-column", reference_model.lon_column),
            ("--alt-column", reference_model.alt_column),
            (TIME_ROLE, reference_model.time_column),
        ]
    roles += list(extra_columns.items())
    return [(role, column) for role, column in roles if column is not None]


def distinct_roles(field_columns, roles) -> None:
    """One column, one role: InputError naming the column and both roles when the three field
    columns and `roles`, pairs of (role, the column's name in the log), name a column twice."""
    seen: dict = {}
    for role, name in [
        *zip(("field column x", "field column y", "field column z"), field_columns),
        *roles,
    ]:
        if name in seen and seen[name] != role:
            raise InputError(
                f"column {name!r} is given as both {seen[name]} and {role}; one column cannot be "
                f"two things: pass another column for one of them"
            )
        seen.setdefault(name, role)


def read_columns(path, columns, *, header: bool | None = None) -> np.ndarray:
    """Columns of a table (names or 0-based positions) as floats, NaN where a cell is not a
    number."""
    table = path if isinstance(path, Table) else read_table(path, header=header)
    names = [column_name(table.frame, c) for c in columns]
    return np.column_stack([numbers(table.frame[name], table.layout.decimal) for name in names])


def read_role_columns(path, groups: Mapping, *, header: bool | None = None) -> list:
    """`read_columns` of each group of columns in `groups` (a mapping of option to columns, say
    {"--truth-columns": [...], "--estimate-columns": [...]}), one array each, refusing a column
    given in two places (`distinct_roles`)."""
    table = path if isinstance(path, Table) else read_table(path, header=header)
    roles = [
        (f"{option} {k + 1}", column_name(table.frame, column))
        for option, columns in groups.items()
        for k, column in enumerate(columns)
    ]
    distinct_roles((), roles)
    return [read_columns(table, columns) for columns in groups.values()]
