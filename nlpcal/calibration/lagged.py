"""`calibrate(..., lag=...)`: the nine parameters with the lag of a reference series
(`nlpcal.lag`).

A lag given is taken out of the reference by interpolation, R(t + tau), before the calibration.
A lag "auto" is estimated with the nine in one problem (`nlpcal.lag.estimate_lag`) from the
no-lag optimum; the calibration then runs on the reference moved by it, so that its parameters,
Table 1 rows and standard errors describe the joint optimum (their standard errors at the
estimated lag; the correlations with tau are recorded beside it).
"""

from __future__ import annotations

import numpy as np

from .. import lag as lags
from .. import units, validation
from ..delta_f import FIXED_SENSOR_DEG, attitude_spread, fixed_sensor_message
from ..errors import InputError, QualityError
from ..io.lazy import field_samples
from ..models.zhou2010 import Zhou2010Parameters, model_directions
from .result import CalibrationResult

#: Rows, evenly strided, that judge whether the sensor's attitude changes.
FIXED_SENSOR_PROBE = 20_000

#: The arguments of `calibrate` that `calibrate_lagged` takes apart from the others.
LAG_ARGUMENTS = ("samples", "reference_field", "lag", "times")


def calibrate_lagged(calibrate, samples, reference, times, lag, options: dict) -> CalibrationResult:
    """`calibrate(samples, reference_field=..., **options)` with the lag `lag` ("auto" or
    seconds) of the reference series at `times` [s]; a "lag" block in the result. An
    undetermined lag raises QualityError holding the no-lag result."""
    lag = lags.lag_option(lag)
    if reference is None or np.ndim(reference) != 1:
        raise InputError(
            "a lag needs a reference series, one value per sample (--reference-column)"
        )
    rows = field_samples(samples)
    times = lags.check_times(times, len(reference))
    values = np.asarray(reference, dtype=float)
    if isinstance(lag, float):
        result = calibrate(rows, reference_field=lags.shifted(values, times, lag), **options)
        result.lag = lags.given_lag(lag)
        return result
    spread = attitude_spread(rows[:: max(1, len(values) // FIXED_SENSOR_PROBE)])
    if spread < FIXED_SENSOR_DEG:
        raise fixed_sensor_failure(rows, values, times, spread, options)
    first = calibrate(rows, reference_field=values, **options)
    unit = first.unit if first.unit != "raw" else "raw"
    base = units.to_base(validation.samples(rows), options.get("unit") or unit)
    ref_base = units.to_base(values, options.get("reference_unit") or options.get("unit") or unit)
    directions = model_directions(first.model_name, True)
    theta = Zhou2010Parameters.from_dict(first.parameters).theta
    estimate = lags.estimate_lag(base, ref_base, times, theta, directions)
    if not estimate.determined:
        first.lag = estimate.to_dict()
        first.warnings.append(estimate.message())
        raise QualityError(estimate.message(), "Lag_Undetermined", result=first)
    seconds = float(estimate.seconds)  # type: ignore[arg-type]  # determined: a number
    result = calibrate(rows, reference_field=lags.shifted(values, times, seconds), **options)
    result.lag = estimate.to_dict()
    result.notes.append(estimate.message())
    return result


def fixed_sensor_failure(rows, values, times, spread: float, options: dict) -> QualityError:
    """The QualityError of a fixed sensor's log: the nine parameters not attempted, the lag
    estimated alone (`nlpcal.lag.fixed_directions`) and told."""
    unit = options.get("unit") or "nT"
    base = units.to_base(validation.samples(rows), unit)
    ref_base = units.to_base(values, options.get("reference_unit") or unit)
    estimate = lags.estimate_lag(base, ref_base, times, np.zeros(9), lags.fixed_directions())
    return QualityError(
        f"{fixed_sensor_message(spread)}: {estimate.message()}; 'nlpcal stats LOG "
        f"--reference-column COL --time-column COL --lag auto' reports delta F by day",
        "Fixed_Sensor",
    )
