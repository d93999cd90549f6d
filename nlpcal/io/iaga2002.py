"""IAGA-2002: the text exchange format of geomagnetic observatory data [1] (no dependency).

A file is a header of fixed-width records (" Format                 IAGA-2002    ... |": the key
in columns 2-24, the value to column 69, a bar at 70), comment records (" # ..."), one line of
column names (DATE TIME DOY and four elements prefixed by the IAGA code: WICX WICY WICZ WICF),
then one line per sample. Field elements are in nT, D and I in minutes of arc; 99999.00 marks a
missing value and 88888.00 one not recorded. The columns are read as `time` (DATE and TIME, UTC)
and the elements by letter (X, Y, Z, F); DOY is left out.

References
----------
[1] IAGA-2002 data exchange format, https://www.ngdc.noaa.gov/IAGA/vdat/IAGA2002/iaga2002format.html
"""

from __future__ import annotations

import io
import re

import numpy as np
import pandas as pd

from ..errors import InputError
from . import observatory
from .observatory import TIME_COLUMN, Observatory

#: The first header record of every IAGA-2002 file.
_MAGIC = re.compile(rb"^\s*Format\s+IAGA-2002\b", re.I)
#: Where a header record's value starts.
KEY_WIDTH = 24
#: Values that mark a cell: missing (99999) and not recorded (88888). [element unit]
MISSING = (99999.0, 88888.0)
#: The unit of the angular elements. [minutes of arc]
ANGLE_UNIT = "arcmin"
#: A comment that opens the data set's conditions of use.
_TERMS = re.compile(r"(conditions|terms) of use|licen[cs]e|acknowledg", re.I)
#: A comment that opens another topic ("DECBAS: ...").
_TOPIC = re.compile(r"^[A-Z][A-Za-z ]{2,30}:")


def is_iaga2002(head: bytes) -> bool:
    """Whether the start of a file is an IAGA-2002 header (" Format IAGA-2002")."""
    return bool(_MAGIC.match(head))


def _header(name: str, lines: list) -> tuple:
    """(header entries, comments, index of the column-names line) of a file's lines."""
    header: dict = {}
    comments: list = []
    for k, line in enumerate(lines):
        text = line.rstrip().rstrip("|").rstrip()
        if text.startswith("DATE"):
            return header, comments, k
        if text.lstrip().startswith("#"):
            comments.append(text.lstrip()[1:].strip())
        elif text.strip():
            header[text[:KEY_WIDTH].strip()] = text[KEY_WIDTH:].strip()
    raise InputError(
        f"{name}: an IAGA-2002 header without the DATE TIME DOY line of column names; the file "
        f"is cut or damaged"
    )


def _terms(comments: list) -> str | None:
    """The conditions of use among the comments: the comment that opens them and those that
    continue it, joined; None when no comment names them."""
    for k, comment in enumerate(comments):
        if _TERMS.search(comment):
            taken = [comment]
            for more in comments[k + 1 :]:
                if not more or _TOPIC.match(more):
                    break
                taken.append(more)
            return " ".join(taken)
    return None


def _elements(name: str, names: list, code: str | None) -> list:
    """The element letters of the column names after DATE TIME DOY (WICX -> X)."""
    elements = []
    for column in names:
        element = column[len(code) :] if code and column.upper().startswith(code) else column[-1:]
        elements.append(element.upper())
    if len(set(elements)) != len(elements) or not all(e.isalpha() for e in elements):
        raise InputError(
            f"{name}: the IAGA-2002 column names {' '.join(names)} do not name distinct "
            f"elements (such as {code or 'ABC'}X {code or 'ABC'}Y {code or 'ABC'}Z "
            f"{code or 'ABC'}F)"
        )
    return elements


def _frame(name: str, text: str, elements: list) -> pd.DataFrame:
    """The data lines as `time` and one float column per element."""
    try:
        frame = pd.read_csv(
            io.StringIO(text),
            sep=r"\s+",
            header=None,
            names=["DATE", "TIME", "DOY", *elements],
            dtype={"DATE": str, "TIME": str},
            engine="c",
        )
    except pd.errors.EmptyDataError:
        raise InputError(f"{name}: an IAGA-2002 file without data lines") from None
    except (pd.errors.ParserError, ValueError) as exc:
        first = " ".join(str(exc).split())[:160]
        raise InputError(f"{name}: IAGA-2002 data lines that cannot be read ({first})") from None
    if frame.empty:
        raise InputError(f"{name}: an IAGA-2002 file without data lines")
    times = pd.to_datetime(
        frame["DATE"].astype(str) + "T" + frame["TIME"].astype(str),
        errors="coerce",
        format="ISO8601",
    )
    if times.isna().any():
        row = int(np.flatnonzero(times.isna().to_numpy())[0]) + 1
        raise InputError(
            f"{name}: IAGA-2002 data line {row} has no valid DATE and TIME "
            f"(YYYY-MM-DD hh:mm:ss.sss)"
        )
    columns = {TIME_COLUMN: times.to_numpy(dtype="datetime64[ns]")}
    for element in elements:
        values = pd.to_numeric(frame[element], errors="coerce")
        if values.isna().any():
            row = int(np.flatnonzero(values.isna().to_numpy())[0]) + 1
            raise InputError(
                f"{name}: IAGA-2002 data line {row} has a value of {element} that is not a "
                f"number (missing values are written 99999.00)"
            )
        columns[element] = values.to_numpy(dtype=float)
    return pd.DataFrame(columns)


def read_iaga2002(name: str, source) -> tuple:
    """(frame, field columns or None, notes, Observatory) of an IAGA-2002 file (a path or its
    bytes): `time` (UTC) and the elements by letter, 99999 and 88888 read as missing."""
    if isinstance(source, (bytes, bytearray)):
        data = bytes(source)
    else:
        with open(source, "rb") as handle:
            data = handle.read()
    lines = data.decode("latin-1").splitlines()
    header, comments, at = _header(name, lines)
    entry = {key.lower(): value for key, value in header.items()}  # keys in any case
    code = (entry.get("iaga code") or "").upper() or None
    names = lines[at].rstrip().rstrip("|").split()
    if [n.upper() for n in names[:3]] != ["DATE", "TIME", "DOY"] or len(names) < 4:
        raise InputError(
            f"{name}: the IAGA-2002 column names ({' '.join(names)}) do not start with DATE TIME "
            f"DOY and an element"
        )
    elements = _elements(name, names[3:], code)
    frame = _frame(name, "\n".join(lines[at + 1 :]), elements)
    units = {
        e: (ANGLE_UNIT if e in observatory.ANGLES else observatory.FIELD_UNIT) for e in elements
    }
    missing = observatory.mark_missing(
        frame, elements, lambda column, values: np.isin(values, MISSING)
    )
    record = Observatory(
        format="IAGA-2002",
        iaga_code=code,
        station=entry.get("station name") or None,
        elements="".join(elements),
        sensor_orientation=entry.get("sensor orientation") or None,
        units=units,
        sampling_interval_s=observatory.sampling_interval(frame[TIME_COLUMN].to_numpy()),
        terms_of_use=_terms(comments),
        missing_values=missing,
        header={**header, **({"comments": comments} if comments else {})},
    )
    columns = observatory.field_columns(elements, units)
    return frame, columns, observatory.notes(name, record, len(frame), columns), record
