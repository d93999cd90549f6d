"""Beyond Liu et al. (2022): the nine parameters and the temperature coefficients from one log.

"common" is the paper's assumption (Eq. 2 and 9 of [1]: one factor k(t) = 1 + c (t - t0) on
scale and offset of all axes); "per-axis" gives each axis its own linear scale and offset drift,
the angles temperature-free as the paper argues; "full" adds a linear drift of each angle. For
long records the scale factors can also drift in time (`time_drift`: "common" or "per-axis",
`nlpcal.models.time_drift`). The objective is the mean square of the
residuals whose RMSE is Eq. 10 in [1]; it is minimised by Levenberg-Marquardt steps, each an IPOPT
problem of fixed size built once (`nlpcal.nlp.temperature`).

References
----------
[1] Liu H., Li Y., Ding X., Feng C. (2022), see `nlpcal.models.liu2022`.
[2] Zhou C., Jin J., Li H., Zhang B., Yan H. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .. import inference, units, validation
from ..calibration.result import (
    BlockSolve,
    CalibrationResult,
    Identifiability,
    Reference,
    SolverReport,
)
from ..errors import InputError
from ..models import liu2022
from ..models.liu2022 import TEMPERATURE_MODELS, TemperatureModel
from ..models.time_drift import DAY_S, TIME_DRIFTS, TimeDrift
from ..models.zhou2010 import PARAMETER_NAMES, Zhou2010Parameters
from ..models.zhou2010 import correct as zhou_correct
from ..moments import sphere_frame
from ..nlp.blocks import variable_scale
from ..nlp.temperature import (
    NO_TEMPERATURE,
    STEP_OPTIONS,
    gauss_newton_pass,
    minimise,
    n_coefficients,
)
from ..results import Document, DocumentReader, Provenance, TableRow
from ..statistics import format_table
from ..verdict import Verdict
from .evaluation import evaluation_row

#: A temperature span below this is too small to determine temperature coefficients. [degC]
MIN_SPAN_DEGC = 0.5
#: Warn when a temperature coefficient's standard error exceeds this fraction of its variable
#: scale (its typical size). [1]
POOR_TEMPERATURE_SE = 0.5
#: The temperature model of a time drift alone: every slope zero, the nine parameters at every
#: temperature (`TemperatureCalibrationResult.apply` without a temperature model).
NEUTRAL = TemperatureModel("per-axis", 0.0)


def coefficient_names(kind: str, time_drift: str = "none") -> tuple:
    """Names of the coefficients of a temperature model and a time drift."""
    if kind == "common":
        names: tuple = ("k_slope_per_degC",)
    elif kind == NO_TEMPERATURE:
        names = ()
    else:
        names = tuple(f"scale_slope_{a}_per_degC" for a in "xyz") + tuple(
            f"offset_slope_{a}_per_degC" for a in "xyz"
        )
    if kind == "full":
        names += tuple(f"{angle}_slope_deg_per_degC" for angle in ("alpha", "beta", "gamma"))
    if time_drift == "common":
        names += ("scale_slope_per_day",)
    elif time_drift == "per-axis":
        names += tuple(f"scale_slope_{a}_per_day" for a in "xyz")
    return names


def coefficient_scale(
    kind: str, radius: float, max_dt: float, time_drift: str = "none", max_days: float = 1.0
) -> np.ndarray:
    """Typical sizes of the coefficients: a change of the field by 1e-3 over the log's largest
    |t - t0| (scale [1/degC]; offsets [field/degC]; angles [rad/degC]) and over its largest
    |tau| from its middle (time drift [1/d])."""
    span = max(max_dt, 1.0)
    sizes = [1e-3 / span] if kind == "common" else [1e-3 / span] * 3 + [1e-3 * radius / span] * 3
    sizes = [] if kind == NO_TEMPERATURE else sizes
    if kind == "full":
        sizes += [1e-3 / span] * 3
    sizes += [1e-3 / max(max_days, 1e-6)] * {"none": 0, "common": 1, "per-axis": 3}[time_drift]
    return np.array(sizes)


def theta_of(
    params: Zhou2010Parameters, model: TemperatureModel, drift: TimeDrift | None = None
) -> np.ndarray:
    """The internal vector: the nine parameters (`Zhou2010Parameters.theta`), then the model's
    coefficients (angles' in rad/degC), then the time drift's."""
    if model.kind == "common":
        parts = [params.theta, [model.k_slope_per_degC]]
    else:
        parts = [params.theta, model.scale_slope_per_degC, model.offset_slope_per_degC]
    if model.kind == "full":
        parts.append(np.radians(model.angle_slope_deg_per_degC))
    if drift is not None and drift.kind != "none":
        slopes = drift.scale_slope_per_day
        parts.append(slopes[:1] if drift.kind == "common" else slopes)
    return np.concatenate([np.asarray(p, dtype=float) for p in parts])


def model_of(theta, kind: str, t0: float, time_drift: str = "none", t_ref: float = 0.0):
    """(Zhou2010Parameters, TemperatureModel or None (NO_TEMPERATURE), TimeDrift) of an
    internal vector."""
    params = Zhou2010Parameters.from_theta(theta[:9])
    model: TemperatureModel | None = None
    if kind == "common":
        model = TemperatureModel("common", t0, k_slope_per_degC=float(theta[9]))
    elif kind != NO_TEMPERATURE:
        model = TemperatureModel(
            kind,
            t0,
            scale_slope_per_degC=tuple(map(float, theta[9:12])),
            offset_slope_per_degC=tuple(map(float, theta[12:15])),
            angle_slope_deg_per_degC=tuple(map(float, np.degrees(theta[15:18])))
            if kind == "full"
            else (0.0, 0.0, 0.0),
        )
    first = 9 + n_coefficients(kind)
    slopes = [float(v) for v in theta[first:]]
    drift = TimeDrift(
        time_drift, t_ref, tuple(slopes * 3 if len(slopes) == 1 else slopes or [0.0] * 3)
    )
    return params, model, drift


def read_temperature_model(reader: DocumentReader) -> TemperatureModel:
    """A TemperatureModel from its document block, every field checked."""
    kind = reader.string("kind", options=TEMPERATURE_MODELS)
    t0 = reader.number("base_temperature_degC", minimum=-273.15, maximum=1000.0)
    if kind == "common":
        return TemperatureModel(
            kind, t0, k_slope_per_degC=reader.number("k_slope_per_degC", minimum=-1.0, maximum=1.0)
        )
    return TemperatureModel(
        kind,
        t0,
        scale_slope_per_degC=tuple(reader.array("scale_slope_per_degC", (3,))),
        offset_slope_per_degC=tuple(reader.array("offset_slope_per_degC", (3,))),
        angle_slope_deg_per_degC=tuple(reader.array("angle_slope_deg_per_degC", (3,)))
        if kind == "full"
        else (0.0, 0.0, 0.0),
    )


def read_time_drift(reader: DocumentReader) -> TimeDrift:
    """A TimeDrift from its document block ("time_drift"), every field checked."""
    return TimeDrift(
        reader.string("kind", options=TIME_DRIFTS),
        reader.number("reference_time_s"),
        tuple(reader.array("scale_slope_per_day", (3,))),
    )


@dataclass
class TemperatureCalibrationResult(Document):
    """The nine parameters at t0 and a temperature model, estimated together.

    Attributes
    ----------
    calibration : CalibrationResult
        The nine parameters at the base temperature t0 (so a reader that knows nothing of
        temperature still finds the system correction at t0).
    temperature_model : TemperatureModel or None
        How the parameters change with temperature; None for a time drift alone (no
        "temperature_model" in the document).
    temperature_column : str or None
        The log column the model was fitted with (used by `nlpcal apply`).
    temperature_range : tuple
        (min, max) of the calibration log. [degC]
    temperature_standard_errors : dict or None
        Standard errors of the temperature coefficients, in their units.
    time_drift : TimeDrift or None
        A drift of the scale factors in time, or None ("time_drift" in the document).
    time_column : str or None
        The log column of times the time drift was fitted with.
    time_drift_standard_errors : dict or None
        Standard errors of the time drift's coefficients. [1/d]

    Examples
    --------
    >>> import numpy as np
    >>> import nlpcal
    >>> t = np.linspace(0.0, 20.0, 600)
    >>> samples = nlpcal.simulate(600, seed=2)[["bx", "by", "bz"]].to_numpy()
    >>> result = nlpcal.calibrate_temperature(samples, t, 49462.0, base_temperature=10.0)
    >>> corrected = result.apply(samples, t)  # Eq. 4 with the parameters at each t [nT]
    >>> corrected.shape
    (600, 3)
    """

    FORMAT = "nlpcal-temperature-calibration"
    LEGACY_FORMATS = (("temperature_model", None),)
    WHAT = "nlpcal temperature parameters file"
    #: It holds the nine parameters of the system correction itself.
    carries_parameters = True

    calibration: CalibrationResult
    temperature_model: TemperatureModel | None
    temperature_column: str | None = None
    temperature_range: tuple = (float("nan"), float("nan"))
    temperature_standard_errors: dict | None = None
    time_drift: TimeDrift | None = None
    time_column: str | None = None
    time_drift_standard_errors: dict | None = None

    @property
    def model(self) -> Zhou2010Parameters:
        return self.calibration.model

    @property
    def parameters(self) -> dict:
        return self.calibration.parameters

    @property
    def statistics(self) -> list:
        return self.calibration.statistics

    @property
    def warnings(self) -> list:
        return self.calibration.warnings

    @property
    def notes(self) -> list:
        return self.calibration.notes

    @property
    def verdict(self) -> Verdict:
        return self.calibration.verdict

    @property
    def unit(self) -> str:
        return self.calibration.unit

    @property
    def input(self) -> Provenance:
        return self.calibration.input

    @property
    def reference(self) -> Reference:
        return self.calibration.reference

    @property
    def robust(self) -> dict:
        return self.calibration.robust

    @property
    def drifts_in_time(self) -> bool:
        """Whether the scale factors drift in time (the log's times are then needed)."""
        return self.time_drift is not None and self.time_drift.kind != "none"

    def apply(self, samples, temperature, unit: str | None = None, times=None) -> np.ndarray:
        """Corrected field at the temperatures t (Eq. 9 in [1], Eq. 4 in [2]).

        samples : (N, 3) raw output [unit, default the calibration's]; temperature [degC];
        times : the samples' times, for a time drift (Unix seconds, or seconds on the clock of
        the calibration log) [s].
        Returns the corrected field in the unit of `samples`.
        """
        samples = validation.vectors(samples)
        unit = unit or self.unit
        units.check_compatible(self.unit, unit, "the samples")
        model = self.temperature_model or NEUTRAL  # a time drift alone: no temperature
        if self.temperature_model is None:
            temperature = np.zeros(samples.shape[0])
        temperature = validation.temperature(temperature, samples.shape[0])
        time_gains = None
        if self.drifts_in_time:
            if times is None:
                raise InputError(
                    "this calibration's scale factors drift in time; give the log's times "
                    f"(--time-column, as {self.time_column or 'the calibration log'}'s)"
                )
            drift = self.time_drift
            assert drift is not None
            time_gains = drift.gains(validation.times(times, samples.shape[0]))
        gains, _ = model.gains_offsets(self.model, temperature)
        if not (gains > 0).all():
            raise InputError(
                "the temperature model gives a non-positive axis gain for "
                f"{int((~(gains > 0)).any(axis=1).sum())} sample(s); check the "
                f"temperature column and its unit (degC)"
            )
        corrected = liu2022.correct(
            units.to_base(samples, unit),
            temperature,
            self.model,
            model,
            time_gains,
        )
        return units.from_base(corrected, unit)

    def correct(self, samples, temperature, params=None, times=None) -> np.ndarray:
        """`apply` (the nine parameters are this result's own; `params` is ignored)."""
        return self.apply(samples, temperature, times=times)

    def table(self, most: int | None = None) -> str:
        return format_table(self.statistics, self.unit, extra=("rmse",), most=most)

    def body(self) -> dict:
        document = self.calibration.body()
        if self.temperature_model is not None:
            document["temperature_model"] = {
                **self.temperature_model.to_dict(),
                "temperature_column": self.temperature_column,
                "temperature_range_degC": [float(v) for v in self.temperature_range],
                "standard_errors": self.temperature_standard_errors,
            }
        if self.drifts_in_time:
            assert self.time_drift is not None
            document["time_drift"] = {
                **self.time_drift.to_dict(),
                "time_column": self.time_column,
                "standard_errors": self.time_drift_standard_errors,
            }
        return document

    @classmethod
    def from_body(cls, reader: DocumentReader) -> TemperatureCalibrationResult:
        calibration = CalibrationResult(**CalibrationResult.fields_from(reader))
        block = reader.reader("temperature_model", None)
        if block is None:  # a time drift alone
            return cls(
                calibration=calibration, temperature_model=None, **_time_drift_fields(reader)
            )
        span = block.array("temperature_range_degC", (2,), np.full(2, np.nan))
        errors = block.mapping("standard_errors", None)
        return cls(
            calibration=calibration,
            temperature_model=read_temperature_model(block),
            temperature_column=block.string("temperature_column", None),
            **_time_drift_fields(reader),
            temperature_range=(float(span[0]), float(span[1])),
            temperature_standard_errors=errors,
        )


def _time_drift_fields(reader: DocumentReader) -> dict:
    """The constructor arguments of a document's "time_drift" block (none without it)."""
    block = reader.reader("time_drift", None)
    if block is None:
        return {}
    return {
        "time_drift": read_time_drift(block),
        "time_column": block.string("time_column", None),
        "time_drift_standard_errors": block.mapping("standard_errors", None),
    }


def calibrate_temperature(
    samples,
    temperature,
    reference,
    *,
    temperature_model: str | None = None,
    base_temperature: float | None = None,
    unit: str = "nT",
    reference_unit: str | None = None,
    temperature_column: str | None = None,
    model: str | None = None,
    times=None,
    time_drift: str = "none",
    time_column: str | None = None,
) -> TemperatureCalibrationResult:
    """The nine parameters and temperature coefficients from one log, estimated together.

    Start: offsets at the centre of a sphere fitted to the samples, scales that map its radius
    onto the reference, angles and temperature coefficients zero.

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        Raw output over many attitudes and temperatures. [unit]
    temperature : array_like, shape (N,), or None
        Temperatures t_i (`--temperature-column`) [degC]; None for a time drift alone (no
        temperature model: the nine parameters and the drift of the scale factors in time).
    reference : float or array_like of shape (N,)
        Reference magnitudes F_i (a proton magnetometer), or one number. [reference_unit]
    temperature_model : {"common", "per-axis", "full"}
        "common" (Eq. 2 and 9 of [1], the default), "per-axis" (linear scale and offset drift
        per axis) or "full" (per-axis, and a linear drift of each angle) (`--temperature-model`).
    base_temperature : float, optional
        t0 of the returned nine parameters; default the log's mean temperature. [degC]
    unit : str
        The unit of the samples; the result is in nT, or raw for counts.
    reference_unit : str, optional
        The unit of the reference (default: `unit`).
    temperature_column : str, optional
        The log column the temperatures came from, recorded for `nlpcal apply`.
    model : str, optional
        The former name of `temperature_model`, still accepted.
    times : array_like, shape (N,), optional
        The samples' times, for a time drift: Unix seconds, or seconds since any origin. [s]
    time_drift : {"none", "common", "per-axis"}
        Scale factors linear in time, one slope for all axes or one per axis (`--time-drift`).
    time_column : str, optional
        The log column the times came from, recorded for `nlpcal apply`.

    Returns
    -------
    TemperatureCalibrationResult
        The nine parameters at t0 and the temperature model, with standard errors.

    Raises
    ------
    InputError
        Unusable input.
    SolveError
        IPOPT failed.

    References
    ----------
    [1] Liu et al. (2022), see `nlpcal.models.liu2022`.

    Examples
    --------
    >>> import numpy as np
    >>> import nlpcal
    >>> t = np.linspace(0.0, 20.0, 1000)  # [degC]
    >>> raw = nlpcal.simulate(1000, seed=2)[["bx", "by", "bz"]].to_numpy()  # at t0 = 10 degC
    >>> samples = raw * (1 + 2e-4 * (t - 10.0))[:, None]  # k(t) of Eq. 9, c = 2e-4 / degC
    >>> result = nlpcal.calibrate_temperature(samples, t, 49462.0, base_temperature=10.0)
    >>> abs(result.temperature_model.k_slope_per_degC - 2e-4) < 1e-5  # [1/degC]
    True
    """
    given = validation.renamed(temperature_model, model, "temperature_model", "model")
    model = given or "common"
    validation.choice(model, "temperature model", TEMPERATURE_MODELS)
    validation.choice(time_drift, "time drift", TIME_DRIFTS)
    timed_only = temperature is None
    if timed_only:  # a time drift alone: no temperature model, every temperature zero
        model, base_temperature = _time_drift_alone(given, time_drift)
    samples, temperature, reference = _checked_series(
        samples, temperature, reference, unit, reference_unit
    )
    n = samples.shape[0]
    nx = 9 + n_coefficients(model, time_drift)
    if n <= nx:
        raise InputError(f"got {n} samples, need more than {nx} for the {model} model")
    base_temperature = (
        float(np.mean(temperature))
        if base_temperature is None
        else validation.number(base_temperature, "the base temperature")
    )
    t_low, t_high = (np.nan, np.nan) if timed_only else _temperature_range(temperature)
    t_ref, days = _days(times, time_drift, temperature)
    dt = temperature - base_temperature
    start, scale = _start_and_scale(model, time_drift, nx, samples, reference, dt, days)
    started = time.perf_counter()
    theta, sums, steps, iterations, status = minimise(
        model, start, scale, (samples, dt, reference, days), time_drift
    )
    wall = time.perf_counter() - started
    params, fitted, drift = model_of(theta, model, float(base_temperature), time_drift, t_ref)

    names = PARAMETER_NAMES + coefficient_names(model, time_drift)
    # the sandwich of the scores, following their dependence on their neighbours: one more
    # pass sums them over blocks of consecutive samples (`nlpcal.inference.dependence_meat`)
    count = -(-n // inference.block_rows(n))
    blocks = (np.zeros((count, nx)), np.zeros((count, nx, nx)))
    gauss_newton_pass(model, theta, scale, samples, dt, reference, days, time_drift, blocks)
    independent = sums.c * n / (n - nx) * (sums.a * n)  # s^2 A
    meat = inference.dependence_meat(*blocks, independent, n - nx)[0]
    uncertainty = inference.estimate(sums.a * n, meat=meat, dof=n - nx)
    not_identifiable = [names[i] for i in uncertainty.weak]
    errors, coefficient_errors, poor = _standard_errors(uncertainty, scale, names, model)
    warnings = _warnings(np.inf if timed_only else t_high - t_low, not_identifiable, poor)
    time_gains = drift.gains(times) if time_drift != "none" else None
    label, method, stage = _labels(model, time_drift, timed_only)
    rows = _statistics_rows(label, samples, temperature, reference, params, fitted, time_gains)
    rows[-1].update(iterations=iterations, wall_s=wall)  # the temperature solve's
    calibration = CalibrationResult(
        parameters=params.to_dict(),
        statistics=[TableRow.from_dict(row) for row in rows],
        method=method,
        reference=Reference("series", field_mean=float(np.mean(reference))),
        gauge=None,
        solver=_solver_report(stage, iterations, status, steps),
        unit=units.base_unit(unit),
        unit_source="option",  # the caller's unit (nT by default); the reference fixes the scale
        standard_errors=errors,
        identifiability=Identifiability(
            not_identifiable=not_identifiable,
            poorly_determined=poor,
            extra={"gauss_newton_eigenvalues_scaled": [float(v) for v in uncertainty.eigenvalues]},
        ),
        warnings=warnings,
        n_samples=n,
        input=Provenance(log_unit=unit),
    )
    drift_names = [name for name in names[9:] if name.endswith("_per_day")]
    return TemperatureCalibrationResult(
        calibration=calibration,
        temperature_model=fitted,
        temperature_column=None if timed_only else temperature_column,
        temperature_range=(np.nan, np.nan) if timed_only else (t_low, t_high),
        temperature_standard_errors=None
        if coefficient_errors is None
        else {k: v for k, v in coefficient_errors.items() if k not in drift_names},
        time_drift=drift if time_drift != "none" else None,
        time_column=time_column if time_drift != "none" else None,
        time_drift_standard_errors=None
        if coefficient_errors is None or time_drift == "none"
        else {k: coefficient_errors[k] for k in drift_names},
    )


#: Above this correlation of the times with the temperatures, a scale drift in time and a
#: temperature coefficient of the scales cannot be told apart. [1]
COLLINEAR = 0.999


def _days(times, time_drift: str, temperature: np.ndarray) -> tuple:
    """(t_ref [s], the samples' times from it [d]) for a time drift; (0, zeros) without one.
    InputError for what the data cannot determine: times that do not change, or change in
    step with the temperature."""
    n = temperature.size
    if time_drift == "none":
        return 0.0, np.zeros(n)
    if times is None:
        raise InputError(
            f"--time-drift {time_drift} needs the samples' times: pass --time-column COL"
        )
    times = validation.times(times, n)
    if times.max() == times.min():
        raise InputError(
            f"all {n} samples have the same time; a drift of the scale factors in time needs "
            f"a log over a span of time"
        )
    varies = temperature.max() > temperature.min()  # not a time drift alone
    correlation = float(np.corrcoef(times, temperature)[0, 1]) if varies else 0.0
    if abs(correlation) > COLLINEAR:
        raise InputError(
            f"the temperature changes in step with time (correlation {correlation:.4f}), so a "
            f"scalar reference cannot tell a drift of the scale factors in time from their "
            f"temperature coefficients; drop --time-drift, or calibrate over a log whose "
            f"temperature goes up and down"
        )
    t_ref = 0.5 * float(times.min() + times.max())
    return t_ref, (times - t_ref) / DAY_S


def _checked_series(samples, temperature, reference, unit: str, reference_unit) -> tuple:
    """The samples and the reference series in the base unit and the temperatures [degC]
    (zero for a time drift alone: `temperature` None), checked: one of each per sample, a
    reference given and of the samples' field."""
    samples = validation.samples(samples)
    n = samples.shape[0]
    temperature = np.zeros(n) if temperature is None else validation.temperature(temperature, n)
    if reference is None:
        raise InputError(
            "the temperature calibration needs a reference field per sample (a "
            "proton magnetometer column)"
        )
    reference = validation.reference(reference, n)
    units.check_compatible(unit, reference_unit or unit)
    samples = units.to_base(samples, unit)
    reference = np.broadcast_to(units.to_base(reference, reference_unit or unit), (n,)).copy()
    validation.reference_scale(reference, validation.mean_magnitude(samples))
    return samples, temperature, reference


def _standard_errors(uncertainty, scale, names, model: str) -> tuple:
    """The standard errors of the nine parameters [nT, 1, deg] and of the coefficients (by
    name, in their units) from the scaled `uncertainty`, and the coefficients poorly
    determined (a standard error above POOR_TEMPERATURE_SE of their scale); None, None and []
    without standard errors."""
    errors = coefficient_errors = None
    poor: list = []
    if uncertainty.standard_errors is not None:
        sd = uncertainty.standard_errors * scale
        sd[6:9] = np.degrees(sd[6:9])
        if model == "full":
            sd[15:18] = np.degrees(sd[15:18])  # angle slopes [deg/degC]
        errors = {name: float(v) for name, v in zip(PARAMETER_NAMES, sd[:9])}
        coefficient_errors = {name: float(v) for name, v in zip(names[9:], sd[9:])}
        poor = [
            name
            for name, v, size in zip(names[9:], sd[9:], scale[9:])
            if v > POOR_TEMPERATURE_SE * (np.degrees(size) if "_deg_" in name else size)
        ]
    return errors, coefficient_errors, poor


def _time_drift_alone(temperature_model: str | None, time_drift: str) -> tuple:
    """(NO_TEMPERATURE, base temperature 0 [degC]) for a calibration without temperatures: a
    time drift alone; InputError when a temperature model or no time drift is asked for."""
    if temperature_model is not None:
        raise InputError(
            f"a {temperature_model} temperature model needs the samples' temperatures "
            f"(--temperature-column COL)"
        )
    if time_drift == "none":
        raise InputError(
            "the temperature calibration needs the samples' temperatures, or a time drift "
            "(--temperature-column COL or --time-drift common|per-axis)"
        )
    return NO_TEMPERATURE, 0.0


def _labels(model: str, time_drift: str, timed_only: bool) -> tuple:
    """(the Table 1 label of the fitted row, the method, the solver stage) of a temperature
    model and a time drift (`timed_only`: a time drift alone)."""
    terms = [] if timed_only else [f"temperature ({model})"]
    terms += [f"time drift ({time_drift})"] if time_drift != "none" else []
    method = f"joint-time-{time_drift}" if timed_only else f"joint-temperature-{model}"
    stage = method if timed_only else method + (f"-time-{time_drift}" * (time_drift != "none"))
    return "system + " + " + ".join(terms), method, stage


def _temperature_range(temperature) -> tuple:
    """The lowest and highest temperature of the log [degC]; InputError when they are equal
    (no temperature coefficient can be estimated)."""
    n = len(temperature)
    t_low, t_high = float(temperature.min()), float(temperature.max())
    if t_high == t_low:
        raise InputError(
            f"all {n} temperatures equal {t_low:g} degC; the temperature "
            f"coefficients need a log over a range of temperatures (calibrate "
            f"without --temperature-column for a log at one temperature)"
        )
    return t_low, t_high


def _start_and_scale(model: str, time_drift: str, nx: int, samples, reference, dt, days) -> tuple:
    """IPOPT's start for the `nx` variables (offsets at the centre of the samples, the scale
    errors from their radius and the reference, everything else zero) and the scale of every
    variable (nine parameters, then the coefficients of `model` and `time_drift` from the
    largest |t - t0| [degC] and |time - t_ref| [d])."""
    frame = sphere_frame(samples)
    start = np.zeros(nx)
    start[0:3] = frame.centre
    start[3:6] = frame.radius / float(np.sqrt(np.mean(reference**2))) - 1.0
    scale = np.concatenate(
        [
            variable_scale(frame.radius),
            coefficient_scale(
                model,
                frame.radius,
                float(np.max(np.abs(dt))),
                time_drift,
                float(np.max(np.abs(days))),
            ),
        ]
    )
    return start, scale


def _statistics_rows(label: str, samples, temperature, reference, params, fitted, gains) -> list:
    """The Table 1 rows of the measured |B_M|, the nine parameters alone and the nine with the
    temperature model (and the time drift's `gains`), that row named `label` (its iterations
    and wall time for the caller to fill in). [base unit]"""
    return [
        {**evaluation_row("measured", samples, reference), "iterations": 0, "wall_s": 0.0},
        {
            **evaluation_row("system (t0 only)", zhou_correct(samples, params), reference),
            "iterations": 0,
            "wall_s": 0.0,
        },
        {
            **evaluation_row(
                label,
                liu2022.correct(samples, temperature, params, fitted or NEUTRAL, gains),
                reference,
            ),
            "iterations": 0,
            "wall_s": 0.0,
        },
    ]


def _solver_report(stage: str, iterations: int, status: str, steps: int) -> SolverReport:
    """The joint temperature solve as one IPOPT block solve, with the Levenberg-Marquardt steps
    that finished it."""
    return SolverReport(
        stages=[
            BlockSolve(
                cycle=1,
                stage=stage,
                finished_by="ipopt",
                iterations=iterations,
                ipopt_status=status,
            )
        ],
        ipopt_options=STEP_OPTIONS.settings(),
        gauss_newton_steps=steps,
    )


def _warnings(span: float, not_identifiable: list, poor: list) -> list:
    warnings = []
    if span < MIN_SPAN_DEGC:
        warnings.append(
            f"the temperature span {span:.3g} degC is too small to determine the "
            f"temperature coefficients; calibrate over a wider temperature range (at "
            f"least {MIN_SPAN_DEGC:g} degC)"
        )
    if not_identifiable:
        warnings.append(
            "not identifiable from this log: "
            + ", ".join(not_identifiable)
            + "; log more attitudes at more temperatures"
        )
    elif poor:
        warnings.append(
            "poorly determined (standard error above half the typical size): "
            + ", ".join(poor)
            + "; log more attitudes over a wider temperature "
            "range"
        )
    return warnings


def objective_value(
    samples, temperature, reference, params: Zhou2010Parameters, model: TemperatureModel
) -> float:
    """The joint objective through the built CasADi residual function (for checks). [field^2]"""
    samples = np.asarray(samples, dtype=float)
    n = samples.shape[0]
    dt = np.asarray(temperature, dtype=float) - model.base_temperature_degC
    reference = np.broadcast_to(np.asarray(reference, dtype=float), (n,))
    theta = theta_of(params, model)
    return gauss_newton_pass(model.kind, theta, np.ones(theta.size), samples, dt, reference).c


def calibrate_temperature_log(
    log,
    temperature_column: str | None,
    *,
    model: str | None = None,
    base_temperature: float | None = None,
    time_drift: str = "none",
    times=None,
    time_column: str | None = None,
) -> TemperatureCalibrationResult:
    """`calibrate_temperature` on a log read by `nlpcal.io.read_log` with its reference column
    and `temperature_column` [degC] (and the samples' `times` [s] from `time_column` for a
    `time_drift`; a time drift alone without `temperature_column`); the result records the
    log under `input`."""
    temperature_column = None if temperature_column is None else log.column(temperature_column)
    if log.reference is None:
        raise InputError(
            "the temperature calibration needs --reference-column COL, a reference "
            "magnitude per sample (for example a proton magnetometer)"
        )
    if temperature_column is not None and temperature_column == log.reference_column:
        raise InputError(
            f"the temperature and reference columns are both "
            f"{temperature_column!r}; they must be different columns"
        )
    result = calibrate_temperature(
        log.samples,
        None if temperature_column is None else log.values(temperature_column),
        log.reference,
        temperature_model=model,
        base_temperature=base_temperature,
        unit=log.base_unit,
        temperature_column=temperature_column,
        times=times,
        time_drift=time_drift,
        time_column=time_column,
    )
    result.calibration.input = Provenance.from_dict(
        log.metadata(temperature_column=temperature_column)
    )
    result.calibration.unit_source = log.unit_source
    result.calibration.warnings[:0] = [w for w in log.warnings if w not in result.warnings]
    result.calibration.reference.column = log.reference_column
    return result
