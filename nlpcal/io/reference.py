"""A reference read from another log with its own time base (`--reference-log`).

The reference log is read by the same reader as the log (`nlpcal.io.tables.read_table`: text,
Parquet, an observatory file ...); its column of values and its column of times are chosen by
name, and the values are interpolated onto the log's times (`nlpcal.timing.reference_at`). Rows
of the log outside the reference's span or inside one of its gaps are dropped and counted; the
reference's own rows without a time or a value are left out and counted.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .. import units, validation
from ..errors import InputError
from ..timing import check_kind, interpolate_reference, seconds
from .observatory import TIME_COLUMN
from .tables import column_name, numbers, read_table


@dataclass(frozen=True)
class ReferenceLog:
    """Where a reference with its own time base comes from.

    path : the reference log (`--reference-log`). column : its column of values
    (`--reference-column`). time_column : its column of times (`--reference-time-column`;
    None: `time` in an observatory file, else the log's time column's name). log_time_column :
    the log's column of times (`--time-column`; None: `time` in an observatory file).
    interpolation : "linear" or "cubic" (`--interpolation`).
    """

    path: str
    column: str
    time_column: str | None = None
    log_time_column: str | None = None
    interpolation: str = "linear"

    def __post_init__(self):
        check_kind(self.interpolation)


def log_times(log, column: str | None, why: str = "--reference-log") -> tuple:
    """(the log's time column, its times on the rows of the samples [s]): `column`, else an
    observatory file's `time`; InputError naming `why` (the option that needs them) when the
    log has none or was streamed."""
    if log.frame is None:
        raise InputError(f"{why} needs the log in memory; drop --low-memory")
    wanted = column or (TIME_COLUMN if log.observatory else None)
    if wanted is None:
        raise InputError(
            f"{why} needs the log's times: pass --time-column COL, the log's column of times "
            f"(ISO 8601 or seconds)"
        )
    column = column_name(log.frame, wanted, "time column")
    times = seconds(log.frame[column])[log.kept]
    bad = int(np.isnan(times).sum())
    if bad:
        raise InputError(
            f"{log.path}: {bad} row(s) have no time in {column!r} (ISO 8601 text or seconds); "
            f"fix them or drop them from the log"
        )
    return column, times


def _reference(spec: ReferenceLog, log_unit: str, default_time: str, notes: list) -> tuple:
    """(times [s], values [base unit], the record of the reference log) of a reference log."""
    table = read_table(spec.path)
    notes.extend(table.notes)
    name = column_name(table.frame, spec.column, "reference column")
    wanted = spec.time_column or (TIME_COLUMN if table.observatory else default_time)
    time_name = column_name(table.frame, wanted, "reference time column")
    times = seconds(table.frame[time_name])
    values = numbers(table.frame[name], table.layout.decimal)
    usable = np.isfinite(times) & np.isfinite(values)
    if (~usable).any():
        notes.append(
            f"{table.source}: left out {int((~usable).sum())} reference row(s) without a time "
            f"or a value"
        )
    declared = table.observatory.units.get(name) if table.observatory else None
    unit = declared or units.unit_in_name(name) or log_unit
    units.check_compatible(log_unit, unit, f"reference column {name!r}")
    record = {
        "file": table.source,
        "column": name,
        "time_column": time_name,
        "unit": unit,
        **({"observatory": table.observatory.to_dict()} if table.observatory else {}),
    }
    return times[usable], units.to_base(values[usable], unit), record


def with_reference_log(log, spec: ReferenceLog):
    """`log` (an `nlpcal.io.Log` read whole) with the reference of `spec` on its rows: rows
    outside the reference's span or in its gaps dropped and counted, the reference log's
    record in `log.reference_log`."""
    column, times = log_times(log, spec.log_time_column)
    notes: list = []
    times_ref, values_ref, record = _reference(spec, log.unit, column, notes)
    interpolated = interpolate_reference(times_ref, values_ref, times, spec.interpolation)
    keep = np.isfinite(interpolated.values)
    if not keep.any():
        raise InputError(
            f"no row of {log.path} lies within the span of the reference log {spec.path} "
            f"(log times {times.min():.3f} .. {times.max():.3f} s, reference "
            f"{times_ref.min():.3f} .. {times_ref.max():.3f} s; both absolute, or both seconds "
            f"since the same origin)"
        )
    notes.extend(interpolated.notes(f"the reference {record['column']!r} of {record['file']}"))
    kept = log.kept.copy()
    kept[np.flatnonzero(log.kept)[~keep]] = False
    return replace(
        log,
        samples=log.samples[keep],
        extras={name: values[keep] for name, values in log.extras.items()},
        kept=kept,
        dropped=log.dropped + int((~keep).sum()),
        reference=validation.reference(
            interpolated.values[keep], int(keep.sum()), f"the reference column {record['column']!r}"
        ),
        reference_column=record["column"],
        notes=[*log.notes, *notes],
        reference_log={**record, "log_time_column": column, **interpolated.to_dict()},
        times=times[keep],
    )
