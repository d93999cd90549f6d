"""A log read chunk after chunk, every row kept in its place: what `nlpcal apply` streams.

`LogStream` reads a log (one file, a pattern or a folder, CSV or Parquet, `-` for stdin) in
chunks of `CHUNK_ROWS` rows, so that memory stays O(chunk) whatever the log's size, and hands
out each chunk's rows of numbers with every column as read (text cells of a text log stay text,
to be written back unchanged), the field vectors in the log's unit, and whether each row is a
reading (`nlpcal.io.rows`: exact-zero vectors, and with drop_invalid repeated vectors, are
not). Rows with a missing or non-numeric value are errors, or with drop_invalid dropped,
counted and their data row numbers kept for the message.

A log in a recorded format (`nlpcal.io.recorders`: a MotionCal capture, a MATLAB .mat file, an
ArduPilot DataFlash log, or a pattern holding one) is read whole (`nlpcal.io.read_table`) and
handed out as one chunk, its field columns and unit those the format fixes.

The columns are resolved as `nlpcal.io.read_log` resolves them, and the field unit decided from
the first chunk (`nlpcal.io.logs.settle_unit` on its readings).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import units
from ..errors import InputError
from ..validation import not_too_large
from .layout import BROKEN_STREAM, STDIN, Layout
from .logs import distinct_roles, format_unit, sensor_unit, settle_unit
from .mapped import spool_stdin
from .recorders import check_options, is_recorded
from .rows import QUOTED_ROWS, RowScreen, quoted_rows
from .tables import (
    Table,
    column_name,
    file_shares,
    log_files,
    numeric_columns,
    read_table,
    resolve_columns,
    unreadable,
)

#: Rows read at a time: about 60 MB of text cells for a log of ten columns.
CHUNK_ROWS = 100_000


@dataclass
class LogChunk:
    """One chunk of a log: its rows of numbers, in the order of the file.

    frame : every column as read (text cells for a text log).
    raw : (n, 3) field vectors in the log's unit. [log unit]
    valid : (n,) whether each row is a reading (not a zero vector, nor a repeat dropped).
    extras : the extra columns on these rows, as numbers.
    """

    frame: pd.DataFrame
    raw: np.ndarray
    valid: np.ndarray
    extras: dict


class LogStream:
    """A log read in chunks; use it in a `with` block (stdin is spooled to a temporary file).

    After `open`: `columns` (the three field columns), `extra` (the extra columns' names),
    `unit` and `unit_source`, `layout`, `parquet` (whether the log is Parquet), `notes` and
    `warnings`. While and after iterating: `rows` (rows of numbers handed out), `readings`,
    `dropped` (rows with missing values left out), `dropped_rows` (their data row numbers, the
    first QUOTED_ROWS).

    header, variable, instance : as `nlpcal.io.read_table` takes them (`--header`,
        `--variable`, `--instance`).
    chunk_rows : rows read at a time (default CHUNK_ROWS).
    progress : an object with `update(done, total)` (`nlpcal.io.progress.Progress`) told how
        many bytes of the log's files were read, of how many.
    """

    def __init__(
        self,
        path,
        *,
        header: bool | None = None,
        variable: str | None = None,
        instance: int | None = None,
        progress=None,
        chunk_rows=None,
    ):
        self.path, self.header, self.progress = path, header, progress
        self.variable, self.instance = variable, instance
        self.table: Table | None = None  # a recorded format's, read whole
        self.chunk_rows = int(chunk_rows or CHUNK_ROWS)
        self._spool = None
        self.notes: list = []
        self.warnings: list = []
        self.rows = self.readings = self.dropped = 0
        self.dropped_rows: list = []
        self._pending: list = []

    def __enter__(self) -> LogStream:
        if str(self.path) == "-":
            self._spool = spool_stdin()
        readable = self.readable
        if is_recorded(readable):
            table = read_table(
                readable,
                header=self.header,
                text=True,
                variable=self.variable,
                instance=self.instance,
            )
            self.table = table
            self.notes += table.notes
            self.layout: Layout = table.layout
            self.parquet = False
            self.source = STDIN if self._spool else table.source
            return self
        check_options(str(self.path), None, variable=self.variable, instance=self.instance)
        name = STDIN if self._spool else None
        self.files = log_files(readable, self.header, name, self.notes)
        first = self.files[0]
        self.layout = first.layout
        self.parquet = any(part.parquet for part in self.files)
        self.source = (
            STDIN
            if self._spool
            else (str(self.path) if len(self.files) > 1 or first.parquet else first.name)
        )
        return self

    @property
    def observatory(self):
        """The header of an observatory file (read whole), else None (`nlpcal.io.observatory`)."""
        return self.table.observatory if self.table is not None else None

    def __exit__(self, *exc) -> None:
        if self._spool is not None:
            self._spool.close()
            self._spool = None

    @property
    def readable(self) -> str:
        """What `nlpcal.io.read_log` reads the same log from (stdin's copy, for stdin)."""
        return self._spool.name if self._spool else str(self.path)

    @property
    def table_columns(self) -> list:
        """Every column of the log, as named in its first file."""
        if self.table is not None:
            return [str(c) for c in self.table.columns]
        return [str(c) for c in self.files[0].preview.columns]

    def open(
        self,
        columns=None,
        *,
        unit: str | None = None,
        fallback_unit: str = "nT",
        extra_columns=None,
        drop_invalid: bool = False,
    ) -> LogStream:
        """Resolve the field columns and `extra_columns` (role -> column), read the first
        chunk and decide the field unit from it."""
        if self.table is not None:
            table, head = self.table, self.table.frame
            self.columns = resolve_columns(
                head,
                columns or table.field_columns,
                header=table.layout.header,
                decimal=table.layout.decimal,
                notes=self.notes,
            )
        else:
            head = self.files[0].preview
            self.columns = self.files[0].field_columns(columns, self.notes)
        roles = [(role, column_name(head, c)) for role, c in (extra_columns or {}).items()]
        distinct_roles(self.columns, roles)
        self.extra = list(dict.fromkeys(name for _, name in roles))
        self.drop_invalid = drop_invalid
        self._screen = RowScreen(drop_repeats=drop_invalid)
        self._chunks = self._read()
        self._pending = [next(self._chunks, None)]
        if self._pending[0] is None:
            raise InputError(f"{self.source}: no data rows")
        declared = format_unit(self.columns, self.notes, self.table)
        unit, self.unit_source = sensor_unit(
            self.columns, unit, fallback_unit, self.notes, declared=declared
        )
        first = self._pending[0]
        samples = first.raw[first.valid] * units.field_factor(unit)
        _, self.unit, check = settle_unit(samples, unit, self.unit_source)
        self.warnings += [check] if check else []
        return self

    @property
    def factor(self) -> float:
        """What turns the log's unit into its base unit (nT, or 1 for raw counts)."""
        return units.field_factor(self.unit)

    @property
    def base_unit(self) -> str:
        return units.base_unit(self.unit)

    def __iter__(self):
        while self._pending:
            yield self._pending.pop()
            chunk = next(self._chunks, None)
            if chunk is not None:
                self._pending.append(chunk)

    def _read(self):
        wanted = self.columns + self.extra
        if self.table is not None:  # read whole: one chunk
            yield self._chunk(self.table.frame, wanted, self.source, ".", 0)
            return
        for part, read in file_shares(self.files, self.progress):
            before = 0  # data rows of this file in the chunks before
            try:
                for chunk in part.chunks(None, self.chunk_rows, text=True, read=read):
                    yield self._chunk(chunk, wanted, part.name, part.layout.decimal, before)
                    before += len(chunk)
            except InputError:
                raise
            except (pd.errors.ParserError, UnicodeDecodeError, ValueError, *BROKEN_STREAM) as exc:
                raise unreadable(part.name, part.layout, exc) from None

    def _chunk(
        self, chunk: pd.DataFrame, wanted: list, name: str, decimal: str, before: int
    ) -> LogChunk:
        numeric = numeric_columns(
            chunk,
            wanted,
            drop_invalid=self.drop_invalid,
            source=name,
            decimal=decimal,
            first_row=before,
        )
        data_rows = self.rows + self.dropped + np.arange(1, len(chunk) + 1)
        if numeric.dropped:
            room = QUOTED_ROWS - len(self.dropped_rows)
            self.dropped_rows += [int(r) for r in data_rows[~numeric.kept][: max(room, 0)]]
            self.dropped += numeric.dropped
            chunk = chunk.loc[numeric.kept]
        valid = self._screen.keep(numeric.values[:, :3], data_rows[numeric.kept])
        if valid.any():
            not_too_large(float(np.abs(numeric.values[:, :3][valid]).max()))
        self.rows += len(chunk)
        self.readings += int(valid.sum())
        extras = {name: numeric.values[:, 3 + k] for k, name in enumerate(self.extra)}
        return LogChunk(frame=chunk, raw=numeric.values[:, :3], valid=valid, extras=extras)

    def summary(self) -> list:
        """What was left out or marked, one sentence each, once the log is read."""
        notes = list(self._screen.notes(kept=True))
        if self.dropped:
            where = quoted_rows(self.dropped, self.dropped_rows)
            notes.append(
                f"dropped {self.dropped} row(s) with missing or non-numeric values "
                f"(--drop-invalid; data row {where})"
            )
        return notes
