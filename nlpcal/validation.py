"""Every check of numbers that enter nlpcal, shared by the library and the command line.

Each check returns the value in the form nlpcal computes with, or raises `InputError` with one
sentence that says what was received, what was expected and how to fix it. Documents read from
files are checked field by field with `nlpcal.results.DocumentReader`, which calls these.
"""

from __future__ import annotations

import math
from numbers import Integral

import numpy as np

from . import passes
from .errors import InputError

#: Fewest samples accepted for the nine parameters: nine plus the mean field of Eq. 8.
MIN_SAMPLES = 10
#: Rows per chunk when validating, so that a memory-mapped log is never copied whole.
CHECK_CHUNK_ROWS = 65536
#: Largest angle accepted anywhere: at 90 deg axes become parallel and matrices singular. [deg]
MAX_ANGLE_DEG = 89.0
#: Largest |value| of a sample in any unit: beyond it squares overflow in the moments (1e12
#: nT is a thousand tesla). [sample unit]
MAX_SAMPLE_VALUE = 1e12
#: The largest sample magnitude must reach this: below it no field unit or count makes sense and
#: squares underflow. [sample unit]
MIN_SAMPLE_MAGNITUDE = 1e-9
#: An axis whose values vary by less than this fraction of the largest magnitude never saw the
#: field change (the rounding of the values, not the field). [1]
MIN_AXIS_SPREAD = 1e-12
#: A reference field must lie within this factor of the mean magnitude of the samples: further
#: out it is in another unit, or of another sensor (scale errors of 0.9 or 9). [1]
REFERENCE_RATIO = 10.0


def fmt_list(values) -> str:
    """Numbers as "[a, b, c]" for messages."""
    return "[" + ", ".join(f"{v:g}" for v in np.asarray(values, dtype=float).ravel()) + "]"


def number(
    value, what: str, *, positive: bool = False, minimum=None, maximum=None, unit: str = ""
) -> float:
    """A finite float, optionally positive or within [minimum, maximum]."""
    suffix = f" {unit}" if unit else ""
    try:
        result = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number{suffix}, got {value!r}") from None
    if not math.isfinite(result):
        raise InputError(f"{what} must be a finite number{suffix}, got {result:g}")
    if positive and not result > 0:
        raise InputError(f"{what} must be a positive number{suffix}, got {result:g}")
    if minimum is not None and result < minimum:
        raise InputError(f"{what} must be at least {minimum:g}{suffix}, got {result:g}")
    if maximum is not None and result > maximum:
        raise InputError(f"{what} must be at most {maximum:g}{suffix}, got {result:g}")
    return result


def optional_number(value, what: str, **kw):
    """None, or `number(value, what, **kw)`."""
    return None if value is None else number(value, what, **kw)


def count(value, what: str, *, minimum: int = 1) -> int:
    """An integer of at least `minimum`."""
    try:
        result = int(value)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{what} must be an integer, got {value!r}") from None
    if result != value and not (isinstance(value, float) and value.is_integer()):
        raise InputError(f"{what} must be an integer, got {value!r}")
    if result < minimum:
        raise InputError(f"{what} must be at least {minimum}, got {result}")
    return result


def optional_whole(value, what: str) -> int | None:
    """None, or a whole number (of an integer type, not a bool) of at least 1: a count of threads
    or of processes."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise InputError(f"{what} must be a whole number of at least 1, got {value!r}")
    return count(value, what)


#: Largest device id: ArduPilot's COMPASS_DEV_ID and PX4's CAL_MAGn_ID are 32-bit signed
#: parameters (AP_Int32, int32), and 0 means "no device" in both.
MAX_SENSOR_ID = 2**31 - 1
#: Longest sensor name accepted as a sensor id. [characters]
MAX_SENSOR_NAME = 100


def sensor_id(value, what: str = "--sensor-id") -> int | str:
    """A sensor's identity: an autopilot device id (an integer 1 .. 2^31 - 1; a string of
    decimal digits is read as one) or a name (1 to MAX_SENSOR_NAME printable characters)."""
    if isinstance(value, str) and value.strip().lstrip("+-").isdigit():
        value = int(value.strip())
    if isinstance(value, bool) or not isinstance(value, (Integral, str)):
        raise InputError(f"{what} must be a device id (an integer) or a name, got {value!r:.40}")
    if isinstance(value, Integral):
        if not 1 <= int(value) <= MAX_SENSOR_ID:
            raise InputError(
                f"{what} must be a device id from 1 to {MAX_SENSOR_ID} (0 means no device), "
                f"got {value}"
            )
        return int(value)
    if not value.strip() or len(value) > MAX_SENSOR_NAME or not value.isprintable():
        raise InputError(
            f"{what} must be 1 to {MAX_SENSOR_NAME} printable characters, got {value!r:.40}"
        )
    return value


def choice(value, what: str, options) -> str:
    if value not in options:
        raise InputError(f"unknown {what} {value!r}; expected one of {', '.join(options)}")
    return value


def vectors(values, what: str = "samples", *, minimum: int = 1, purpose: str = "") -> np.ndarray:
    """An (N, 3) float64 array with at least `minimum` rows (finite values not checked here); a
    Dask array stays where it is, as `nlpcal.passes.LazySamples`."""
    try:
        array = passes.as_rows(values)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be numeric, an (N, 3) array-like") from None
    if array.ndim != 2 or array.shape[1] != 3:
        raise InputError(f"{what} must have shape (N, 3), got {array.shape}")
    if array.shape[0] < minimum:
        need = f" {purpose}" if purpose else ""
        raise InputError(f"got {array.shape[0]} {what}, need at least {minimum}{need}")
    return array


def finite_vectors(
    values, what: str = "samples", *, minimum: int = 1, purpose: str = ""
) -> np.ndarray:
    """`vectors` whose every value is finite, checked chunk by chunk (memory maps stay mapped)."""
    array = vectors(values, what, minimum=minimum, purpose=purpose)
    for start in range(0, array.shape[0], CHECK_CHUNK_ROWS):
        if not np.isfinite(array[start : start + CHECK_CHUNK_ROWS]).all():
            raise InputError(f"{what} contain NaN or infinite values; drop or fix those rows")
    return array


def samples(
    values, *, minimum: int = MIN_SAMPLES, purpose: str = "for nine parameters"
) -> np.ndarray:
    """Field samples from many attitudes, (N, 3) float64: finite, not all equal, and no axis
    constant."""
    array = vectors(values, "samples", minimum=minimum, purpose=purpose)
    low, high, largest = sample_sizes(array)
    if np.all(low == high):
        raise InputError("all samples are equal; calibration needs many attitudes")
    if np.any(high - low <= MIN_AXIS_SPREAD * largest):
        axes = ", ".join("xyz"[k] for k in np.flatnonzero(high - low <= MIN_AXIS_SPREAD * largest))
        raise InputError(
            f"the {axes} column is constant: that axis never saw the field change; "
            f"calibration needs attitudes that turn every axis"
        )
    return array


def sample_sizes(array) -> tuple:
    """(per-column minimum, maximum, largest |value|) of (N, 3) samples, refused when a value
    is not finite or the samples are too large or too small in any unit for their squares
    (MAX_SAMPLE_VALUE, MIN_SAMPLE_MAGNITUDE): every log is checked so when read. [sample unit]"""
    low, high = axis_ranges(array)
    if not (np.isfinite(low).all() and np.isfinite(high).all()):
        raise InputError("samples contain NaN or infinite values; drop or fix those rows")
    largest = float(np.max(np.maximum(np.abs(low), np.abs(high))))
    not_too_large(largest)
    if largest < MIN_SAMPLE_MAGNITUDE:
        raise InputError(
            f"the samples are at most {largest:.3g} in size, below "
            f"{MIN_SAMPLE_MAGNITUDE:g} in any unit; check the columns and their unit"
        )
    return low, high, largest


def not_too_large(largest: float) -> None:
    """Refuse samples whose largest |value| exceeds MAX_SAMPLE_VALUE (a log read in chunks
    checks each chunk so, before anything computes with it). [sample unit]"""
    if largest > MAX_SAMPLE_VALUE:
        raise InputError(
            f"samples reach {largest:.3g}, beyond {MAX_SAMPLE_VALUE:g} in any unit; "
            f"check the columns and their unit"
        )


def axis_ranges(array) -> tuple:
    """Per-column minimum and maximum of an (N, 3) array, NaN where a column has a NaN, in
    chunks (a memory map stays mapped; a Dask log gives those of its survey)."""
    return passes.axis_ranges(array, CHECK_CHUNK_ROWS)


def reference(value, n: int, what: str = "the reference field"):
    """None, a positive number, or N positive values (a series sampled with the log)."""
    if value is None:
        return None
    if passes.is_lazy(value):
        return _lazy_reference(passes.as_rows(value), n, what)
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number or an array of numbers") from None
    if array.ndim == 0:
        return number(array, what, positive=True)
    array = array.ravel()
    if array.size != n:
        raise InputError(f"{what} has {array.size} values for {n} samples")
    if not np.isfinite(array).all():
        raise InputError(f"{what} contains NaN or infinite values")
    if (array <= 0).any():
        raise InputError(
            f"{what} has {int((array <= 0).sum())} non-positive value(s); a field "
            f"magnitude must be positive"
        )
    return array


def _lazy_reference(values, n: int, what: str):
    """`reference` for a Dask series, from its survey."""
    if values.ndim != 1 or values.shape[0] != n:
        raise InputError(f"{what} has shape {values.shape} for {n} samples")
    survey = values.survey()
    if not (np.isfinite(survey.low).all() and np.isfinite(survey.high).all()):
        raise InputError(f"{what} contains NaN or infinite values")
    if survey.nonpositive.sum():
        raise InputError(
            f"{what} has {int(survey.nonpositive.sum())} non-positive value(s); a field "
            f"magnitude must be positive"
        )
    return values


def magnitudes(vectors) -> np.ndarray:
    """|v| of each row of (N, 3) vectors, as `np.linalg.norm(vectors, axis=1)` sums the squares
    (x^2 + y^2 first), by column: numpy's reduction over rows of three takes several times as
    long. [vector unit]"""
    squares = np.square(np.asarray(vectors, dtype=float))
    return np.sqrt(squares[:, 0] + squares[:, 1] + squares[:, 2])


def mean_magnitude(samples, most: int = 100_000) -> float:
    """The mean |sample| over an even stride of at most `most` samples. [sample unit]"""
    step = max(1, samples.shape[0] // most)
    return float(magnitudes(samples[::step]).mean())


def reference_scale(reference, magnitude: float, what: str = "the reference field") -> None:
    """A reference field within REFERENCE_RATIO of the samples' mean magnitude `magnitude`."""
    if reference is None or not magnitude > 0:
        return
    values = np.atleast_1d(passes.in_memory(reference, 100_000))
    ratio = float(np.median(values)) / magnitude
    if not 1.0 / REFERENCE_RATIO < ratio < REFERENCE_RATIO:
        raise InputError(
            f"{what} ({float(np.median(values)):.6g}) is {ratio:.3g} times the mean "
            f"magnitude of the samples ({magnitude:.6g}); they must be in the same "
            f"unit and of the same field"
        )


def _per_sample(values, n: int | None, what: str, unit: str) -> np.ndarray:
    """N finite numbers, one per sample (any number without `n`), called `what` in messages,
    in `unit`."""
    try:
        array = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError(f"the {what} must be numbers [{unit}]") from None
    if n is not None and array.size != n:
        raise InputError(f"got {array.size} {what} for {n} samples")
    if not np.isfinite(array).all():
        raise InputError(f"the {what} contain NaN or infinite values; drop or fix those rows")
    return array


def channel(values, n: int | None, what: str) -> np.ndarray:
    """N finite numbers of a channel logged with the samples (an aux channel, say), any number
    of them without `n`. [the channel's unit]"""
    return _per_sample(values, n, f"values of {what}", "its unit")


def times(values, n: int) -> np.ndarray:
    """N finite times: Unix seconds, or seconds since any origin. [s]"""
    return _per_sample(values, n, "times", "s")


def temperature(values, n: int) -> np.ndarray:
    """N finite temperatures. [degC]"""
    return _per_sample(values, n, "temperatures", "degC")


def angles(
    values, what: str = "angles", size: int = 3, names: str = "alpha beta gamma"
) -> np.ndarray:
    """`size` finite angles, each within +-MAX_ANGLE_DEG. [deg]"""
    try:
        array = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError(f"{what} must be {size} numbers ({names}) in degrees") from None
    if array.size != size:
        raise InputError(f"got {array.size} {what}, expected {size} ({names}) in degrees")
    if not np.isfinite(array).all():
        raise InputError(f"{what} must be finite, got {fmt_list(array)} deg")
    if (np.abs(array) > MAX_ANGLE_DEG).any():
        raise InputError(
            f"{what} must lie within +-{MAX_ANGLE_DEG:g} deg (the axes become "
            f"parallel at 90 deg), got {fmt_list(array)} deg"
        )
    return array


def renamed(value, former, name: str, former_name: str):
    """A keyword renamed to mirror its command-line flag (`reference_field=` for
    `--reference-field`): the value given under either name. The former name stays accepted;
    both names with different values are an error."""
    if former is None:
        return value
    if value is not None and not np.array_equal(value, former):
        raise InputError(
            f"{name}={value!r} and its former name {former_name}={former!r} differ; "
            f"pass {name} alone"
        )
    return former


def field(value, what: str = "field") -> float:
    """A positive finite field magnitude. [nT]"""
    return number(value, f"the {what}", positive=True, unit="in nT")


def bounds(values) -> np.ndarray:
    """One bound for all three angles or three bounds; each in (0, MAX_ANGLE_DEG]. [deg]"""
    try:
        array = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError("the bound must be one or three positive numbers in degrees") from None
    if array.size == 1:
        array = np.repeat(array, 3)
    if array.size != 3:
        raise InputError(f"got {array.size} bounds, expected 1 or 3 (alpha beta gamma) in degrees")
    if not np.isfinite(array).all() or (array <= 0).any() or (array > MAX_ANGLE_DEG).any():
        raise InputError(
            f"bounds must lie in (0, {MAX_ANGLE_DEG:g}] deg, got {fmt_list(array)} deg"
        )
    return array


def matrix(values, what: str, shape=(3, 3), *, invertible: bool = False) -> np.ndarray:
    """A finite float matrix of `shape`; with `invertible`, well conditioned enough to invert."""
    try:
        array = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a {shape[0]} x {shape[1]} matrix of numbers") from None
    if array.shape != tuple(shape):
        raise InputError(
            f"{what} must be a {shape[0]} x {shape[1]} matrix, got shape {array.shape}"
        )
    if not np.isfinite(array).all():
        raise InputError(f"{what} contains NaN or infinite values")
    if invertible and not np.linalg.cond(array) < 1e12:
        raise InputError(f"{what} is singular (or nearly): it cannot be inverted")
    return array
