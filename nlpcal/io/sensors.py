"""`read_sensor_log`: a magnetometer and an accelerometer in one housing (an e-compass log).

Read like every log (`nlpcal.io.logs`): any delimited text, columns by name or 0-based position,
each sensor's unit given, else from its column names, else a fallback, and checked against
Earth's field and gravity; rows that are not readings screened.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .. import units, validation
from ..errors import InputError
from .layout import Layout
from .logs import screened, sensor_unit, unit_check
from .recorders import declared_unit
from .tables import Table, read_table, resolve_columns


@dataclass
class SensorLog:
    """A log of a magnetometer and an accelerometer in one housing (an e-compass).

    mag : (N, 3) field in nT; acc : (N, 3) specific force in g, on the same rows.
    frame, kept : the table and the rows behind the samples; notes, warnings, layout : as in
    `Log`. reference_field : a known field magnitude, or None. [nT]
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
    warnings: list = field(default_factory=list)
    layout: Layout = field(default_factory=Layout)
    reference_field: float | None = None

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
            "layout": self.layout.to_dict(),
            "rows_skipped": int(self.dropped),
            **more,
        }


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
    header: bool | None = None,
    text: bool = False,
    reference_field=None,
    reference_field_unit: str | None = None,
) -> SensorLog:
    """Read a magnetometer + accelerometer log; the field in nT, the specific force in g.

    Columns are detected unless given (names or 0-based positions); each sensor's unit is the one
    given, else the one its column names carry, else the fallback (nT and g, or the units of a
    calibration), and both are checked against Earth's field and gravity. reference_field : a
    known field magnitude in `reference_field_unit` (default: the magnetometer's unit).
    """
    table = path if isinstance(path, Table) else read_table(path, header=header, text=text)
    frame = table.frame
    mag_cols, acc_cols = _sensor_columns(table, mag_columns, acc_columns)
    notes: list = list(table.notes)
    fixed = table.field_unit if table.field_columns in (None, mag_cols) else None
    mag_unit, mag_how = sensor_unit(
        mag_cols,
        mag_unit,
        mag_fallback,
        notes,
        flag="--mag-unit",
        declared=fixed or declared_unit(mag_cols, notes),
    )
    acc_unit, acc_how = sensor_unit(
        acc_cols, acc_unit, acc_fallback, notes, "accelerometer", "--acc-unit"
    )
    if mag_unit == "raw":
        raise InputError(
            "the e-compass needs the magnetometer in a field unit (nT, uT, ...), "
            "not raw counts; pass --mag-unit"
        )
    values, kept, dropped = screened(table, mag_cols + acc_cols, drop_invalid, notes)
    mag = values[:, :3] * units.field_factor(mag_unit)
    acc = values[:, 3:] * units.acc_factor(acc_unit)
    checks = [
        unit_check(mag, mag_unit, mag_how, "magnetometer", "--mag-unit", raw_allowed=False),
        unit_check(acc, acc_unit, acc_how, "accelerometer", "--acc-unit"),
    ]
    reference = None
    if reference_field is not None:
        reference = units.to_base(
            validation.number(reference_field, "the reference field", positive=True),
            reference_field_unit or mag_unit,
        )
    return SensorLog(
        path=table.source,
        frame=frame,
        kept=kept,
        mag=mag,
        acc=acc,
        mag_columns=mag_cols,
        acc_columns=acc_cols,
        mag_unit=mag_unit,
        acc_unit=acc_unit,
        dropped=dropped,
        notes=notes,
        warnings=[w for w in checks if w is not None],
        layout=table.layout,
        reference_field=reference,
    )


def _sensor_columns(table: Table, mag_columns, acc_columns) -> tuple:
    """The magnetometer's and the accelerometer's three columns (names) of `table`: given, or
    the table's field columns for the magnetometer; InputError without a header row unless
    both are given by position, or when they overlap."""
    if not table.layout.header and not (mag_columns and acc_columns):
        raise InputError(
            f"{table.source} has no header row; pass --mag-columns and --acc-columns with "
            f"0-based positions, for example --mag-columns 3 4 5 --acc-columns 0 1 2"
        )
    mag_cols = resolve_columns(table.frame, mag_columns or table.field_columns, what="magnetometer")
    acc_cols = resolve_columns(table.frame, acc_columns, what="accelerometer")
    if set(mag_cols) & set(acc_cols):
        raise InputError(
            f"the magnetometer columns ({', '.join(mag_cols)}) and accelerometer "
            f"columns ({', '.join(acc_cols)}) overlap; pass --mag-columns and "
            f"--acc-columns"
        )
    return mag_cols, acc_cols
