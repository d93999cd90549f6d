"""Tables: reading a delimited text log, choosing its columns and taking numbers from them.

A log is read once into a `Table`: the cells, the layout it was found in (`nlpcal.io.layout`) and
where it came from. Columns are chosen by name (exact, then case-insensitive), by 0-based
position, or recognised from their names (bx/by/bz, mag_x/..., "Magnetometer X (uT)"); a file
without a header row with three columns, or with a leading time column and three more, needs no
--columns at all. Every problem with a table raises `InputError` with one sentence that says what
was received and how to fix it.
"""

from __future__ import annotations

import io
import os
import re
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from .. import units
from ..errors import InputError
from . import recorders, sources
from .layout import BROKEN_STREAM, Layout, detect_layout, open_source
from .observatory import Observatory

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
#: Rows looked at to recognise a leading time column in a file without a header row.
PREVIEW_ROWS = 1000


def csv_engine() -> str:
    """The fastest pandas CSV engine available here: "pyarrow" when installed, else "c"."""
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        return "c"
    return "pyarrow"


@dataclass
class Table:
    """A delimited text log as read.

    source : the path, or "stdin".
    frame : the cells; column names are the header's, or "0", "1", ... without a header row.
    layout : how the file is laid out (delimiter, header, decimal mark, comments).
    engine : the pandas engine that read it.
    text : whether the cells were kept as text (so that they can be written back unchanged).
    field_unit : the unit of the field columns when the file format fixes it (an ArduPilot
        DataFlash MAG message is in milligauss, a MotionCal count 0.1 uT: `nlpcal.io.recorders`),
        else None; `nlpcal.io.read_log` then records the unit with `unit_source` "format". (ROS
        CSV columns fix theirs by their names: `nlpcal.io.recorders.declared_unit`.)
    field_columns : the field columns the file format fixes (a MotionCal capture's mx, my, mz),
        else None: recognised from the names.
    observatory : the header of an observatory file (`nlpcal.io.observatory.Observatory`),
        else None.
    """

    source: str
    frame: pd.DataFrame
    layout: Layout
    engine: str = "c"
    text: bool = False
    notes: list = field(default_factory=list)
    field_unit: str | None = None
    field_columns: list | None = None
    observatory: Observatory | None = None

    @property
    def columns(self) -> list:
        return list(self.frame.columns)


def _message(exc: Exception) -> str:
    """The first line of a parser's message, printable characters only, at most 160 of them."""
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return "".join(ch for ch in first if ch.isprintable())[:160]


def _frame(name: str, source, layout: Layout, *, text: bool = False, **more) -> tuple:
    """(frame, engine) of a log in `layout`; column names as strings."""
    options = {**layout.pandas_options(), **more}
    if text:
        options.update(dtype=str, keep_default_na=False)
    engine = "c"
    plain = layout.header and layout.delimiter != " " and layout.decimal == "."
    if plain and not text and not layout.preamble and not more and csv_engine() == "pyarrow":
        try:
            arrow = {k: options[k] for k in ("sep", "header", "encoding", "compression")}
            frame = pd.read_csv(_readable(source), engine="pyarrow", **arrow)
            engine = "pyarrow"
        except Exception:  # comments or ragged lines further down: the C engine copes
            engine = "c"
    if engine == "c":
        try:
            frame = pd.read_csv(_readable(source), engine="c", **options)
        except pd.errors.EmptyDataError:
            raise InputError(f"{name}: the file is empty") from None
        except (pd.errors.ParserError, UnicodeDecodeError, ValueError, *BROKEN_STREAM) as exc:
            raise unreadable(name, layout, exc) from None
    return named(frame, layout), engine


_RAGGED = re.compile(r"Expected (\d+) fields in line (\d+), saw (\d+)")


def unreadable(name: str, layout: Layout, exc: Exception) -> InputError:
    """The one-sentence error of a text log that pandas' parser refuses."""
    ragged = _RAGGED.search(str(exc))
    if ragged:
        expected, line, saw = ragged.groups()
        return InputError(
            f"{name}: line {line} has {saw} fields where the lines before have {expected} "
            f"(read as a {layout.describe()} text log); fix or remove that line, since "
            f"--drop-invalid drops rows with missing or non-numeric values, not ragged lines"
        )
    return InputError(f"{name}: cannot be read as a {layout.describe()} text log ({_message(exc)})")


def named(frame: pd.DataFrame, layout: Layout) -> pd.DataFrame:
    """The columns of a frame read in `layout`: the header's names stripped, else 0, 1, ..."""
    if layout.header:  # stripped, a repeat numbered (pandas numbers only the exact repeats)
        frame.columns = sources.distinct_names(frame.columns)
    else:
        frame.columns = [str(k) for k in range(frame.shape[1])]
    return frame


def _readable(source):
    return io.BytesIO(source) if isinstance(source, (bytes, bytearray)) else source


def read_table(
    path,
    *,
    header: bool | None = None,
    text: bool = False,
    variable: str | None = None,
    instance: int | None = None,
) -> Table:
    """Read a log (a path, or "-" for stdin): delimited text whatever its layout, Parquet, or a
    recorded format (`nlpcal.io.recorders`: MotionCal, MATLAB .mat, ArduPilot DataFlash).

    header : force (True) or deny (False) a header row; None detects it.
    text : keep every cell as text, so that columns not used pass through unchanged when the
        table is written back (`nlpcal.io.output`).
    variable : the variable of a .mat file that holds the field (None: detected).
    instance : the compass of a DataFlash log, 0-based (None: the only one).
    """
    formats: dict = {"variable": variable, "instance": instance}
    # Hook: Parquet files, and the files of a glob pattern or a folder (nlpcal.io.sources).
    if sources.is_pattern(path):
        notes: list = []
        paths = sources.log_paths(path, notes)
        tables = [read_table(p, header=header, text=text, **formats) for p in paths]
        frame = sources.concatenated(paths, [table.frame for table in tables])
        return replace(tables[0], source=str(path), frame=frame, notes=notes)
    if sources.is_parquet(path):
        recorders.check_options(str(path), "parquet", **formats)
        frame = sources.read_parquet(path)
        if frame.empty:
            raise InputError(f"{path}: no data rows")
        return Table(source=str(path), frame=frame, layout=Layout(), engine="pyarrow")
    name, source = open_source(path)
    recorded = recorders.read_recorded(name, source, **formats)
    if recorded is not None:
        return Table(
            source=name,
            frame=recorded.frame,
            layout=Layout(),
            engine=recorded.engine,
            notes=recorded.notes,
            field_unit=recorded.field_unit,
            field_columns=recorded.field_columns,
            observatory=recorded.observatory,
        )
    layout = detect_layout(name, source, header)
    frame, engine = _frame(name, source, layout, text=text)
    if frame.empty:
        raise InputError(f"{name}: no data rows")
    return Table(source=name, frame=frame, layout=layout, engine=engine, text=text)


def _listing(frame: pd.DataFrame) -> str:
    names = [str(c) for c in frame.columns]
    if names == [str(k) for k in range(len(names))]:
        last = len(names) - 1
        return f"no header row, {len(names)} columns: give their 0-based positions 0 to {last}"
    shown = ", ".join(f"{k} {name}" for k, name in enumerate(names[:40]))
    more = f", ... ({len(names)} in all)" if len(names) > 40 else ""
    return f"columns (0-based position and name): {shown}{more}"


def column_name(frame: pd.DataFrame, name, what: str = "column") -> str:
    """The column called `name` (case-insensitively when no exact match), or at 0-based position
    `name`; InputError listing the columns otherwise (`what` names it in the message)."""
    key = str(name).strip()
    if key in frame.columns:
        return key
    lower = {str(c).lower(): c for c in frame.columns}
    if key.lower() in lower:
        return lower[key.lower()]
    if re.fullmatch(r"\d+", key):
        if int(key) < frame.shape[1]:
            return str(frame.columns[int(key)])
        raise InputError(
            f"{what} {key!r} is out of range: positions are 0-based, and the log has "
            f"{_listing(frame)}"
        )
    raise InputError(f"{what} {key!r} not found; the log has {_listing(frame)}")


def numbers(column: pd.Series, decimal: str = ".") -> np.ndarray:
    """A column as floats; cells that are not numbers become NaN."""
    if pd.api.types.is_numeric_dtype(column) and not pd.api.types.is_bool_dtype(column):
        return column.to_numpy(dtype=float, na_value=np.nan)
    parsed = _arrow_numbers(column, decimal)
    if parsed is not None:
        return parsed
    text = column.astype(str).str.strip()
    if decimal == ",":
        text = text.str.replace(",", ".", regex=False)
    return pd.to_numeric(text, errors="coerce").to_numpy(dtype=float, na_value=np.nan)


def _arrow_numbers(column: pd.Series, decimal: str) -> np.ndarray | None:
    """A column of text held by pyarrow as floats, parsed by pyarrow (ten times pandas' speed,
    to the nearest double too) when every cell is a plain number; None otherwise (a cell that
    is empty, padded or not a number), for pandas to parse cell by cell."""
    if not isinstance(column.array, pd.arrays.ArrowStringArray):
        return None
    import pyarrow
    import pyarrow.compute as pc

    cells = pyarrow.array(column.array)
    if decimal == ",":
        cells = pc.replace_substring(cells, ",", ".")
    try:
        return pc.cast(cells, pyarrow.float64()).to_numpy(zero_copy_only=False)
    except (pyarrow.ArrowInvalid, pyarrow.ArrowNotImplementedError):
        return None


def _is_time(values: np.ndarray) -> bool:
    finite = values[np.isfinite(values)]
    return finite.size > 2 and bool(np.all(np.diff(finite) > 0))


def _headerless_columns(frame: pd.DataFrame, what: str, decimal: str, notes) -> list:
    """The field columns of a file without a header row: all three, or the three after a leading
    time column; InputError for other shapes."""
    flag = SENSORS[what][3]
    preview = frame.head(PREVIEW_ROWS)
    used = [c for c in frame.columns if np.isfinite(numbers(preview[c], decimal)).any()]
    if what == "magnetometer" and len(used) == 3:
        return used
    if what == "magnetometer" and len(used) == 4 and _is_time(numbers(preview[used[0]], decimal)):
        notes.append(
            f"no header row: column {used[0]} increases on every row and is read as time; "
            f"the field columns are {' '.join(used[1:])} (0-based positions)"
        )
        return used[1:]
    example = " ".join(str(c) for c in used[-3:])  # the columns' own 0-based positions
    raise InputError(
        f"the log has no header row and {len(used)} numeric columns, so the {what} columns "
        f"cannot be told apart; pass {flag.split()[0]} with 0-based positions, for example "
        f"{flag.split()[0]} {example}"
    )


def resolve_columns(
    frame: pd.DataFrame,
    columns=None,
    what: str = "magnetometer",
    *,
    header: bool = True,
    decimal: str = ".",
    notes=None,
) -> list:
    """The three axis columns of a sensor: the ones asked for (names or 0-based positions), or
    the one recognised triple.

    what : "magnetometer" or "accelerometer" (`SENSORS`).
    header : False for a file without a header row: three columns, or a leading time column and
        three more, are taken as they are (with a note).
    Raises InputError listing the columns found when a column is missing or the choice is
    ambiguous.
    """
    prefixes, suffixes, examples, flag = SENSORS[what]
    notes = [] if notes is None else notes
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
    if not header:
        return _headerless_columns(frame, what, decimal, notes)
    matches = [
        triple
        for template, triple in units.axis_templates(list(frame.columns)).items()
        if units.is_axis_template(template, prefixes, suffixes)
    ]
    if len(matches) == 1:
        return list(matches[0])
    hint = f"pass {flag} (names or 0-based positions)"
    if not matches:
        raise InputError(
            f"no {what} columns recognised ({examples}); the log has {_listing(frame)}; {hint}"
        )
    options = "; ".join(" ".join(m) for m in matches)
    raise InputError(f"ambiguous {what} columns ({options}); the log has {_listing(frame)}; {hint}")


@dataclass
class NumericColumns:
    """Numeric columns taken from a table, with the rows that were dropped."""

    values: np.ndarray
    kept: np.ndarray  # boolean mask over the table's rows
    dropped: int


def numeric_columns(
    frame: pd.DataFrame,
    columns,
    *,
    drop_invalid: bool = False,
    source: str = "log",
    decimal: str = ".",
    first_row: int = 0,
) -> NumericColumns:
    """Take `columns` as a float array; non-numeric, empty or non-finite cells are errors.

    With drop_invalid, such rows are dropped instead and counted. `first_row`: the data rows of
    the source before the frame's first (for the row number in a message).
    """
    data = np.empty((len(frame), len(columns)))
    for k, name in enumerate(columns):
        data[:, k] = numbers(frame[name], decimal)
    valid = np.asarray(np.isfinite(data).all(axis=1))
    bad = int((~valid).sum())
    if bad and not drop_invalid:
        first = int(np.flatnonzero(~valid)[0])
        raise InputError(
            f"{source}: {bad} row(s) have a missing, non-numeric or non-finite value in "
            f"{', '.join(columns)} (first at data row {first_row + first + 1}); fix them or pass "
            f"--drop-invalid"
        )
    return NumericColumns(values=data[valid], kept=valid, dropped=bad)


@dataclass
class LogFile:
    """One file of a log, as its chunks are read: CSV (or other delimited text) or Parquet.

    name : for messages. source : what is read. layout : the text layout (the default one for
    Parquet). preview : the first rows (none for Parquet): the column names, or 0, 1, ... without
    a header row.
    """

    name: str
    source: object
    layout: Layout
    preview: pd.DataFrame
    parquet: bool = False

    def field_columns(self, columns, notes: list) -> list:
        """The three field columns of the file (`resolve_columns` on its first rows)."""
        return resolve_columns(
            self.preview,
            columns,
            header=self.layout.header,
            decimal=self.layout.decimal,
            notes=notes,
        )

    def chunks(self, wanted: list | None, chunk_rows: int, *, text: bool = False, read=None):
        """The `wanted` columns of the file (None: all of them), chunk after chunk, every column
        checked (ragged rows are errors). text : keep a text file's cells as text. read : a
        function called after each chunk with the share of the file read so far (0 to 1)."""
        if self.parquet:
            total = max(sum(sources.parquet_row_groups(self.source)), 1)
            done = 0
            for chunk in sources.parquet_chunks(self.source, chunk_rows, wanted):
                done += len(chunk)
                if read is not None:
                    read(done / total)
                yield chunk
            return
        columns = list(self.preview.columns)
        positions = sorted({columns.index(c) for c in wanted}) if wanted else None
        options = {**self.layout.pandas_options(), "chunksize": chunk_rows}
        if text:
            options.update(dtype=str, keep_default_na=False)
        size = _size(self.source)
        with _opened(self.source) as handle:
            for chunk in pd.read_csv(handle, engine="c", **options):
                if positions is None:
                    chunk.columns = columns
                else:
                    chunk = chunk.iloc[:, positions]
                    chunk.columns = [columns[k] for k in positions]
                if read is not None and size:
                    read(min(handle.tell() / size, 1.0))
                yield chunk


def file_shares(files: list, progress=None):
    """(file, read) for each of a log's files (`log_files`), `read(share)` telling `progress`
    (`nlpcal.io.progress.Progress`, or None) how many bytes of all the files were read once
    `share` of that file was."""
    sizes = [_size(part.source) for part in files]
    total, done = sum(sizes) or 1, 0
    for part, size in zip(files, sizes):

        def read(share, done=done, size=size):
            if progress is not None:
                progress.update(done + share * size, total)

        yield part, read
        done += size


def _size(source) -> int:
    """The bytes of a file (0 for bytes in memory: their share read is not followed)."""
    return 0 if isinstance(source, (bytes, bytearray)) else os.stat(source).st_size


def _opened(source):
    """A binary handle on a file's bytes (its position: how far a reader has got)."""
    if isinstance(source, (bytes, bytearray)):
        return io.BytesIO(source)
    return open(source, "rb")


def log_files(
    path, header: bool | None = None, name: str | None = None, notes: list | None = None
) -> list:
    """The files of a log (one file, a pattern or a folder: `nlpcal.io.sources`, which says in
    `notes` what it left out), each with its layout and first rows; they must have the same
    columns."""
    found = []
    for item in [path] if name else sources.log_paths(path, notes):
        if not name and sources.is_parquet(item):
            columns = sources.parquet_columns(item)
            found.append(LogFile(str(item), item, Layout(), pd.DataFrame(columns=columns), True))
            continue
        label, source = open_source(item)
        recorders.refuse_streaming(name or label, source)
        layout = detect_layout(name or label, source, header)
        preview, _ = _frame(name or label, source, layout, nrows=PREVIEW_ROWS)
        found.append(LogFile(name or label, source, layout, preview))
    sources.same_columns([(part.name, [str(c) for c in part.preview.columns]) for part in found])
    return found
