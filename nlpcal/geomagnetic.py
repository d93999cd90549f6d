"""The geomagnetic reference field from a model: IGRF-14 or WMM2025 at a place and a date.

A calibration without a reference cannot fix the absolute scale (Zhou et al. 2010, Eq. 8); the
Earth's main field at the place and date of the log is such a reference. Two maintained packages
evaluate the two standard models (optional: pip install 'nlpcal[geomag]'):

* "igrf": the International Geomagnetic Reference Field, 14th generation (IAGA, 2024), defined
  1900.0 to 2030.0, through `ppigrf` (its IGRF14.shc coefficients; the Gauss coefficients are
  linear in time between the five-year epochs);
* "wmm": the World Magnetic Model 2025 (NOAA/NCEI and BGS), defined 2025.0 to 2030.0, through
  `pygeomag` (its WMM_2025.COF; linear secular variation from 2025.0).

Positions are geodetic (WGS 84) latitude and longitude [deg] and height above the ellipsoid [m];
times are UTC. A height above mean sea level differs by the geoid undulation (< 110 m), which
moves the total field by less than 3 nT.

Because the field at a fixed place is linear in the Gauss coefficients and these are linear in
time between epochs, a series is evaluated exactly at the ends of the log's time span (and at
any epoch inside it) and interpolated in time per sample; each distinct position is evaluated
once.
"""

from __future__ import annotations

import contextlib
import io
from dataclasses import dataclass
from importlib import metadata
from typing import Any

import numpy as np
import pandas as pd

from . import validation
from .errors import InputError

MODELS = ("igrf", "wmm")
#: name, package, coefficient file, first and last valid decimal year, epochs inside. [year]
_MODELS = {
    "igrf": ("IGRF-14", "ppigrf", "IGRF14.shc", 1900.0, 2030.0, np.arange(1905.0, 2030.0, 5.0)),
    "wmm": ("WMM2025", "pygeomag", "WMM_2025.COF", 2025.0, 2030.0, np.array([])),
}
GEOMAG_HINT = "pip install 'nlpcal[geomag]'"
#: Distinct positions evaluated per call of the IGRF package (bounds its memory).
CHUNK_POSITIONS = 20000
#: Heights accepted: WMM is defined from 1 km below the ellipsoid to 850 km above it; IGRF, a
#: potential field of internal sources, holds out to several Earth radii (6 000 km here). [m]
ALTITUDE_RANGE_M = {"igrf": (-1000.0, 6_000_000.0), "wmm": (-1000.0, 850_000.0)}


@dataclass
class ModelField:
    """The model's field: north, east, down and total [nT], declination and inclination [deg];
    floats for one place, arrays for many."""

    north_nT: Any
    east_nT: Any
    down_nT: Any

    @property
    def total_nT(self):
        return np.sqrt(self.north_nT**2 + self.east_nT**2 + self.down_nT**2)

    @property
    def declination_deg(self):
        """Angle of the horizontal field from true north, east positive. [deg]"""
        return np.degrees(np.arctan2(self.east_nT, self.north_nT))

    @property
    def inclination_deg(self):
        """Angle of the field below the horizontal, down positive. [deg]"""
        return np.degrees(np.arctan2(self.down_nT, np.hypot(self.north_nT, self.east_nT)))


def model_info(model: str) -> dict:
    """Name, package and version, coefficient file and validity of a model."""
    validation.choice(model, "geomagnetic model", MODELS)
    name, package, coefficients, first, last, _ = _MODELS[model]
    try:
        version = metadata.version(package)
    except metadata.PackageNotFoundError:
        version = "not installed"
    return {
        "name": name,
        "package": package,
        "package_version": version,
        "coefficients": coefficients,
        "valid_years": [first, last],
    }


def decimal_year(times) -> np.ndarray:
    """UTC times (datetime64) as decimal years: year + elapsed fraction of that year. [year]"""
    stamps = pd.DatetimeIndex(np.atleast_1d(np.asarray(times, dtype="datetime64[ns]")))
    start = pd.to_datetime({"year": stamps.year, "month": 1, "day": 1})
    end = pd.to_datetime({"year": stamps.year + 1, "month": 1, "day": 1})
    fraction = (stamps - pd.DatetimeIndex(start)) / (
        pd.DatetimeIndex(end) - pd.DatetimeIndex(start)
    )
    return np.asarray(stamps.year + np.asarray(fraction, dtype=float), dtype=float)


def parse_date(text) -> np.datetime64:
    """A date or date-time (YYYY-MM-DD, ISO 8601), taken as UTC."""
    try:
        stamp = pd.Timestamp(str(text))
    except (ValueError, TypeError):
        raise InputError(f"the date must be YYYY-MM-DD (or ISO 8601), got {text!r}") from None
    if stamp is pd.NaT:
        raise InputError(f"the date must be YYYY-MM-DD (or ISO 8601), got {text!r}")
    if stamp.tzinfo is not None:
        stamp = stamp.tz_convert("UTC").tz_localize(None)
    return np.datetime64(stamp.to_datetime64(), "ns")


def parse_times(values) -> np.ndarray:
    """A time column as UTC datetime64 (NaT where a cell is not a time): ISO 8601 text, or
    numbers taken as Unix time [s]."""
    series = pd.Series(values)
    if pd.api.types.is_numeric_dtype(series) and not pd.api.types.is_bool_dtype(series):
        seconds = pd.to_numeric(series, errors="coerce").to_numpy(dtype=float)
        finite = np.isfinite(seconds)
        out = np.full(seconds.shape, np.datetime64("NaT", "ns"), dtype="datetime64[ns]")
        out[finite] = (seconds[finite] * 1e9).astype("int64").astype("datetime64[ns]")
        return out
    parsed = pd.to_datetime(series.astype(str), errors="coerce", utc=True, format="ISO8601")
    return parsed.dt.tz_localize(None).to_numpy(dtype="datetime64[ns]")


def _check_place(model: str, lat, lon, alt_m) -> tuple:
    lat, lon, alt = (np.asarray(v, dtype=float) for v in (lat, lon, alt_m))
    for values, what, low, high in (
        (lat, "latitude", -90.0, 90.0),
        (lon, "longitude", -360.0, 360.0),
        (alt, "height above the ellipsoid [m]", *ALTITUDE_RANGE_M[model]),
    ):
        if not np.isfinite(values).all():
            raise InputError(f"the {what} contains non-finite values")
        if (values < low).any() or (values > high).any():
            raise InputError(
                f"the {what} must lie within {low:g} .. {high:g}, got "
                f"{float(values.min()):g} .. {float(values.max()):g}"
            )
    return lat, np.where(lon > 180.0, lon - 360.0, lon), alt


def _check_years(model: str, years: np.ndarray) -> None:
    name, _, _, first, last, _ = _MODELS[model]
    if not np.isfinite(years).all():
        raise InputError("the times contain values that are not dates")
    low, high = float(years.min()), float(years.max())
    if low < first or high > last:
        raise InputError(
            f"{name} is defined from {first:.1f} to {last:.1f}; the dates reach "
            f"{low:.3f} .. {high:.3f}"
            + ("; use --reference-model igrf for earlier dates" if model == "wmm" else "")
        )


def _igrf(lat, lon, alt_m, years) -> np.ndarray:
    """(n_years, n_places, 3) north, east, down [nT] from ppigrf (IGRF-14)."""
    ppigrf = _package("ppigrf")
    out = np.empty((years.size, lat.size, 3))
    dates = [_datetime(y) for y in years]
    for start in range(0, lat.size, CHUNK_POSITIONS):
        part = slice(start, start + CHUNK_POSITIONS)
        with contextlib.redirect_stdout(io.StringIO()):  # the package prints its warnings
            east, north, up = ppigrf.igrf(lon[part], lat[part], alt_m[part] / 1000.0, dates)
        out[:, part] = np.stack([north, east, -up], axis=-1).reshape(years.size, -1, 3)
    return out


def _wmm(lat, lon, alt_m, years) -> np.ndarray:
    """(n_years, n_places, 3) north, east, down [nT] from pygeomag (WMM2025)."""
    pygeomag = _package("pygeomag")
    model = pygeomag.GeoMag(coefficients_file="wmm/WMM_2025.COF")
    out = np.empty((years.size, lat.size, 3))
    for i, year in enumerate(years):
        for k in range(lat.size):
            r = model.calculate(
                glat=float(lat[k]), glon=float(lon[k]), alt=float(alt_m[k]) / 1000.0, time=year
            )
            out[i, k] = (r.x, r.y, r.z)
    return out


def _package(name: str):
    try:
        return __import__(name)
    except ImportError:
        raise InputError(f"the geomagnetic models need {name}; {GEOMAG_HINT}") from None


def _datetime(year: float):
    whole = int(np.floor(year))
    start, end = pd.Timestamp(whole, 1, 1), pd.Timestamp(whole + 1, 1, 1)
    return (start + (end - start) * (year - whole)).to_pydatetime()


def evaluate(model: str, lat_deg, lon_deg, alt_m=0.0, when=None) -> ModelField:
    """The model's field at places and times (broadcast together).

    lat_deg, lon_deg : geodetic latitude and longitude. [deg]
    alt_m : height above the WGS 84 ellipsoid. [m]
    when : a date ("2026-06-01", ISO 8601 text, datetime64) or an array of datetime64, UTC.
    Returns a ModelField (floats for scalar inputs). Raises InputError outside the model's range
    or when its package is not installed.
    """
    validation.choice(model, "geomagnetic model", MODELS)
    if when is None:
        raise InputError("the geomagnetic model needs a date (--date YYYY-MM-DD or --time-column)")
    times = np.asarray(when) if np.ndim(when) else parse_date(when)
    lat, lon, alt, times = np.broadcast_arrays(*_check_place(model, lat_deg, lon_deg, alt_m), times)
    shape = lat.shape
    years = decimal_year(times.ravel())
    _check_years(model, years)
    places = np.column_stack([lat.ravel(), lon.ravel(), alt.ravel()])
    unique, inverse = np.unique(places, axis=0, return_inverse=True)
    inverse = np.asarray(inverse).ravel()
    knots = _knots(model, years)
    synthesis = _igrf if model == "igrf" else _wmm
    fields = synthesis(unique[:, 0], unique[:, 1], unique[:, 2], knots)  # (knots, places, 3)
    # The field is linear in time between knots: interpolate each sample exactly.
    slot = np.clip(np.searchsorted(knots, years, side="right") - 1, 0, max(knots.size - 2, 0))
    if knots.size == 1:
        values = fields[0, inverse]
    else:
        t0, t1 = knots[slot], knots[slot + 1]
        weight = ((years - t0) / (t1 - t0))[:, None]
        values = (1 - weight) * fields[slot, inverse] + weight * fields[slot + 1, inverse]
    north, east, down = (values[:, k].reshape(shape) for k in range(3))
    if not shape:
        north, east, down = float(north), float(east), float(down)
    return ModelField(north, east, down)


def _knots(model: str, years: np.ndarray) -> np.ndarray:
    """The ends of the time span and the model's epochs inside it. [year]"""
    low, high = float(years.min()), float(years.max())
    inside = _MODELS[model][5]
    return np.unique(np.concatenate([[low, high], inside[(inside > low) & (inside < high)]]))


@dataclass(frozen=True)
class ReferenceModel:
    """A reference field from a geomagnetic model; position and time constants or log columns.

    Attributes
    ----------
    model : str
        "igrf" (IGRF-14, ppigrf) or "wmm" (WMM2025, pygeomag) (`--reference-model`).
    lat_deg, lon_deg : float, optional
        Constant latitude and longitude (`--lat`, `--lon`). [deg]
    alt_m : float, optional
        Constant altitude above the WGS 84 ellipsoid (`--alt-m`; 0 when neither it nor a column is
        given). [m]
    date : str, optional
        Constant date, YYYY-MM-DD (`--date`).
    lat_column, lon_column : str, optional
        Log columns of latitude and longitude, one value per sample. [deg]
    alt_column : str, optional
        Log column of the altitude. [m]
    time_column : str, optional
        Log column of the time of each sample.

    Examples
    --------
    >>> import nlpcal
    >>> model = nlpcal.ReferenceModel("igrf", lat_deg=52.0, lon_deg=4.9, date="2025-06-01")
    >>> total, provenance = model.field({})  # needs nlpcal[geomag]
    >>> bool(45_000 < total < 55_000), provenance["name"]  # [nT]
    (True, 'IGRF-14')
    """

    model: str
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None
    date: str | None = None
    lat_column: str | None = None
    lon_column: str | None = None
    alt_column: str | None = None
    time_column: str | None = None

    def numeric_columns(self) -> list:
        """The position columns to read from the log (the time column is read apart)."""
        return [c for c in (self.lat_column, self.lon_column, self.alt_column) if c]

    def check(self) -> None:
        """Each quantity given once: a constant or a column (the date or a time column)."""
        validation.choice(self.model, "reference model", MODELS)
        for what, value, column in (
            ("latitude", self.lat_deg, self.lat_column),
            ("longitude", self.lon_deg, self.lon_column),
            ("date", self.date, self.time_column),
        ):
            if (value is None) == (column is None):
                flag = "--date" if what == "date" else f"--{what[:3]}"
                other = "--time-column" if what == "date" else f"--{what[:3]}-column"
                raise InputError(
                    f"--reference-model needs the {what}: give {flag} or {other}, one of them"
                )
        if self.alt_m is not None and self.alt_column is not None:
            raise InputError("give the height as --alt-m or --alt-column, not both")

    def field(self, columns: dict, times=None) -> tuple:
        """(the total field [nT]: a float, or one value per sample; the "model" block of a
        result). columns : the position columns' values; times : the time column (datetime64)."""
        self.check()
        lat = columns[self.lat_column] if self.lat_column else self.lat_deg
        lon = columns[self.lon_column] if self.lon_column else self.lon_deg
        alt = columns[self.alt_column] if self.alt_column else (self.alt_m or 0.0)
        when = times if self.time_column else self.date
        result = evaluate(self.model, lat, lon, alt, when)
        total = result.total_nT
        inputs = {
            "lat_deg": _given(self.lat_column, self.lat_deg),
            "lon_deg": _given(self.lon_column, self.lon_deg),
            "alt_m": _given(self.alt_column, self.alt_m or 0.0),
            "date": _given(self.time_column, None if self.date is None else str(self.date)),
            "height": "above the WGS 84 ellipsoid",
        }
        block = {**model_info(self.model), "inputs": inputs}
        if np.ndim(total):
            block.update(
                total_nT_mean=float(np.mean(total)),
                total_nT_min=float(np.min(total)),
                total_nT_max=float(np.max(total)),
            )
        else:
            block.update(
                total_nT=float(total),
                declination_deg=float(result.declination_deg),
                inclination_deg=float(result.inclination_deg),
            )
        return total, block


def _given(column, value):
    """An input of the record: {"column": name} when read from the log, else the value."""
    return {"column": column} if column else value


def declination(model: str, lat_deg: float, lon_deg: float, alt_m: float = 0.0, date=None):
    """(the model's declination, east positive [deg], the "model" block for a record)."""
    result = evaluate(model, lat_deg, lon_deg, alt_m, date)
    block = {
        **model_info(model),
        "inputs": {"lat_deg": lat_deg, "lon_deg": lon_deg, "alt_m": alt_m, "date": str(date)},
        "declination_deg": float(result.declination_deg),
    }
    return float(result.declination_deg), block
