"""delta F = |B| - F: a vector magnetometer's total field against a scalar reference, by day.

Observatories compare the total field of the vector instrument with the scalar magnetometer's,
delta F = |B| - F; its mean is the baseline difference of the two instruments (and the pier
difference), its spread what the vector's calibration and the lag between the two clocks leave
[J19]. `delta_f_report` gives it before (|B_M|) and after a calibration (|B1|, Eq. 4 in [1]),
for the whole log and for every UTC day of a log that spans days, with the lag of the reference
(`nlpcal.lag`) given, taken from the parameters, or estimated per period.

A fixed sensor (an observatory's) never changes attitude: the field's direction moves by the
field's own variation only, a degree or two in a storm, and no attitude determines the nine
parameters. `attitude_spread` measures it; delta F and the lag are computed all the same (the
lag alone, the parameters held).

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
[J19] Jankowski, J. and Sucksdorff, C. (1996). Guide for magnetic measurements and observatory
    practice. IAGA, Warsaw. ISBN 0-9650686-2-5 (the scalar check of the vector instrument,
    delta F).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from . import lag as lags
from .errors import InputError, QualityError
from .models.zhou2010 import Zhou2010Parameters, correct

#: A log whose field directions stay within this rms angle of their mean [deg] comes from a
#: fixed sensor: a calibration turns the sensor through tens of degrees, a storm moves the
#: field's direction by a degree or two.
FIXED_SENSOR_DEG = 5.0
#: Times from this many seconds on are Unix times (1973 on), whose UTC days group the report;
#: smaller ones are seconds from any origin. [s]
ABSOLUTE_FROM_S = 1e8
SECONDS_PER_DAY = 86400.0


def attitude_spread(samples) -> float:
    """The rms angle of the field directions from their mean direction. [deg]"""
    samples = np.asarray(samples, dtype=float)
    directions = samples / np.linalg.norm(samples, axis=1, keepdims=True)
    mean = directions.mean(axis=0)
    mean /= np.linalg.norm(mean)
    cosines = np.clip(directions @ mean, -1.0, 1.0)
    return float(np.degrees(np.sqrt(np.mean(np.arccos(cosines) ** 2))))


def is_fixed_sensor(samples) -> bool:
    """Whether the attitude does not change (`FIXED_SENSOR_DEG`)."""
    return attitude_spread(samples) < FIXED_SENSOR_DEG


def periods(times) -> list:
    """(label, row mask) of the periods a report gives: "all", and every UTC day
    (YYYY-MM-DD) when the times are absolute and span more than one day."""
    everything = [("all", slice(None))]
    if times is None:
        return everything
    times = np.asarray(times, dtype=float)
    if times.min() < ABSOLUTE_FROM_S:
        return everything
    day = np.floor(times / SECONDS_PER_DAY)
    days = np.unique(day)
    if days.size < 2:
        return everything
    labels = (
        (days * SECONDS_PER_DAY).astype("int64").astype("datetime64[s]").astype("datetime64[D]")
    )
    return everything + [(str(label), day == d) for label, d in zip(labels, days)]


@dataclass(frozen=True)
class Spread:
    """Mean and std (ddof 0) of delta F over a period. [field unit]"""

    mean: float
    std: float

    @classmethod
    def of(cls, values) -> Spread:
        values = np.asarray(values, dtype=float)
        return cls(float(values.mean()), float(values.std()))

    def to_dict(self) -> dict:
        return {"mean": self.mean, "std": self.std}


def delta_f_report(
    samples,
    reference,
    times=None,
    parameters: Zhou2010Parameters | None = None,
    lag=None,
    lag_in_parameters: dict | None = None,
) -> dict:
    """delta F = |B| - F per period (`periods`), before and after the correction.

    samples : (N, 3) raw B_M [unit]; reference : (N,) F [unit]; times : (N,) [s] or None.
    parameters : the correction (None: the "after" columns are left out).
    lag : None, "auto" or seconds (`--lag`): "auto" estimates the lag per period (tau alone,
        `nlpcal.lag.estimate_lag` with no free parameter) and adds the spread of delta F with
        it taken out; seconds take it out of the reference everywhere. None takes the lag of
        the parameters file (`lag_in_parameters`, estimated or given) out, if any.
    Returns {"fixed_sensor", "attitude_spread_deg", "lag_used_s", "periods": [{"period", "n",
    "before", "after", "lag", "after_lag"}]}. [unit], [s]
    """
    samples = np.asarray(samples, dtype=float)
    reference = np.asarray(reference, dtype=float)
    lag = lags.lag_option(lag)
    used = lag_in_force(lag, lag_in_parameters)
    if used or lag == "auto":
        times = lags.check_times(times, reference.size)
    aligned = lags.shifted(reference, times, used) if used else reference
    theta = np.zeros(9) if parameters is None else parameters.theta
    corrected = samples if parameters is None else correct(samples, parameters)
    magnitude = np.linalg.norm(corrected, axis=1)
    raw = np.linalg.norm(samples, axis=1)
    spread = attitude_spread(samples)
    rows = []
    for label, rows_of in periods(times):
        row = {
            "period": label,
            "n": int(np.count_nonzero(np.ones(reference.size, bool)[rows_of])),
            "before": Spread.of(raw[rows_of] - aligned[rows_of]).to_dict(),
        }
        if parameters is not None:
            row["after"] = Spread.of(magnitude[rows_of] - aligned[rows_of]).to_dict()
        if lag == "auto":
            estimate = lags.estimate_lag(
                samples[rows_of], reference[rows_of], times[rows_of], theta, lags.fixed_directions()
            )
            row["lag"] = estimate.to_dict()
            moved = lags.shifted(reference[rows_of], times[rows_of], estimate.seconds or 0.0)
            row["after_lag"] = Spread.of(magnitude[rows_of] - moved).to_dict()
        rows.append(row)
    return {
        "fixed_sensor": spread < FIXED_SENSOR_DEG,
        "attitude_spread_deg": spread,
        "lag_used_s": used,
        "periods": rows,
    }


def undetermined_periods(report: dict) -> list:
    """The periods of a report whose lag was asked for and is undetermined."""
    return [
        row["period"]
        for row in report["periods"]
        if row.get("lag", {}).get("status") == "undetermined"
    ]


def format_report(report: dict, unit: str) -> str:
    """The report as a text table."""
    after = "after" in report["periods"][0]
    lagged = "lag" in report["periods"][0]
    head = f"{'period':<12}{'n':>9}{'mean before':>14}{'std before':>12}"
    head += f"{'mean after':>13}{'std after':>12}" if after else ""
    head += f"{'lag [s]':>11}{'SE [s]':>10}{'std w/ lag':>12}  lag" if lagged else ""
    lines = [f"delta F = |B| - F [{unit}] (before: |B_M|; after: |B1|)", head, "-" * len(head)]
    for row in report["periods"]:
        line = f"{row['period']:<12}{row['n']:>9}"
        line += f"{row['before']['mean']:>14.4f}{row['before']['std']:>12.4f}"
        if after:
            line += f"{row['after']['mean']:>13.4f}{row['after']['std']:>12.4f}"
        if lagged:
            block = row["lag"]
            seconds = block["seconds"] if block["seconds"] is not None else block.get("estimate_s")
            line += f"{_cell(seconds):>11}{_cell(block['standard_error_s']):>10}"
            line += f"{row['after_lag']['std']:>12.4f}  {block['status']}"
        lines.append(line)
    return "\n".join(lines)


def lag_in_force(lag, lag_in_parameters: dict | None) -> float:
    """The lag a correction takes out of the reference: `lag` when a number (`--lag`), 0 for
    "auto" (estimated per period by `delta_f_report`), else the parameters file's. [s]"""
    lag = lags.lag_option(lag)
    if isinstance(lag, float):
        return lag
    return 0.0 if lag == "auto" else lags.seconds_of(lag_in_parameters)


def aligned_log(log, lag, lag_in_parameters: dict | None = None):
    """`log` (`nlpcal.io.Log`) with its reference series moved by the lag in force
    (`lag_in_force`), R(t + tau), so that its rows compare with the field's; the log itself
    when no lag is in force."""
    seconds = lag_in_force(lag, lag_in_parameters)
    if not seconds:
        return log
    if log.reference is None or np.ndim(log.reference) != 1:
        raise InputError(
            "a lag needs a reference series, one value per sample (--reference-column)"
        )
    times = lags.check_times(log.times, len(log.reference))
    return replace(log, reference=lags.shifted(log.reference, times, seconds))


def fixed_sensor_message(spread_deg: float) -> str:
    """Why the nine parameters are not attempted on a fixed sensor's log (`attitude_spread`,
    [deg])."""
    return (
        f"the sensor's attitude does not change (the field's direction stays within "
        f"{spread_deg:.2g} deg rms of its mean, below {FIXED_SENSOR_DEG:g}): no attitude "
        f"determines the nine parameters, so they are not attempted; delta F and the lag are "
        f"computed"
    )


def log_delta_f(log, parameters=None, lag=None, lag_in_parameters: dict | None = None) -> dict:
    """`delta_f_report` of a log read with its reference series and times (`nlpcal.io.Log`).

    parameters : a CalibrationResult (its nine parameters correct the "after" columns) or None.
    """
    if log.reference is None or np.ndim(log.reference) != 1:
        raise InputError("delta F and the lag need a reference series (--reference-column COL)")
    model = parameters.model if parameters is not None else None
    return delta_f_report(log.samples, log.reference, log.times, model, lag, lag_in_parameters)


def check_lags(report: dict) -> None:
    """QualityError when a lag asked for is undetermined in some period of a report."""
    periods = undetermined_periods(report)
    if periods:
        raise QualityError(
            f"lag undetermined in {', '.join(periods)}: dF/dt is too small against the noise "
            f"(its standard error exceeds {lags.MAX_ERROR_SAMPLES:g} of the sample interval)",
            "Lag_Undetermined",
        )


def _cell(value) -> str:
    """A number of the table to 4 decimals, "-" for none."""
    return "-" if value is None else f"{value:.4f}"
