"""Lines of a stream into field samples: MotionCal `Raw:` lines, delimited text, a pattern.

The parser is chosen from the stream's first lines (`detect_parser`): a `--regex` when given,
MotionCal's protocol when a `Raw:` line is among them (`nlpcal.io.motioncal`), else delimited
text, its delimiter, decimal mark, header row, field columns and unit detected as `nlpcal
calibrate` detects them in a log (`nlpcal.io.layout.detect_layout`,
`nlpcal.io.tables.resolve_columns`, `nlpcal.io.logs.sensor_unit`). Every parser also says what
`--record` writes for a line, so that `nlpcal calibrate` reads the recording as it would have
read the stream.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..errors import InputError
from ..io import motioncal
from ..io.layout import detect_layout, is_number
from ..io.logs import sensor_unit
from ..io.tables import resolve_columns

#: Lines the parser is chosen from (fewer when the stream ends first).
HEAD_LINES = 8
#: The header `--record` writes above the numbers a `--regex` captured.
REGEX_HEADER = "bx,by,bz"


@dataclass
class Parser:
    """One way of reading a stream's lines.

    kind : "motioncal", "delimited" or "regex". unit : the unit of the field values, and
    unit_source, where it came from (`nlpcal.units.UNIT_SOURCES`). notes : what was detected.
    header : the line `--record` writes first (a delimited stream's header row, or
    REGEX_HEADER), or None.
    """

    kind: str
    unit: str
    unit_source: str
    notes: list = field(default_factory=list)
    header: str | None = None
    _values: object = None  # line -> the three field values as text, or None

    def values(self, line: str) -> list | None:
        """The three field values of a line as text, or None for a line without them."""
        return self._values(line)  # type: ignore[operator]

    def parse(self, lines) -> tuple:
        """((k, 3) samples, [the line to record of each], lines left out) of some lines.
        [unit]"""
        rows, kept, skipped = [], [], 0
        for line in lines:
            cells = self.values(line)
            numbers = _floats(cells)
            if numbers is None:
                skipped += bool(line.strip())
                continue
            rows.append(numbers)
            kept.append(",".join(cells) if self.kind == "regex" else line)  # type: ignore[arg-type]
        return np.asarray(rows, dtype=float).reshape(-1, 3), kept, skipped


def _floats(cells) -> list | None:
    if cells is None:
        return None
    try:
        numbers = [float(c) for c in cells]
    except ValueError:
        return None
    return numbers if all(np.isfinite(numbers)) else None


def motioncal_values(line: str) -> list | None:
    """mx, my, mz of a MotionCal `Raw:` line."""
    line = line.strip()
    counts = motioncal.raw_counts(line) if line.startswith("Raw:") else None
    return None if counts is None else [str(c) for c in counts[6:9]]


def regex_parser(pattern: str, unit: str | None) -> Parser:
    """A parser that takes the named groups x, y, z of `pattern`, or its first three groups."""
    try:
        compiled = re.compile(pattern)
    except re.error as error:
        raise InputError(f"--regex {pattern!r} is not a regular expression: {error}") from None
    names = ["x", "y", "z"] if {"x", "y", "z"} <= set(compiled.groupindex) else [1, 2, 3]
    if compiled.groups < 3:
        raise InputError(
            f"--regex {pattern!r} has {compiled.groups} group(s); it needs three, the x, y and z "
            f"values, e.g. 'mag=([-0-9.]+) ([-0-9.]+) ([-0-9.]+)' or named (?P<x>...)"
        )

    def values(line: str) -> list | None:
        match = compiled.search(line)
        return None if match is None else [match.group(n) for n in names]

    return Parser(
        "regex",
        unit or "nT",
        "option" if unit else "assumed",
        header=REGEX_HEADER,
        _values=values,
    )


def delimited_parser(head: list, columns, unit: str | None) -> Parser:
    """A parser of delimited text laid out as the first lines `head` are (with the reader's
    detection of a log: delimiter, decimal mark, header row, field columns, unit)."""
    text = "\n".join(head).encode()
    layout = detect_layout("the stream", text)
    notes: list = []
    frame = pd.read_csv(io.BytesIO(text), **{**layout.pandas_options(), "dtype": str})
    names = resolve_columns(
        frame,
        columns,
        header=layout.header,
        decimal=layout.decimal,
        notes=notes,
    )
    positions = [frame.columns.get_loc(name) for name in names]
    chosen, source = sensor_unit([str(n) for n in names], unit, "nT", notes)
    splitter = None if layout.delimiter == " " else layout.delimiter
    decimal = layout.decimal

    def values(line: str) -> list | None:
        cells = line.split("#", 1)[0].split(splitter)
        if len(cells) <= max(positions):
            return None
        picked = [cells[p].strip().replace(decimal, ".") for p in positions]
        return picked if all(is_number(c) for c in picked) else None

    notes.insert(
        0, f"delimited text, {layout.describe()}; field columns {', '.join(map(str, names))}"
    )
    header = next((line for line in head if line.strip() and not line.startswith("#")), None)
    return Parser(
        "delimited",
        chosen,
        source,
        notes,
        header=header if layout.header else None,
        _values=values,
    )


def detect_parser(head: list, *, columns=None, regex: str | None = None, unit=None) -> Parser:
    """The parser of a stream whose first lines are `head`."""
    if regex is not None:
        return regex_parser(regex, unit)
    if any(line.strip().startswith("Raw:") for line in head):
        chosen, source = (unit, "option") if unit else (motioncal.FIELD_UNIT, "format")
        return Parser(
            "motioncal",
            chosen,
            source,
            ["MotionCal Raw: lines; the field is mx, my, mz in counts of 0.1 uT (1 mG)"],
            _values=motioncal_values,
        )
    lines = [line for line in head if line.strip()]
    if not lines:
        raise InputError(
            "no line came from the stream (it ended, or --max-seconds passed, before the first)"
        )
    return delimited_parser(lines, columns, unit)
