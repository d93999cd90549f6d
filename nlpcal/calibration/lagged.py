"""`calibrate(..., lag=...)`: the nine parameters with the lag of a reference series
(`nlpcal.lag`).

A lag given is taken out of the reference by interpolation, R(t + tau), before the calibration.
A lag "auto" is estimated with the nine in one problem (`nlpcal.lag.estimate_lag`) from the
no-lag optimum; the calibration then runs on the reference moved by it, so that its parameters,
Table 1 rows and standard errors describe the joint optimum (their standard errors at the
estimated lag; the correlations with tau are recorded beside it).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .. import lag as lags
from .. import units, validation
from ..delta_f import FIXED_SENSOR_DEG, attitude_spread, fixed_sensor_message
from ..errors import InputError, QualityError
from ..io.lazy import field_samples
from ..io.logs import settle_unit
from ..models.zhou2010 import Zhou2010Parameters, model_directions
from .result import CalibrationResult
from .settings import LagSettings

#: Rows, evenly strided, that judge whether the sensor's attitude changes.
FIXED_SENSOR_PROBE = 20_000

#: The arguments of `calibrate` that `calibrate_lagged` takes apart from the others.
LAG_ARGUMENTS = ("samples", "reference_field", "lag", "times", "lag_tolerance")


def calibrate_lagged(
    calibrate, samples, reference, settings: LagSettings, options: dict
) -> CalibrationResult:
    """`calibrate(samples, reference_field=..., **options)` with the lag of the reference series
    `settings.value` ("auto" or seconds) at `settings.times` [s]; a "lag" block in the result.
    An undetermined lag raises QualityError holding the no-lag result."""
    lag, times = settings.value, settings.times
    if reference is None or np.ndim(reference) != 1:
        raise InputError(
            "a lag needs a reference series, one value per sample (--reference-column)"
        )
    rows = field_samples(samples)
    times = lags.check_times(times, len(reference))
    settings = replace(settings, times=times)
    values = np.asarray(reference, dtype=float)
    if isinstance(lag, float):
        lags.check_span(lag, times)
        result = calibrate_moved(calibrate, rows, values, times, lag, options)
        result.lag = lags.given_lag(lag)
        return result
    spread = attitude_spread(rows[:: max(1, len(values) // FIXED_SENSOR_PROBE)])
    if spread < FIXED_SENSOR_DEG:
        raise fixed_sensor_failure(rows, values, settings, spread, options)
    first = calibrate(rows, reference_field=values, **options)
    base, ref_base = in_base(rows, values, options)
    directions = model_directions(first.model_name, True)
    theta = Zhou2010Parameters.from_dict(first.parameters).theta
    estimate = lags.estimate_lag(base, ref_base, times, theta, directions, settings.tolerance)
    colour = estimate.colour_warning()
    if colour:
        first.warnings.append(colour)
    if not estimate.determined:
        first.lag = estimate.to_dict()
        first.warnings.append(estimate.message())
        raise QualityError(estimate.message(), "Lag_Undetermined", result=first)
    seconds = float(estimate.seconds)  # type: ignore[arg-type]  # determined: a number
    result = calibrate_moved(calibrate, rows, values, times, seconds, options)
    result.lag = estimate.to_dict()
    result.notes.append(estimate.message())
    result.warnings.extend([colour] if colour else [])
    return result


def in_base(rows, values, options: dict) -> tuple:
    """(samples, reference) in the base unit, the samples' unit settled as `calibrate` settles
    it (`unit=`, else nT assumed and taken as raw counts when the magnitudes are far from
    Earth's field, `nlpcal.io.logs.settle_unit`), the reference's `reference_unit=` or the
    samples' unit. [nT or raw]"""
    given = options.get("unit")
    unit = given or "nT"
    samples = units.to_base(validation.samples(rows), unit)
    samples, unit, _ = settle_unit(samples, unit, "option" if given else "assumed")
    return samples, units.to_base(values, options.get("reference_unit") or unit)


def calibrate_moved(calibrate, rows, values, times, seconds: float, options: dict):
    """`calibrate` on the rows that keep a reference once the lag `seconds` [s] is taken out of
    it (`nlpcal.lag.kept_rows`), R(t + tau); a note counts the rows dropped at the ends."""
    kept = lags.kept_rows(times, seconds)
    moved = lags.shifted(values, times, seconds)
    result = calibrate(rows[kept], reference_field=moved, **options)
    dropped = len(values) - len(moved)
    if dropped:
        result.notes.append(lags.dropped_note(dropped, seconds))
    return result


def fixed_sensor_failure(
    rows, values, settings: LagSettings, spread: float, options: dict
) -> QualityError:
    """The QualityError of a fixed sensor's log: the nine parameters not attempted, the lag
    estimated alone (`nlpcal.lag.fixed_directions`) and told."""
    base, ref_base = in_base(rows, values, options)
    estimate = lags.estimate_lag(
        base, ref_base, settings.times, np.zeros(9), lags.fixed_directions(), settings.tolerance
    )
    colour = estimate.colour_warning()
    return QualityError(
        f"{fixed_sensor_message(spread)}: {estimate.message()}{'; ' + colour if colour else ''}"
        f"; 'nlpcal stats LOG "
        f"--reference-column COL --time-column COL --lag auto' reports delta F by day",
        "Fixed_Sensor",
    )
