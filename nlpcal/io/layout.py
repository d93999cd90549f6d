"""How a delimited text log is laid out: delimiter, header row, decimal mark, comments, encoding.

Logs come from every kind of logger: comma-, semicolon-, tab- or whitespace-separated, with or
without a header row, with `#` comment lines, sometimes with a decimal comma, sometimes from a pipe
(`-` reads stdin). `detect_layout` looks at the start of the file and decides, and `Layout`
remembers the decision so that a corrected log can be written back in the layout it was read in.
Binary files (HDF5, spreadsheets, raw floats; Parquet arriving on stdin, since Parquet files are
read by `nlpcal.io.sources`, as MATLAB and DataFlash files are by `nlpcal.io.recorders`) are
refused by name in one sentence, never dumped to the terminal.
"""

from __future__ import annotations

import csv
import gzip
import re
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError
from .files import existing_file

#: Bytes looked at to detect the layout.
HEAD_BYTES = 65536
#: What a gzip stream cut short or damaged raises as it is read: the end of the stream missing,
#: a bad header or checksum, data that do not decompress.
BROKEN_STREAM = (EOFError, zlib.error, gzip.BadGzipFile)
#: Lines looked at to detect the layout.
HEAD_LINES = 200
#: What `-` stands for in messages and result documents.
STDIN = "stdin"

#: Numbers read back exactly as written: pandas 3 parses floats to the nearest double; before
#: it, the C parser's default may miss by one ulp, and by different ulps on different paths
#: (whole file, chunks, Dask blocks), unless asked to round-trip.
EXACT_FLOATS = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}

#: Delimiters tried, in order of preference when several split every line the same way (a
#: semicolon or tab file may hold decimal commas; a comma file never holds semicolons).
DELIMITERS = ("\t", ";", ",")
#: Names of delimiters, for messages.
DELIMITER_NAMES = {",": "comma", ";": "semicolon", "\t": "tab", " ": "whitespace"}

#: Signatures of binary formats people try to pass as logs: (magic bytes, offset, name).
BINARY_SIGNATURES = (
    (b"PAR1", 0, "a Parquet file"),
    (b"\x89HDF\r\n\x1a\n", 0, "an HDF5 file"),
    (b"\x89HDF\r\n\x1a\n", 512, "a MATLAB v7.3 (HDF5) file"),
    (b"ARROW1", 0, "an Arrow/Feather file"),
    (b"PK\x03\x04", 0, "a zip archive or a spreadsheet (.xlsx)"),
    (b"\xd0\xcf\x11\xe0", 0, "an old-style spreadsheet (.xls)"),
    (b"\x93NUMPY", 0, "a NumPy .npy file"),
    (b"BZh", 0, "a bzip2 archive"),
    (b"\xfd7zXZ\x00", 0, "an xz archive"),
)
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(nan|inf|infinity)$", re.I)
_DECIMAL_COMMA = re.compile(r"^[+-]?\d+,\d+([eE][+-]?\d+)?$")
_DECIMAL_POINT = re.compile(r"^[+-]?\d*\.\d+([eE][+-]?\d+)?$")
_QUOTED = re.compile(r'"[^"]*"')


@dataclass(frozen=True)
class Layout:
    """The layout of a delimited text log, as detected or forced.

    delimiter : ",", ";", "\\t", or " " for runs of spaces and tabs.
    header : whether the first line that is not a comment names the columns.
    decimal : "." or "," (a decimal comma, with a semicolon or tab delimiter).
    encoding, compression : how the bytes are text ("utf-8", "utf-8-sig", "utf-16", "latin-1";
        None or "gzip").
    preamble : the comment lines before the data, written back above a corrected log.
    newline : the line ending, "\\n" or "\\r\\n".
    """

    delimiter: str = ","
    header: bool = True
    decimal: str = "."
    encoding: str = "utf-8"
    compression: str | None = None
    preamble: tuple = ()
    newline: str = "\n"

    def describe(self) -> str:
        """For messages: "semicolon-separated, decimal comma, no header row"."""
        parts = [f"{DELIMITER_NAMES[self.delimiter]}-separated"]
        if self.decimal == ",":
            parts.append("decimal comma")
        parts.append("with a header row" if self.header else "no header row")
        if self.preamble:
            parts.append(f"{len(self.preamble)} comment line(s) first")
        return ", ".join(parts)

    def to_dict(self) -> dict:
        """For the "input" block of a result document."""
        return {
            "delimiter": DELIMITER_NAMES[self.delimiter],
            "header": self.header,
            "decimal": self.decimal,
        }

    def pandas_options(self) -> dict:
        """The `pandas.read_csv` options that read this layout."""
        return {
            "sep": r"\s+" if self.delimiter == " " else self.delimiter,
            "header": 0 if self.header else None,
            "decimal": self.decimal,
            "comment": "#",
            "skip_blank_lines": True,
            "skipinitialspace": self.delimiter != " ",
            "encoding": self.encoding,
            "compression": self.compression,
            **EXACT_FLOATS,
        }


def open_source(path) -> tuple:
    """(name for messages, what pandas reads: a Path, or the bytes of stdin).

    `-` reads standard input whole, once.
    """
    if str(path) == "-":
        return STDIN, sys.stdin.buffer.read()
    path = existing_file(path, "a delimited text log")
    return str(path), path


def head_bytes(source) -> bytes:
    """The first HEAD_BYTES bytes of a path or of bytes."""
    if isinstance(source, (bytes, bytearray)):
        return bytes(source[:HEAD_BYTES])
    with open(source, "rb") as handle:
        return handle.read(HEAD_BYTES)


def refuse_binary(name: str, head: bytes) -> None:
    """InputError in one sentence when `head` starts a binary file rather than text."""
    known = [what for magic, at, what in BINARY_SIGNATURES if head[at : at + len(magic)] == magic]
    if known:
        what = known[0]
    elif b"\x00" not in head or head.startswith((b"\xff\xfe", b"\xfe\xff")):
        return
    else:
        what = "a binary file"
    suffix = Path(name).suffix or "binary"
    raise InputError(
        f"{name} is {what}, not a delimited text log; nlpcal reads text logs "
        f"(comma, semicolon, tab or whitespace separated): export the {suffix} data to CSV "
        f"first, for example with pandas"
    )


def _text(head: bytes) -> tuple:
    """(text of the head, its encoding): UTF-8 (with or without BOM), UTF-16, else Latin-1."""
    if head.startswith(b"\xef\xbb\xbf"):
        return head[3:].decode("utf-8", errors="ignore"), "utf-8-sig"
    if head.startswith((b"\xff\xfe", b"\xfe\xff")):
        return head.decode("utf-16", errors="ignore"), "utf-16"
    try:
        return head.decode("utf-8"), "utf-8"
    except UnicodeDecodeError as exc:
        if exc.start >= len(head) - 3:  # a character cut at the end of the head
            return head[: exc.start].decode("utf-8"), "utf-8"
    return head.decode("latin-1"), "latin-1"


def is_number(text: str, decimal: str = ".") -> bool:
    """Whether a cell reads as a number (with the given decimal mark)."""
    text = text.strip().strip('"').strip()
    if decimal == ",":
        text = text.replace(",", ".")
    return bool(_NUMBER.match(text))


def _split(line: str, delimiter: str) -> list:
    if delimiter == " ":
        return line.split()
    return next(csv.reader([line], delimiter=delimiter, skipinitialspace=True), [])


#: A delimiter must split at least this share of the first lines into the same number of fields
#: (the other lines are ragged rows, which the reader then reports by line number). [1]
CONSISTENT_SHARE = 0.9


def _consistent(counts: list, minimum: int) -> bool:
    """Whether most lines have the same count, and it is at least `minimum`."""
    values, frequency = np.unique(counts, return_counts=True)
    k = int(np.argmax(frequency))
    return values[k] >= minimum and frequency[k] >= CONSISTENT_SHARE * len(counts)


def _delimiter(lines: list) -> str | None:
    """The delimiter that splits (nearly) every line into the same number (> 1) of fields."""
    for candidate in DELIMITERS:
        if _consistent([_QUOTED.sub("", line).count(candidate) for line in lines], 1):
            return candidate
    if _consistent([len(line.split()) for line in lines], 2):
        return " "
    return None


def _decimal(rows: list, delimiter: str) -> str:
    if delimiter == ",":
        return "."
    cells = [cell.strip().strip('"') for row in rows for cell in row]
    comma = any(_DECIMAL_COMMA.match(cell) for cell in cells)
    point = any(_DECIMAL_POINT.match(cell) for cell in cells)
    return "," if comma and not point else "."


def _has_header(rows: list, decimal: str) -> bool:
    """A header row has a cell that is not a number in a column that holds numbers below it."""
    first, below = rows[0], rows[1:]
    for j, cell in enumerate(first):
        if not cell.strip() or is_number(cell, decimal):
            continue
        if not below or any(j < len(row) and is_number(row[j], decimal) for row in below):
            return True
    return False


def detect_layout(name: str, source, header: bool | None = None) -> Layout:
    """The layout of a log (a path or bytes), from its first lines.

    header : True or False forces the header row (--header / --no-header); None detects it.
    Raises InputError for binary files, empty files and files whose lines do not split into the
    same number of fields.
    """
    head = head_bytes(source)
    compression = None
    if head.startswith(b"\x1f\x8b"):
        compression = "gzip"
        try:
            if isinstance(source, (bytes, bytearray)):
                head = gzip.decompress(bytes(source))[:HEAD_BYTES]
            else:
                with gzip.open(source, "rb") as handle:
                    head = handle.read(HEAD_BYTES)
        except BROKEN_STREAM as exc:
            raise InputError(f"{name}: cannot be read as gzip-compressed text ({exc})") from None
    refuse_binary(name, head)
    text, encoding = _text(head)
    complete = len(head) < HEAD_BYTES
    lines = text.splitlines()
    if not complete and lines:
        lines = lines[:-1]  # the last line of the head may be cut
    newline = "\r\n" if "\r\n" in text else "\n"
    preamble: list = []
    data: list = []
    for line in lines:
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            if not data:
                preamble.append(line)
            continue
        data.append(line.split("#", 1)[0].rstrip() if "#" in line else line)
        if len(data) >= HEAD_LINES:
            break
    if not data:
        raise InputError(f"{name}: the file is empty (no lines other than comments)")
    delimiter = _delimiter(data)
    if delimiter is None:
        delimiter = _delimiter(data[1:]) if len(data) > 2 else None
    if delimiter is None:
        raise InputError(
            f"{name}: cannot tell how the columns are separated (the first lines do not "
            f"split into the same number of fields by comma, semicolon, tab or whitespace); "
            f"expected a delimited text log with one sample per line"
        )
    rows = [_split(line, delimiter) for line in data]
    decimal = _decimal(rows[1:] or rows, delimiter)
    if header is None:
        header = _has_header(rows, decimal)
    return Layout(
        delimiter=delimiter,
        header=bool(header),
        decimal=decimal,
        encoding=encoding,
        compression=compression,
        preamble=tuple(preamble),
        newline=newline,
    )
