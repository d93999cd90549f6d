"""Tables written by nlpcal: the output's extension decides the container, the data the digits.

Every command that writes a table (a corrected log, attitudes, a simulated log) writes it here.
An output named `*.parquet` (or .parq, .pq) is a Parquet file; any other output, stdout
included, is delimited text in the layout of the log it came from (delimiter, decimal mark,
header row, comment lines). Text values carry the precision the data warrant (`Precision`): by
default one significant digit more than the input's numbers carry, every digit of a float64
from Parquet input (its shortest round-trip form), or the digits asked for.

A table may be written in chunks (`write_frames` takes any iterable of frames, a generator
that reads and corrects a log as it goes included); the output is still put in place whole
or not at all (`nlpcal.io.files.Outputs`). Every chunk passes `nlpcal.io.strict.finite_table`
first: nothing written holds NaN or Infinity.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError
from .files import PARQUET_SUFFIXES, Outputs, output_target
from .layout import Layout
from .sources import pyarrow_parquet
from .strict import finite_table
from .tables import csv_engine

#: Significant digits of a float64: enough to read every value back exactly. [1]
FLOAT64_DIGITS = 17
#: What a text cell holds besides its significant digits: sign, decimal mark, exponent.
#: (Spelled without \\s and \\d, which pandas hands to Python's re rather than to pyarrow.)
NOT_SIGNIFICANT = r"[eE][+-]?[0-9]+[ \t]*$|[ \t+.,-]"


def is_parquet_output(path) -> bool:
    """Whether an output path is written as Parquet: by its extension alone (stdout is text)."""
    return bool(path) and str(path) != "-" and Path(str(path)).suffix.lower() in PARQUET_SUFFIXES


def significant_digits(cells: pd.Series, at_least: int = 0) -> int:
    """The most significant digits a column of text numbers carries ("-0.00120" carries 3,
    "1.50e3" 3, "1200" 4), or `at_least` when no cell carries more (only cells with more than
    `at_least` digits in all are looked at closely)."""
    text = cells if pd.api.types.is_string_dtype(cells) else cells.astype(str)
    text = text[text.str.count("[0-9]") > at_least]
    if not len(text):
        return at_least
    digits = text.str.replace(NOT_SIGNIFICANT, "", regex=True).str.lstrip("0").str.len()
    return max(at_least, int(digits.max()))


def rounded(values: np.ndarray, digits: int) -> np.ndarray:
    """`values` rounded to `digits` significant digits, each to the float64 nearest the
    rounded decimal, whose shortest form (repr) then has at most `digits` digits."""
    values = np.asarray(values, dtype=float)
    out = values.copy()
    rounding = np.isfinite(values) & (values != 0.0)
    x = values[rounding]
    decimals = digits - 1 - np.floor(np.log10(np.abs(x)))
    scale = 10.0 ** np.abs(decimals)  # exact up to 10^22
    up = decimals >= 0  # an integer x * 10^d over 10^d, or x / 10^-d times 10^-d
    x[up] = np.round(x[up] * scale[up]) / scale[up]
    x[~up] = np.round(x[~up] / scale[~up]) * scale[~up]
    out[rounding] = x
    return out


class Precision:
    """The significant digits of the numbers nlpcal writes into a text table.

    digits : the digits asked for (--precision N), or None for the default: one more than the
        input's numbers carry (`observe`), or every digit of a float64 for numbers that were
        never text (Parquet input: `exact`).
    """

    def __init__(self, digits: int | None = None):
        if digits is not None and not 1 <= int(digits) <= FLOAT64_DIGITS:
            raise InputError(f"--precision {digits}: expected 1 to {FLOAT64_DIGITS} digits")
        self.digits = None if digits is None else int(digits)
        self.seen = 0  # the most digits an input number carried so far
        self.exact = False

    def observe(self, columns) -> None:
        """The input's numbers read so far include `columns` (text Series, or numbers: then
        nothing limits the digits but float64's own)."""
        for column in columns:
            if column.dtype.kind == "O" or pd.api.types.is_string_dtype(column):
                self.seen = significant_digits(column, self.seen)
            else:
                self.exact = True

    @property
    def significant(self) -> int | None:
        """The significant digits of the numbers written now; None for the shortest form that
        reads back exactly (every digit of a float64)."""
        if self.digits is not None:
            return self.digits
        if self.exact or self.seen == 0:
            return None
        return min(self.seen + 1, FLOAT64_DIGITS)


def check_table_output(path) -> None:
    """Fail before any work when a Parquet output would go to a terminal (binary on a screen)."""
    if not is_parquet_output(path):
        return
    target = output_target(path)
    terminal = False
    if target.kind == "descriptor":
        terminal = os.isatty(target.fd)
    elif target.kind == "through" and stat.S_ISCHR(os.stat(target.path).st_mode):
        fd = os.open(target.path, os.O_WRONLY | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            terminal = os.isatty(fd)
        finally:
            os.close(fd)
    if terminal:
        raise InputError(
            f"{path}: is a terminal; a Parquet file is binary, so write it to a file or a pipe"
        )


def _quoted(cells, delimiter: str):
    """Text cells as a CSV writer quotes them: those holding the delimiter, a quote or a line
    break in double quotes, their quotes doubled (whitespace delimits a whitespace layout)."""
    import pyarrow.compute as pc

    special = r'[\s"]' if delimiter == " " else f'[{re.escape(delimiter)}"\r\n]'
    needs = pc.match_substring_regex(cells, special)
    if not pc.any(needs).as_py():
        return cells
    quoted = pc.binary_join_element_wise('"', pc.replace_substring(cells, '"', '""'), '"', "")
    return pc.if_else(needs, quoted, cells)


def _cells(column: pd.Series, layout: Layout):
    """A column as the text cells of its rows (a pyarrow string array), as pandas' `to_csv`
    writes them: numbers in their shortest form with the layout's decimal mark, flags as
    True/False, text as it was read (quoted where it must be), missing values empty."""
    import pyarrow
    import pyarrow.compute as pc

    kind = column.dtype.kind
    if kind == "f":
        values = column.to_numpy(dtype=float)
        cells = pyarrow.array(values, from_pandas=True).cast(pyarrow.string())
        if layout.decimal != ".":
            cells = pc.replace_substring(cells, ".", layout.decimal)
    elif kind == "b":
        cells = pc.if_else(pyarrow.array(column.to_numpy()), "True", "False")
    elif kind in "iu":
        cells = pyarrow.array(column.to_numpy()).cast(pyarrow.string())
    else:
        text = column.astype(str).where(column.notna(), "")
        cells = _quoted(pyarrow.array(text, type=pyarrow.string()), layout.delimiter)
    return pc.fill_null(cells, "")


def _text_chunk(handle, frame: pd.DataFrame, layout: Layout, first: bool, digits) -> None:
    """One chunk of a text table: the comment lines and the header row first (`first`), then
    one line per row, the numbers nlpcal computed `rounded` to `digits` (None: every digit) and
    written in their shortest form. With pyarrow the cells are made by its compute functions,
    an order of magnitude faster than pandas' `to_csv` on floats; without it by `to_csv`, to
    the same numbers (pandas writes a whole float as "12.0", pyarrow as "12")."""
    if first:
        handle.write("".join(line + layout.newline for line in layout.preamble))
    if digits is not None:
        floats = [name for name in frame.columns if frame[name].dtype.kind == "f"]
        frame = frame.assign(**{name: rounded(frame[name], digits) for name in floats})
    if csv_engine() == "pyarrow":
        _arrow_lines(handle, frame, layout, first)
        return
    frame.to_csv(
        handle,
        sep=layout.delimiter,
        header=layout.header and first,
        index=False,
        decimal=layout.decimal,
        lineterminator=layout.newline,
    )


def _arrow_lines(handle, frame: pd.DataFrame, layout: Layout, first: bool) -> None:
    """`_text_chunk`'s lines made with pyarrow."""
    import pyarrow.compute as pc

    newline = layout.newline
    if first and layout.header:
        names = pd.Series([str(c) for c in frame.columns])
        handle.write(layout.delimiter.join(_cells(names, layout).to_pylist()) + newline)
    if not len(frame):
        return
    cells = [_cells(frame[name], layout) for name in frame.columns]
    lines = pc.binary_join_element_wise(*cells, layout.delimiter) if len(cells) > 1 else cells[0]
    handle.write(newline.join(lines.to_pylist()) + newline)


class _ParquetSchema:
    """The column types of a Parquet output, fixed by its first chunk: numbers stay numbers;
    text cells (a text log's other columns) become integers or floats when every cell of the
    first chunk reads as one, else stay text. A later chunk that does not fit is InputError."""

    def __init__(self, frame: pd.DataFrame):
        self.types = {name: self._type(frame[name]) for name in frame.columns}

    @staticmethod
    def _type(column: pd.Series) -> str:
        if column.dtype.kind in "biuf":
            return column.dtype.name
        text = column.astype(str).str.strip()
        if len(text) and text.str.fullmatch(r"[+-]?\d{1,18}").all():
            return "int64"
        if len(text) and pd.to_numeric(text, errors="coerce").notna().all():
            return "float64"
        return "string"

    def cast(self, frame: pd.DataFrame) -> pd.DataFrame:
        columns = {}
        for name, kind in self.types.items():
            column = frame[name]
            if kind == "string":
                columns[name] = column.astype(str)
            elif column.dtype.name == kind:
                columns[name] = column
            else:
                values = pd.to_numeric(column.astype(str).str.strip(), errors="coerce")
                if values.isna().any() or (kind == "int64" and (values % 1 != 0).any()):
                    raise InputError(
                        f"column {name!s} holds {kind} values in the first rows and other "
                        f"values further down; a Parquet column has one type, so write a text "
                        f"output instead"
                    )
                columns[name] = values.astype(kind)
        return pd.DataFrame(columns, index=frame.index)


def _write_parquet(handle, frames) -> int:
    parquet = pyarrow_parquet()
    import pyarrow

    writer = schema = None
    rows = 0
    try:
        for frame in frames:
            if schema is None:
                schema = _ParquetSchema(frame)
            table = pyarrow.Table.from_pandas(schema.cast(frame), preserve_index=False)
            if writer is None:
                writer = parquet.ParquetWriter(handle, table.schema)
            writer.write_table(table)
            rows += len(frame)
    finally:
        if writer is not None:
            writer.close()
    if writer is None:
        raise InputError("no rows to write")
    return rows


def write_frames(
    outputs: Outputs,
    path,
    frames,
    layout: Layout | None = None,
    precision: Precision | None = None,
    what: str = "the output",
    missing: bool = False,
) -> None:
    """The table of `frames` (an iterable of DataFrames with the same columns, read as it is
    written) as one output of `outputs` at `path`: Parquet by the extension, else text in
    `layout` (default: comma-separated with a header row) with the numbers at `precision`
    (default: every digit); with `missing`, NaN is a missing value (an empty cell, a Parquet
    null), not a number nlpcal computed (`nlpcal.io.strict.finite_table`)."""
    layout = layout or Layout()
    precision = precision or Precision()
    finite = (finite_table(frame, what, missing=missing) for frame in frames)
    if is_parquet_output(path):
        check_table_output(path)
        outputs.write(path, lambda handle: _write_parquet(handle, finite), binary=True)
        return

    def write(handle) -> None:
        first = True
        for frame in finite:
            _text_chunk(handle, frame, layout, first, precision.significant)
            first = False

    outputs.write(path, write)


def write_table(
    frame: pd.DataFrame, layout: Layout | None = None, output=None, precision=None
) -> None:
    """One table to `output` (stdout for None or "-"), Parquet or text by its extension
    (`write_frames`)."""
    with Outputs() as outputs:
        write_frames(outputs, output, [frame], layout, precision)


def aligned(
    frame: pd.DataFrame,
    columns: list,
    values: np.ndarray,
    valid: np.ndarray,
    total_column: str,
    valid_column: str | None,
    extra: dict | None = None,
) -> pd.DataFrame:
    """Rows of a log written back: the field `columns` replaced by `values` (in the log's unit;
    raw values on the rows that are not readings), their magnitude in `total_column`, the
    `valid` flags as 1/0 in `valid_column` (None leaves it out) and the `extra` columns, all
    appended last; every other column as it was read."""
    frame = frame.copy()
    for k, column in enumerate(columns):
        frame[column] = values[:, k]
    appended = [total_column, *([valid_column] if valid_column else []), *(extra or {})]
    frame = frame.drop(columns=[c for c in appended if c in frame.columns])
    frame[total_column] = np.sqrt(np.einsum("ij,ij->i", values, values))
    if valid_column:
        frame[valid_column] = np.asarray(valid, dtype=np.int8)
    for name, column in (extra or {}).items():
        frame[name] = column
    return frame
