"""INTERMAGNET ImagCDF: geomagnetic observatory data in NASA's Common Data Format [1], through
cdflib (optional: `pip install 'nlpcal[cdf]'`).

An ImagCDF file holds one variable per element, `GeomagneticField` + its letter (H, E, Z, S ...),
and `Temperature1`, `Temperature2` ..., each naming the variable of its sample times (DEPEND_0:
`DataTimes`, or `GeomagneticVectorTimes` and `GeomagneticScalarTimes` when the scalar has its own
rate), times in CDF TT2000 (nanoseconds of terrestrial time since J2000, with leap seconds),
read as UTC. Cells equal to the variable's FILLVAL (99999.0, or NaN) or outside VALIDMIN ..
VALIDMAX are missing. The global attributes are the header: IagaCode, ObservatoryName,
ElementsRecorded, VectorSensOrient, TermsOfUse and the sensor's description.

References
----------
[1] INTERMAGNET, ImagCDF format, version 1.3 (2021), https://tech-man.intermagnet.org/
"""

from __future__ import annotations

import os
import tempfile

import numpy as np
import pandas as pd

from ..errors import InputError
from . import observatory
from .observatory import TIME_COLUMN, Observatory

INSTALL = "reading an INTERMAGNET ImagCDF file needs cdflib: pip install 'nlpcal[cdf]'"
#: The start of a CDF file: version 3, and versions 2.6 and 2.7.
MAGIC = (b"\xcd\xf3\x00\x01", b"\xcd\xf2\x60\x02")
#: The names of the element and temperature variables.
FIELD_PREFIX = "GeomagneticField"
TEMPERATURE_PREFIX = "Temperature"
#: The unit ImagCDF writes for temperatures, and the unit nlpcal names it. [degC]
CELSIUS = {"celsius": "degC", "deg_c": "degC", "degc": "degC"}


def is_imagcdf(head: bytes) -> bool:
    """Whether the start of a file is a CDF file (ImagCDF is one; others are refused when read)."""
    return head.startswith(MAGIC)


def _column(variable: str) -> str:
    """The column of a variable: its element letter (GeomagneticFieldH -> H), or T1, T2 ..."""
    if variable.startswith(FIELD_PREFIX):
        return variable[len(FIELD_PREFIX) :]
    return "T" + variable[len(TEMPERATURE_PREFIX) :]


def _text(value):
    """A global attribute's entries as one JSON value: a number, or text."""
    items = [v.item() if isinstance(v, np.generic) else v for v in np.atleast_1d(value).tolist()]
    if len(items) == 1 and isinstance(items[0], (int, float)) and np.isfinite(items[0]):
        return items[0]
    return "; ".join(str(item) for item in items)


def _globals(cdf) -> dict:
    return {key: _text(value) for key, value in cdf.globalattsget().items()}


def _times(cdf, name: str, variable: str):
    """The sample times of a time variable as UTC datetime64[ns] (TT2000, or CDF_EPOCH)."""
    import cdflib

    values = cdf.varget(variable)
    if values is None or np.size(values) == 0:
        raise InputError(f"{name}: the ImagCDF time variable {variable} holds no times")
    return np.asarray(cdflib.cdfepoch.to_datetime(values), dtype="datetime64[ns]")


def _missing(attributes: dict):
    """`is_missing(column, values)` from each column's FILLVAL, VALIDMIN and VALIDMAX."""

    def is_missing(column: str, values: np.ndarray) -> np.ndarray:
        found = attributes[column]
        out = np.zeros(values.shape, dtype=bool)
        fill = found.get("FILLVAL")
        if fill is not None and np.isfinite(float(np.ravel(fill)[0])):
            out |= values == float(np.ravel(fill)[0])
        for key, outside in (("VALIDMIN", np.less), ("VALIDMAX", np.greater)):
            if found.get(key) is not None:
                out |= outside(values, float(np.ravel(found[key])[0]))
        return out

    return is_missing


def _read(name: str, cdf) -> tuple:
    """(frame, per-column variable attributes, notes) of an open ImagCDF file."""
    variables = [
        v
        for v in cdf.cdf_info().zVariables
        if v.startswith(FIELD_PREFIX) or v.startswith(TEMPERATURE_PREFIX)
    ]
    if not any(v.startswith(FIELD_PREFIX) for v in variables):
        raise InputError(
            f"{name}: a CDF file without GeomagneticField variables, so not INTERMAGNET ImagCDF"
        )
    attributes = {_column(v): cdf.varattsget(v) for v in variables}
    times_of = {
        _column(v): attributes[_column(v)].get("DEPEND_0") or "DataTimes" for v in variables
    }
    main = times_of[_column(variables[0])]
    times = _times(cdf, name, main)
    columns: dict = {TIME_COLUMN: times}
    said = []
    for variable in variables:
        column = _column(variable)
        values = np.asarray(cdf.varget(variable), dtype=float).ravel()
        if times_of[column] != main:
            own = _times(cdf, name, times_of[column])
            if own.shape != values.shape:
                raise InputError(
                    f"{name}: {variable} and its times {times_of[column]} differ in length"
                )
            at = pd.Index(own).get_indexer(times)
            values = np.where(at >= 0, values[np.maximum(at, 0)], np.nan)
            said.append(
                f"{name}: {column} has its own times ({times_of[column]}); it is read on the "
                f"times of {main} where they coincide ({int((at >= 0).sum())} rows), missing "
                f"elsewhere; --reference-log interpolates a reference of another time base"
            )
        if values.shape != times.shape:
            raise InputError(
                f"{name}: {variable} has {values.size} values for {times.size} times ({main})"
            )
        columns[column] = values
    return pd.DataFrame(columns), attributes, said


def _opened(name: str, path):
    try:
        import cdflib
    except ImportError:
        raise InputError(INSTALL) from None
    try:
        cdf = cdflib.CDF(os.path.abspath(path))
    except Exception as exc:  # cdflib raises many kinds on a damaged file
        raise InputError(f"{name}: cannot be read as a CDF file ({_first(exc)})") from None
    cdf._f = _WholeReads(cdf._f)
    return cdf


class _WholeReads:
    """A file that raises EOFError where it has fewer bytes than asked for: cdflib takes the
    bytes missing from a cut file as values (zeros, say) and says nothing."""

    def __init__(self, handle):
        self._handle = handle

    def read(self, size: int = -1) -> bytes:
        data = self._handle.read(size)
        if size is not None and size >= 0 and len(data) < size:
            raise EOFError("the file ends inside a record: it is cut")
        return data

    def __getattr__(self, name):
        return getattr(self._handle, name)


def _first(exc: Exception) -> str:
    return (" ".join(str(exc).split()) or type(exc).__name__)[:160]


def read_imagcdf(name: str, source) -> tuple:
    """(frame, field columns or None, notes, Observatory) of an ImagCDF file (a path or its
    bytes): `time` (UTC), the elements by letter and the temperatures T1, T2 ..."""
    spool = None
    if isinstance(source, (bytes, bytearray)):  # cdflib opens files by name
        spool = tempfile.NamedTemporaryFile(suffix=".cdf", delete=False)
        spool.write(source)
        spool.close()
        source = spool.name
    cdf = None
    try:
        cdf = _opened(name, source)
        frame, attributes, said = _read(name, cdf)
        header = _globals(cdf)
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"{name}: cannot be read as INTERMAGNET ImagCDF ({_first(exc)})") from None
    finally:
        _close(cdf)
        if spool is not None:
            os.unlink(spool.name)
    return _result(name, frame, attributes, header, said)


def _close(cdf) -> None:
    """Close a cdflib file and remove the copy it decompressed a compressed file into."""
    if cdf is None:
        return
    handle = getattr(cdf, "_f", None)
    if handle is not None and hasattr(handle, "close"):
        handle.close()
    copy = getattr(cdf, "temp_file", None)
    if copy is not None:
        cdf.temp_file = None
        if os.path.exists(copy):
            os.remove(copy)


def _result(name: str, frame: pd.DataFrame, attributes: dict, header: dict, said: list) -> tuple:
    elements = [c for c in frame.columns if c != TIME_COLUMN]
    units = {}
    for column in elements:
        unit = str(attributes[column].get("UNITS") or "")
        units[column] = CELSIUS.get(unit.lower(), unit)
    missing = observatory.mark_missing(frame, elements, _missing(attributes))
    known = ("IagaCode", "ObservatoryName", "ElementsRecorded", "VectorSensOrient", "TermsOfUse")
    record = Observatory(
        format="ImagCDF",
        iaga_code=str(header["IagaCode"]) if "IagaCode" in header else None,
        station=str(header["ObservatoryName"]) if "ObservatoryName" in header else None,
        elements=str(header.get("ElementsRecorded") or "".join(elements)),
        sensor_orientation=str(header["VectorSensOrient"])
        if "VectorSensOrient" in header
        else None,
        units=units,
        sampling_interval_s=observatory.sampling_interval(frame[TIME_COLUMN].to_numpy()),
        terms_of_use=str(header["TermsOfUse"]) if header.get("TermsOfUse") else None,
        missing_values=missing,
        header={k: v for k, v in header.items() if k not in known},
    )
    columns = observatory.field_columns([c for c in elements if not c.startswith("T")], units)
    return frame, columns, [*observatory.notes(name, record, len(frame), columns), *said], record
