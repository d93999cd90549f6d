"""Sample times, and a reference series on a time base of its own brought onto a log's times.

A scalar reference (a proton or Overhauser magnetometer) is often recorded by another instrument
with its own clock and rate. `reference_at` interpolates it onto the log's times: linearly
(numpy), or by a cubic spline (scipy's `CubicSpline`, not-a-knot ends; `pip install
'nlpcal[spline]'`). Times outside the reference's span get no value (NaN), and neither do times
inside a gap of the reference: a step longer than `GAP_SAMPLES` of its median steps is a gap,
not something to interpolate across. A spline is fitted to each stretch between gaps on its own,
so that a gap does not make it ring. The lag of a reference (`--lag`) re-interpolates it with
the same function at shifted times.

Times are seconds [s]: Unix seconds for absolute times (`seconds` turns datetime64 values and
ISO 8601 text into them), or seconds since any origin, the same for the log and the reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .errors import InputError

#: The interpolations of a reference: linear (numpy) and a cubic spline (scipy).
INTERPOLATIONS = ("linear", "cubic")
#: A step of the reference longer than this many of its median steps is a gap, not
#: interpolated across. [samples]
GAP_SAMPLES = 3.0
INSTALL = "--interpolation cubic needs scipy: pip install 'nlpcal[spline]'"


def seconds(column) -> np.ndarray:
    """Times as seconds, NaN where a value is not a time. [s]

    datetime64 values and ISO 8601 text become Unix seconds; numbers (or text that is all
    numbers) are taken as seconds as they are (Unix seconds, or since any origin).
    """
    series = pd.Series(column)
    if pd.api.types.is_datetime64_any_dtype(series):
        if getattr(series.dt, "tz", None) is not None:
            series = series.dt.tz_convert("UTC").dt.tz_localize(None)
        values = series.to_numpy(dtype="datetime64[ns]")
        out = values.astype("int64") / 1e9
        return np.where(np.isnat(values), np.nan, out)
    numeric = pd.to_numeric(series, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
    if np.isfinite(numeric).sum() * 2 > len(numeric):
        return numeric
    parsed = pd.to_datetime(series.astype(str), errors="coerce", utc=True, format="ISO8601")
    values = parsed.dt.tz_localize(None).to_numpy(dtype="datetime64[ns]")
    return np.where(np.isnat(values), np.nan, values.astype("int64") / 1e9)


def check_kind(kind: str) -> None:
    """InputError unless `kind` is one of INTERPOLATIONS."""
    if kind not in INTERPOLATIONS:
        choices = ", ".join(INTERPOLATIONS)
        raise InputError(f"--interpolation must be one of {choices}, got {kind!r}")


def _checked(times_ref, values_ref) -> tuple:
    """The reference's times [s] and values as floats, in time order, one value per time."""
    times_ref = np.asarray(times_ref, dtype=float).ravel()
    values_ref = np.asarray(values_ref, dtype=float).ravel()
    if times_ref.shape != values_ref.shape:
        raise InputError(
            f"the reference has {times_ref.size} times and {values_ref.size} values; give one "
            f"time per value"
        )
    if not (np.isfinite(times_ref).all() and np.isfinite(values_ref).all()):
        raise InputError("the reference's times and values must be finite numbers")
    order = np.argsort(times_ref, kind="stable")
    times_ref, values_ref = times_ref[order], values_ref[order]
    if times_ref.size < 2 or times_ref[-1] == times_ref[0]:
        raise InputError("the reference needs at least two samples at different times")
    if (np.diff(times_ref) == 0).any():
        repeated = int((np.diff(times_ref) == 0).sum())
        raise InputError(f"the reference repeats {repeated} time(s); each time must have one value")
    return times_ref, values_ref


def reference_at(times_ref, values_ref, times, kind: str = "linear", gap_samples=GAP_SAMPLES):
    """The reference interpolated at `times`: NaN outside its span and inside its gaps.

    Parameters
    ----------
    times_ref : array_like, shape (M,)
        Times of the reference's samples, in any order, each once. [s]
    values_ref : array_like, shape (M,)
        The reference's values (a field magnitude, say). [unit of the reference]
    times : array_like, shape (N,)
        The times wanted (the log's rows, shifted by a lag). [s]
    kind : {"linear", "cubic"}
        Linear interpolation, or a not-a-knot cubic spline per stretch between gaps.
    gap_samples : float
        A step longer than this many median steps of the reference is a gap. [samples]

    Returns
    -------
    numpy.ndarray, shape (N,)
        The reference at `times`, NaN where it is not interpolated. [unit of the reference]
    """
    if kind not in INTERPOLATIONS:
        raise InputError(
            f"--interpolation must be one of {', '.join(INTERPOLATIONS)}, got {kind!r}"
        )
    times_ref, values_ref = _checked(times_ref, values_ref)
    times = np.asarray(times, dtype=float).ravel()
    origin = times_ref[0]  # spline times near zero: Unix seconds lose digits in cubic terms
    t_ref, t = times_ref - origin, times - origin
    steps = np.diff(t_ref)
    gap = steps > gap_samples * float(np.median(steps))
    # the interval [t_ref[i], t_ref[i + 1]] each time falls in (the last one for the last time)
    at = np.clip(np.searchsorted(t_ref, t, side="right") - 1, 0, t_ref.size - 2)
    inside = np.isfinite(t) & (t >= t_ref[0]) & (t <= t_ref[-1])
    usable = inside & ~(gap[at] & (t > t_ref[at]) & (t < t_ref[at + 1]))
    out = np.full(t.shape, np.nan)
    if kind == "linear":
        out[usable] = np.interp(t[usable], t_ref, values_ref)
        return out
    try:
        from scipy.interpolate import CubicSpline
    except ImportError:
        raise InputError(INSTALL) from None
    stretch = np.concatenate([[0], np.cumsum(gap)])  # the stretch of each reference sample
    for k in np.unique(stretch):
        mine = stretch == k
        wanted = usable & (stretch[at] == k) & (t >= t_ref[mine][0]) & (t <= t_ref[mine][-1])
        if mine.sum() >= 2 and wanted.any():
            out[wanted] = CubicSpline(t_ref[mine], values_ref[mine])(t[wanted])
    return out


@dataclass
class Interpolated:
    """A reference brought onto a log's times (`interpolate_reference`).

    values : the reference at each time, NaN where not interpolated. [unit of the reference]
    outside : times outside the reference's span. in_gaps : times inside its gaps.
    gaps : the gaps of the reference. step_s : its median step. [s] kind : the interpolation.
    """

    values: np.ndarray
    outside: int
    in_gaps: int
    gaps: int
    step_s: float
    kind: str

    def notes(self, what: str = "the reference") -> list:
        """What the interpolation decided, for the user to read."""
        said = [
            f"{what} interpolated onto the log's times ({self.kind}; its step {self.step_s:g} s)"
        ]
        if self.outside:
            said.append(f"dropped {self.outside} row(s) of the log outside the span of {what}")
        if self.gaps:
            said.append(
                f"{what} has {self.gaps} gap(s) longer than {GAP_SAMPLES:g} of its steps, not "
                f"interpolated across: dropped {self.in_gaps} row(s) of the log inside them"
            )
        return said

    def to_dict(self) -> dict:
        return {
            "interpolation": self.kind,
            "step_s": self.step_s,
            "rows_outside_span": self.outside,
            "gaps": self.gaps,
            "rows_in_gaps": self.in_gaps,
        }


def interpolate_reference(times_ref, values_ref, times, kind: str = "linear") -> Interpolated:
    """`reference_at`, with the count of the times it leaves without a value and why."""
    values = reference_at(times_ref, values_ref, times, kind)
    t_ref, _ = _checked(times_ref, values_ref)
    times = np.asarray(times, dtype=float).ravel()
    steps = np.diff(t_ref)
    step = float(np.median(steps))
    outside = int((~((times >= t_ref[0]) & (times <= t_ref[-1]))).sum())
    return Interpolated(
        values=values,
        outside=outside,
        in_gaps=int(np.isnan(values).sum()) - outside,
        gaps=int((steps > GAP_SAMPLES * step).sum()),
        step_s=step,
        kind=kind,
    )
