"""Logs larger than memory: the field columns of a log streamed, chunk by chunk, into a
memory-mapped temporary file (`read_log(..., low_memory=True)`, `nlpcal calibrate --low-memory`).
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import InputError
from .layout import BROKEN_STREAM, STDIN, Layout
from .rows import RowScreen
from .tables import column_name, file_shares, log_files, numeric_columns, unreadable


@dataclass
class MappedColumns:
    """Numeric columns of a log streamed into a memory-mapped temporary file.

    values : (N, k) float64, backed by an unlinked temporary file (freed when dropped).
    columns : the k column names.
    dropped : rows dropped as invalid (missing values, zero vectors, repeats with drop_invalid).
    notes : what was left out and why, for the user to read.
    layout : the layout of the file.
    """

    values: np.ndarray
    columns: list
    dropped: int
    notes: list
    layout: Layout
    source: str = ""


def spool_stdin(directory=None):
    """Standard input copied into a temporary file, so that it can be read in chunks."""
    spool = tempfile.NamedTemporaryFile(dir=directory, suffix=".log")
    shutil.copyfileobj(sys.stdin.buffer, spool)
    spool.flush()
    return spool


def csv_to_memmap(
    path,
    columns=None,
    extra_columns=(),
    *,
    header: bool | None = None,
    drop_invalid: bool = False,
    scale=1.0,
    chunk_rows: int = 250_000,
    directory=None,
    progress=None,
) -> MappedColumns:
    """Stream the field columns (and `extra_columns`) of a log into a memory-mapped array.

    Memory stays O(chunk_rows) whatever the size of the log; the pandas C engine reads the chunks
    (pyarrow those of a Parquet file; the files of a pattern or folder one after another).
    The three field columns come first and are multiplied by `scale` (a unit conversion) on the
    way (`scale` a number, or a function of the three column names); the extra columns are kept
    as they are. Rows are screened as in `read_log`: zero vectors
    left out, repeated vectors counted (dropped with drop_invalid). `progress`
    (`nlpcal.io.progress.Progress`) is told how many bytes of the files were read.
    """
    spool = spool_stdin(directory) if str(path) == "-" else None
    try:
        notes: list = []
        files = log_files(spool.name if spool else path, header, STDIN if spool else None, notes)
        first = files[0]
        chosen = first.field_columns(columns, notes)
        wanted = chosen + [column_name(first.preview, c) for c in extra_columns]
        factor = float(scale(chosen) if callable(scale) else scale)
        factors = np.array([factor] * 3 + [1.0] * (len(wanted) - 3))
        screen = RowScreen(drop_repeats=drop_invalid)
        store = tempfile.TemporaryFile(dir=directory)
        rows = dropped = missing = 0
        part = first
        try:
            for part, read in file_shares(files, progress):
                before = 0  # data rows of this file in the chunks before
                for chunk in part.chunks(wanted, chunk_rows, read=read):
                    numeric = numeric_columns(
                        chunk,
                        wanted,
                        drop_invalid=drop_invalid,
                        source=part.name,
                        decimal=part.layout.decimal,
                        first_row=before,
                    )
                    before += len(chunk)
                    data_rows = rows + dropped + np.flatnonzero(numeric.kept) + 1
                    keep = screen.keep(numeric.values[:, :3], data_rows)
                    dropped += numeric.dropped + int((~keep).sum())
                    missing += numeric.dropped
                    values = numeric.values[keep]
                    rows += values.shape[0]
                    store.write(np.ascontiguousarray(values * factors).tobytes())
        except InputError:
            store.close()
            raise
        except (pd.errors.ParserError, UnicodeDecodeError, ValueError, *BROKEN_STREAM) as exc:
            store.close()
            raise unreadable(part.name, part.layout, exc) from None
    finally:
        if spool is not None:
            spool.close()
    store.flush()
    name = STDIN if spool else str(path)
    if rows == 0:
        store.close()
        raise InputError(f"{name}: no data rows")
    if missing:  # as `nlpcal.io.logs.screened` says it
        notes.append(f"dropped {missing} row(s) with missing or non-numeric values")
    mapped = np.memmap(store, dtype=np.float64, mode="r", shape=(rows, len(wanted)))
    return MappedColumns(
        values=mapped,
        columns=wanted,
        dropped=dropped,
        notes=notes + screen.notes(),
        layout=first.layout,
        source=name if len(files) > 1 or first.parquet else first.name,
    )
