"""Tables: reading a CSV log, choosing its columns and taking numbers from them.

Every problem with a table raises `InputError` with one sentence that says what was received and
how to fix it.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import units
from ..errors import InputError
from . import sources
from .files import existing_file

#: What each sensor's axis columns may be called, for `resolve_columns`:
#: name -> (prefixes, unit suffixes, examples for messages, flag for messages).
SENSORS = {
    "magnetometer": (
        units.MAGNETIC_PREFIXES,
        units.FIELD_SUFFIXES,
        "bx/by/bz, x/y/z, mag_x/mag_y/mag_z, mx_uT/...",
        "--columns X Y Z",
    ),
    "accelerometer": (
        units.ACC_PREFIXES,
        units.ACC_SUFFIXES,
        "ax/ay/az, acc_x/acc_y/acc_z, ax_g/...",
        "--acc-columns AX AY AZ",
    ),
}


def _one_line(error: Exception) -> str:
    """An exception's message on one line (pandas' tokenizer messages end in a newline)."""
    return " ".join(str(error).split())


def csv_engine() -> str:
    """The fastest pandas CSV engine available here: "pyarrow" when installed, else "c"."""
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        return "c"
    return "pyarrow"


def read_table(path) -> pd.DataFrame:
    """Read a CSV log with the fastest available pandas engine (a Parquet file, or the files of
    a glob pattern or a folder, through `nlpcal.io.sources`)."""
    # Hook: Parquet, patterns and folders are read by nlpcal.io.sources.
    if sources.is_pattern(path):
        paths = sources.log_paths(path)
        return sources.concatenated(paths, [read_table(p) for p in paths])
    if sources.is_parquet(path):
        return sources.read_parquet(path)
    path = existing_file(path)
    engine = csv_engine()
    try:
        frame = pd.read_csv(path, engine=engine)
    except pd.errors.EmptyDataError:
        raise InputError(f"{path}: the file is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        if engine != "c":  # pyarrow is stricter; let the C engine have a go before giving up
            try:
                frame = pd.read_csv(path, engine="c")
            except Exception as c_exc:  # the C engine says where, with the line number
                raise InputError(f"{path}: cannot be read as CSV ({_one_line(c_exc)})") from None
        else:
            raise InputError(f"{path}: cannot be read as CSV ({_one_line(exc)})") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    return frame


def resolve_columns(frame: pd.DataFrame, columns=None, what: str = "magnetometer") -> list:
    """The three axis columns of a sensor: the ones asked for, or the one recognised triple.

    what : "magnetometer" or "accelerometer" (`SENSORS`).
    Raises InputError listing the columns found when a column is missing or the choice is
    ambiguous.
    """
    prefixes, suffixes, examples, flag = SENSORS[what]
    found = list(frame.columns)
    if columns:
        columns = list(columns)
        if len(columns) != 3:
            raise InputError(f"got {len(columns)} {what} columns, expected 3; pass {flag}")
        resolved = [column_name(frame, name) for name in columns]
        if len(set(resolved)) != 3:
            raise InputError(
                f"the {what} columns {', '.join(resolved)} repeat a column; pass "
                f"three different columns ({flag})"
            )
        return resolved
    matches = [
        triple
        for template, triple in units.axis_templates(found).items()
        if units.is_axis_template(template, prefixes, suffixes)
    ]
    if len(matches) == 1:
        return list(matches[0])
    if not matches:
        raise InputError(
            f"no {what} columns recognised ({examples}); the log has columns: "
            f"{', '.join(found)}; pass {flag}"
        )
    options = "; ".join(" ".join(m) for m in matches)
    raise InputError(
        f"ambiguous {what} columns ({options}); the log has columns: "
        f"{', '.join(found)}; pass {flag}"
    )


def column_name(frame: pd.DataFrame, name: str) -> str:
    """The column called `name` (case-insensitively when no exact match), or InputError."""
    if name in frame.columns:
        return name
    lower = {str(c).lower(): c for c in frame.columns}
    if str(name).lower() in lower:
        return lower[str(name).lower()]
    raise InputError(
        f"column {name!r} not found; the log has columns: {', '.join(map(str, frame.columns))}"
    )


@dataclass
class NumericColumns:
    """Numeric columns taken from a table, with the rows that were dropped."""

    values: np.ndarray
    kept: np.ndarray  # boolean mask over the table's rows
    dropped: int


def numeric_columns(
    frame: pd.DataFrame, columns, *, drop_invalid: bool = False, source: str = "log"
) -> NumericColumns:
    """Take `columns` as a float array; non-numeric, empty or non-finite cells are errors.

    With drop_invalid, such rows are dropped instead and counted.
    """
    data = np.empty((len(frame), len(columns)))
    for k, name in enumerate(columns):
        column = frame[name]
        if not pd.api.types.is_numeric_dtype(column) or pd.api.types.is_bool_dtype(column):
            column = pd.to_numeric(column, errors="coerce")
        data[:, k] = column.to_numpy(dtype=float, na_value=np.nan)
    valid = np.asarray(np.isfinite(data).all(axis=1))
    bad = int((~valid).sum())
    if bad and not drop_invalid:
        first = int(np.flatnonzero(~valid)[0])
        raise InputError(
            f"{source}: {bad} row(s) have a missing, non-numeric or non-finite value in "
            f"{', '.join(columns)} (first at data row {first + 1}); fix them or pass "
            f"--drop-invalid"
        )
    return NumericColumns(values=data[valid], kept=valid, dropped=bad)


@dataclass
class MappedColumns:
    """Numeric columns of a CSV streamed into a memory-mapped temporary file.

    values : (N, k) float64, backed by an unlinked temporary file (freed when dropped).
    columns : the k column names.
    dropped : rows dropped as invalid.
    """

    values: np.ndarray
    columns: list
    dropped: int


def csv_to_memmap(
    path,
    columns=None,
    extra_columns=(),
    *,
    drop_invalid: bool = False,
    scale: float = 1.0,
    chunk_rows: int = 250_000,
    directory=None,
) -> MappedColumns:
    """Stream the field columns (and `extra_columns`) of a CSV into a memory-mapped array.

    Memory stays O(chunk_rows) whatever the size of the log; the pandas C engine reads the chunks
    (the pyarrow engine cannot read in chunks). The three field columns come first and are
    multiplied by `scale` (a unit conversion) on the way; the extra columns are kept as they are.
    """
    path = Path(path)
    header = read_table_header(path)
    chosen = resolve_columns(header, columns)
    wanted = chosen + [column_name(header, name) for name in extra_columns]
    factors = np.array([scale] * 3 + [1.0] * (len(wanted) - 3))
    store = tempfile.TemporaryFile(dir=directory)
    rows = dropped = 0
    try:
        # Hook: the chunks of CSV or Parquet files, one file or many (nlpcal.io.sources).
        for chunk in sources.chunks(path, chunk_rows):
            chunk.columns = [str(c).strip() for c in chunk.columns]
            numeric = numeric_columns(chunk, wanted, drop_invalid=drop_invalid, source=str(path))
            dropped += numeric.dropped
            rows += numeric.values.shape[0]
            store.write(np.ascontiguousarray(numeric.values * factors).tobytes())
    except InputError as exc:
        store.close()
        if "first at data row" in str(exc):
            raise InputError(f"{exc} (in the chunk after row {rows + dropped})") from None
        raise
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        store.close()
        raise InputError(f"{path}: cannot be read as CSV ({_one_line(exc)})") from None
    store.flush()
    if rows == 0:
        store.close()
        raise InputError(f"{path}: no data rows")
    values = np.memmap(store, dtype=np.float64, mode="r", shape=(rows, len(wanted)))
    return MappedColumns(values=values, columns=wanted, dropped=dropped)


def read_table_header(path) -> pd.DataFrame:
    """The column names of a CSV (an empty frame), with the checks of `read_table`."""
    # Hook: Parquet, patterns and folders through nlpcal.io.sources.
    if sources.is_pattern(path):
        paths = sources.log_paths(path)
        sources.same_columns(paths, lambda p: list(read_table_header(p).columns))
        return read_table_header(paths[0])
    if sources.is_parquet(path):
        return pd.DataFrame(columns=sources.parquet_columns(path))
    path = existing_file(path)
    try:
        frame = pd.read_csv(path, nrows=0)
    except pd.errors.EmptyDataError:
        raise InputError(f"{path}: the file is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{path}: cannot be read as CSV ({_one_line(exc)})") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    return frame
