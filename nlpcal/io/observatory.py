"""Geomagnetic observatory data: what the IAGA-2002 and INTERMAGNET ImagCDF readers share.

An observatory file holds the elements of the field, named by letter: a vector triple (X, Y, Z
north, east, down; or H, E, Z, or H, D, Z with D an angle), a scalar (F, or S in ImagCDF: an
independent scalar instrument), sometimes delta F (G), and temperatures. The readers
(`nlpcal.io.iaga2002`, `nlpcal.io.imagcdf`) name the columns by element, put the sample times
(UTC) in the column `time`, mark missing values (99999, and 88888 "not recorded" in IAGA-2002)
as missing, and keep the header in an `Observatory` record: the station, the sensor, the units,
the sampling and the terms of use, which the result's provenance carries ("input.observatory")
and the command line prints where results from the data are shown.

References
----------
[1] IAGA-2002 data exchange format, https://www.ngdc.noaa.gov/IAGA/vdat/IAGA2002/iaga2002format.html
[2] INTERMAGNET ImagCDF format, version 1.3 (2021), https://tech-man.intermagnet.org/
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

#: The column of sample times (UTC, datetime64[ns]) in every observatory log.
TIME_COLUMN = "time"
#: The unit of a field element. [nT]
FIELD_UNIT = "nT"
#: Elements that are angles, not field components (D declination, I inclination).
ANGLES = ("D", "I")
#: What each element letter is, for notes.
ELEMENTS = {
    "X": "north",
    "Y": "east",
    "Z": "down",
    "H": "horizontal intensity",
    "E": "east (in the D direction)",
    "D": "declination",
    "I": "inclination",
    "V": "vertical",
    "F": "total field (scalar)",
    "S": "total field (independent scalar)",
    "G": "delta F",
}


@dataclass
class Observatory:
    """The header of an observatory file, kept in a result's provenance ("input.observatory").

    format : "IAGA-2002" or "ImagCDF". iaga_code : the station's IAGA code. elements : the
    elements recorded, in order ("XYZF", "HEZS"). units : the unit of each column read.
    sampling_interval_s : the median step between samples. [s] terms_of_use : the data set's
    conditions of use, verbatim (its required acknowledgement), or None. missing_values : the
    cells marked missing, per column. header : every other header entry, as written.
    """

    format: str
    iaga_code: str | None = None
    station: str | None = None
    elements: str | None = None
    sensor_orientation: str | None = None
    units: dict = field(default_factory=dict)
    sampling_interval_s: float | None = None
    terms_of_use: str | None = None
    missing_values: dict = field(default_factory=dict)
    header: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The record as JSON values, None entries left out."""
        record = {
            "format": self.format,
            "iaga_code": self.iaga_code,
            "station": self.station,
            "elements": self.elements,
            "sensor_orientation": self.sensor_orientation,
            "units": dict(self.units),
            "sampling_interval_s": self.sampling_interval_s,
            "terms_of_use": self.terms_of_use,
            "missing_values": dict(self.missing_values),
            "header": dict(self.header),
        }
        return {key: value for key, value in record.items() if value is not None}


def terms_of_use(source) -> str | None:
    """The terms of use (the acknowledgement they require) of an `Observatory`, of a result
    whose provenance ("input") holds one, or of such a provenance block; None otherwise."""
    if isinstance(source, Observatory):
        return source.terms_of_use
    block = source if isinstance(source, dict) else getattr(source, "input", None)
    if not isinstance(block, dict):
        return None
    record = block.get("observatory")
    terms = record.get("terms_of_use") if isinstance(record, dict) else None
    return terms if isinstance(terms, str) and terms.strip() else None


def field_columns(elements: list, units: dict) -> list | None:
    """The first three elements when they are a vector triple in nT, else None (an angle, D or
    I, is not a field component: the field columns are then to be chosen with --columns)."""
    vector = [e for e in elements if e not in ("F", "S", "G") and not e.startswith("T")][:3]
    if len(vector) == 3 and all(units.get(e) == FIELD_UNIT for e in vector):
        return vector
    return None


def mark_missing(frame: pd.DataFrame, columns, is_missing) -> dict:
    """Set to NaN, in place, the cells of `columns` for which `is_missing(column, values)` is
    true (and NaN already there); the count of missing cells per column (columns with none left
    out)."""
    counts = {}
    for column in columns:
        values = frame[column].to_numpy(dtype=float)
        missing = np.isnan(values) | is_missing(column, values)
        if missing.any():
            frame[column] = np.where(missing, np.nan, values)
            counts[column] = int(missing.sum())
    return counts


def sampling_interval(times: np.ndarray) -> float | None:
    """The median step of sample times (datetime64[ns]). [s]"""
    steps = np.diff(times.astype("int64")) / 1e9
    return float(np.median(steps)) if steps.size else None


def notes(name: str, record: Observatory, n: int, columns: list | None) -> list:
    """What the reader of an observatory file says: what it read, and its missing values."""
    said = [
        f"{name}: {record.format} of {record.station or record.iaga_code or 'an observatory'}"
        f"{f' ({record.iaga_code})' if record.iaga_code and record.station else ''}, {n} samples"
        f"{f' every {record.sampling_interval_s:g} s' if record.sampling_interval_s else ''}, "
        f"elements {record.elements or '?'}"
        + (f"; field columns {', '.join(columns)} in nT" if columns else "")
    ]
    if not columns:
        said.append(
            f"{name}: the elements {record.elements or '?'} are not a vector triple in nT (D and "
            f"I are angles); pass --columns with three field components"
        )
    if record.missing_values:
        listing = ", ".join(f"{k} {v}" for k, v in record.missing_values.items())
        said.append(
            f"{name}: cells marked missing (99999, 88888 or the fill value) read as missing: "
            f"{listing}; rows with a missing value in a column used fail, or are dropped with "
            f"--drop-invalid"
        )
    return said
