"""Temperature drift (seed 002): the paper's k(t) pipeline and a joint temperature calibration.

Liu et al. (2022) [1] calibrate in two steps. The nine system parameters are estimated at a base
temperature t0. Then a static log with a temperature ramp and a proton reference gives the line
|B_m| = a t + b (Eq. 1), after the diurnal correction, and the factor k(t) of Eq. 9 divides the
raw vector before the system correction. The model is in `nlpcal.models.liu2022`; this module
holds the steps built on it:

* `fit_drift`: the diurnal correction and the least-squares line of Eq. 1 on a static log, with
  the standard errors of a and b and a warning when the temperature span is too small.
* `rmse_rows`: the paper's evaluation by the RMSE of Eq. 10, raw -> system -> system + temperature.
* `calibrate_temperature`: beyond the paper, the nine parameters and the temperature coefficients
  from ONE log that spans temperatures, in ONE CasADi NLP solved by IPOPT. "common" is the paper's
  assumption (Eq. 2 and 9: one factor k(t) = 1 + c (t - t0) on scale and offset of all axes);
  "per-axis" gives each axis its own linear scale and offset drift. The angles stay
  temperature-free, as the paper argues.
* `write_liu2022_replica`: a replica of the paper's experiment for `nlpcal simulate`.

The joint objective is the reference variant of Eq. 8 of Zhou et al. (2010) [2] with a
temperature in every sample,

    f = (1/N) sum_i ( |B1_i(t_i)| - F_i )^2,   B1_i = T^-1 diag(gain(t_i))^-1 (B_m,i - z(t_i))

(the mean square of the residuals whose RMSE is Eq. 10 in [1]). The moment expansion of
`nlpcal.moments` assumes parameters that are the same for every sample, which a temperature
breaks. The NLP is therefore written per sample in CasADi MX with the data as a 3 x N parameter:
the expression graph has a fixed number of matrix nodes whatever N, the `nlpsol` is built once
per (model, N) for the life of the process, and the tests check it against a direct per-sample
evaluation in numpy.

References
----------
[1] Liu H., Li Y., Ding X., Feng C. (2022), see `nlpcal.models.liu2022`.
[2] Zhou C., Jin J., Li H., Zhang B., Yan H. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import casadi as ca
import numpy as np
import pandas as pd

from . import __version__
from .calibration import CalibrationResult
from .errors import InputError, SolveError
from .io import (as_samples, check_reference, check_samples, read_json, write_csv_atomic,
                 write_json_atomic)
from .models import liu2022
from .models.liu2022 import TEMPERATURE_MODELS, TemperatureModel, k_factor, modulus_line, rmse
from .models.zhou2010 import PARAMETER_NAMES, Zhou2010Parameters, correction_matrix_entries
from .models.zhou2010 import correct as zhou_correct
from .models.zhou2010 import forward as zhou_forward
from .moments import sphere_frame
from .problems import variable_scale
from .simulate import random_rotations
from .solver import IpoptOptions, build_nlpsol, solve
from .statistics import (field_statistics, format_table, lag1_autocorrelation,
                         standard_error_inflation)

DRIFT_FORMAT = "nlpcal-drift"
DRIFT_FORMAT_VERSION = 1

#: Fewest samples of a drift fit: two for the line of Eq. 1, one more for its standard errors.
MIN_DRIFT_SAMPLES = 3
#: A temperature span below this is too small for a meaningful slope. [degC]
MIN_SPAN_DEGC = 0.5
#: Warn when the standard error of the slope a exceeds this fraction of |a|. [1]
MAX_SLOPE_RELATIVE_ERROR = 0.1
#: Warn when the field direction of a "static" drift log turns by more than this. [deg]
STATIC_SPREAD_DEG = 1.0
#: Joint calibration: eigenvalues of the scaled Gauss-Newton matrix below this fraction of the
#: largest mark a direction of the parameters that the log does not determine. [1]
WEAK_EIGENVALUE = 1e-10
#: Joint calibration: warn when a temperature coefficient's standard error exceeds this fraction
#: of its variable scale (its typical size). [1]
POOR_TEMPERATURE_SE = 0.5


# --- the paper's pipeline: diurnal correction, Eq. 1, Eq. 9 ------------------------------------

@dataclass
class DriftFit:
    """The line |B_m| = a t + b of Eq. 1 in [1] and the factor k(t) of Eq. 9.

    a : slope. [nT/degC]   b : intercept (the modulus at 0 degC). [nT]
    base_temperature : t0, where k = 1 (the temperature of the system calibration). [degC]
    fit_rmse : RMSE of the diurnal-corrected modulus about the line. [nT]
    a_standard_error, b_standard_error : standard errors of a [nT/degC] and b [nT], from the
        residual variance with n - 2 degrees of freedom.
    temperature_range : (min, max) of the log's temperatures. [degC]
    diurnal_base : F_1, the first reference value (base of the diurnal correction). [nT]
    direction_spread : largest angle of a raw vector from their mean direction. [deg]
    """

    a: float
    b: float
    base_temperature: float
    fit_rmse: float
    n: int
    temperature_range: tuple
    a_standard_error: float
    b_standard_error: float
    diurnal_base: float
    direction_spread: float = 0.0
    base_temperature_source: str = "argument"
    unit: str = "nT"
    warnings: list = field(default_factory=list)
    input: dict = field(default_factory=dict)

    @property
    def k_slope(self) -> float:
        """c = a / (a t0 + b), so that k(t) = 1 + c (t - t0) (Eq. 9 in [1]). [1/degC]"""
        return self.a / float(modulus_line(self.base_temperature, self.a, self.b))

    def k(self, temperature) -> np.ndarray:
        """k(t) of Eq. 9 in [1]. [1]"""
        return k_factor(temperature, self.a, self.b, self.base_temperature)

    @property
    def model(self) -> TemperatureModel:
        """The common temperature model equivalent to this fit."""
        return TemperatureModel.from_drift(self.a, self.b, self.base_temperature)

    def correct(self, samples, temperature, params: Zhou2010Parameters | None) -> np.ndarray:
        """Eq. 9 (divide the raw vector by k(t)), then Eq. 4 with `params` (None: Eq. 9 only)."""
        k = check_k(self.k(temperature), "the drift file")
        scaled = np.asarray(samples, dtype=float) / k[:, None]  # Eq. 9
        if params is None:
            return scaled
        return zhou_correct(scaled, params)  # Eq. 4 of [2]

    def to_dict(self) -> dict:
        return {
            "format": DRIFT_FORMAT,
            "format_version": DRIFT_FORMAT_VERSION,
            "model": "liu2022",
            "a_nT_per_degC": self.a,
            "b_nT": self.b,
            "base_temperature_degC": self.base_temperature,
            "fit_rmse_nT": self.fit_rmse,
            "n": self.n,
            "temperature_range_degC": [float(v) for v in self.temperature_range],
            "a_standard_error_nT_per_degC": self.a_standard_error,
            "b_standard_error_nT": self.b_standard_error,
            "k_slope_per_degC": self.k_slope,
            "base_temperature_source": self.base_temperature_source,
            "diurnal_base_nT": self.diurnal_base,
            "direction_spread_deg": self.direction_spread,
            "unit": self.unit,
            "warnings": list(self.warnings),
            "input": dict(self.input),
            "nlpcal_version": __version__,
        }

    @classmethod
    def from_dict(cls, document) -> "DriftFit":
        if not isinstance(document, dict):
            raise InputError("not an nlpcal drift file: expected a JSON object")
        if "parameters" in document and "a_nT_per_degC" not in document:
            raise InputError("this is a parameters file, not a drift file; pass the output of "
                             "'nlpcal drift fit' to --drift")
        if document.get("format", DRIFT_FORMAT) != DRIFT_FORMAT:
            raise InputError(f"not an nlpcal drift file (format {document.get('format')!r})")
        version = document.get("format_version", DRIFT_FORMAT_VERSION)
        if version != DRIFT_FORMAT_VERSION:
            raise InputError(f"drift file has format_version {version!r}; this nlpcal reads "
                             f"format_version {DRIFT_FORMAT_VERSION}")
        try:
            a = float(document["a_nT_per_degC"])
            b = float(document["b_nT"])
            t0 = float(document["base_temperature_degC"])
        except KeyError as exc:
            raise InputError(f"drift file: missing {exc.args[0]}") from None
        except (TypeError, ValueError) as exc:
            raise InputError(f"drift file: {exc}") from None
        if not all(np.isfinite([a, b, t0])):
            raise InputError("drift file: a_nT_per_degC, b_nT and base_temperature_degC must be "
                             "finite numbers")
        if not modulus_line(t0, a, b) > 0:
            raise InputError(f"drift file: a t0 + b = {float(modulus_line(t0, a, b)):g} nT, but "
                             f"the modulus at the base temperature must be positive")
        span = document.get("temperature_range_degC") or [t0, t0]
        return cls(
            a=a, b=b, base_temperature=t0,
            fit_rmse=float(document.get("fit_rmse_nT", float("nan"))),
            n=int(document.get("n", 0)),
            temperature_range=(float(span[0]), float(span[1])),
            a_standard_error=float(document.get("a_standard_error_nT_per_degC", float("nan"))),
            b_standard_error=float(document.get("b_standard_error_nT", float("nan"))),
            diurnal_base=float(document.get("diurnal_base_nT", float("nan"))),
            direction_spread=float(document.get("direction_spread_deg", 0.0)),
            base_temperature_source=str(document.get("base_temperature_source", "argument")),
            unit=str(document.get("unit", "nT")),
            warnings=list(document.get("warnings", [])),
            input=dict(document.get("input") or {}),
        )

    def save(self, path) -> None:
        write_json_atomic(path, self.to_dict())

    @classmethod
    def load(cls, path) -> "DriftFit":
        return cls.from_dict(read_json(path, "nlpcal drift file"))


def check_k(k, source: str) -> np.ndarray:
    """k(t) must be finite and positive for every sample (a sign change would flip the field)."""
    k = np.asarray(k, dtype=float)
    if not np.isfinite(k).all() or (k <= 0).any():
        raise InputError(f"{source} gives a non-positive temperature factor k(t) for "
                         f"{int((~(k > 0)).sum())} sample(s); check the temperature column and "
                         f"its unit (degC)")
    return k


def check_temperature(temperature, n: int) -> np.ndarray:
    """Validate N temperatures. [degC]"""
    try:
        temperature = np.asarray(temperature, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError("the temperatures must be numbers [degC]") from None
    if temperature.size != n:
        raise InputError(f"got {temperature.size} temperatures for {n} samples")
    if not np.isfinite(temperature).all():
        raise InputError("the temperatures contain NaN or infinite values; drop or fix those rows")
    return temperature


def _direction_spread(samples: np.ndarray) -> float:
    """Largest angle between a sample and the mean direction of all samples. [deg]"""
    norms = np.linalg.norm(samples, axis=1)
    unit = samples[norms > 0] / norms[norms > 0, None]
    if unit.size == 0:
        return 0.0
    mean = unit.mean(axis=0)
    mean /= np.linalg.norm(mean) or 1.0
    return float(np.degrees(np.arccos(np.clip(unit @ mean, -1.0, 1.0)).max()))


def fit_drift(samples, temperature, reference, *, base_temperature: float | None = None,
              unit: str = "nT") -> DriftFit:
    """The paper's drift fit on a static log (section 1 of [1]).

    samples : (N, 3) raw fluxgate output of a static sensor. [nT]
    temperature : (N,) temperatures t_i. [degC]
    reference : (N,) proton magnetometer values F_i, sampled with the fluxgate. [nT]
    base_temperature : t0, the temperature of the system calibration, where k = 1. Without it the
        mean temperature of the log is used, with a warning. [degC]

    The modulus gets the diurnal correction -(F_i - F_1), then a and b of Eq. 1 are the least-
    squares line through (t_i, corrected modulus_i). Raises InputError for unusable input.
    """
    samples = as_samples(samples, minimum=MIN_DRIFT_SAMPLES,
                         purpose="for the line of Eq. 1 and its standard errors")
    n = samples.shape[0]
    if not np.isfinite(samples).all():
        raise InputError("samples contain NaN or infinite values; drop or fix those rows")
    temperature = check_temperature(temperature, n)
    reference = check_reference(np.asarray(reference, dtype=float).reshape(-1), n)
    t_low, t_high = float(temperature.min()), float(temperature.max())
    span = t_high - t_low
    if span <= 0:
        raise InputError(f"all {n} temperatures equal {t_low:g} degC; the slope of Eq. 1 needs a "
                         f"log over a range of temperatures")
    warnings = []
    source = "argument"
    if base_temperature is None:
        base_temperature = float(np.mean(temperature))
        source = "log mean"
        warnings.append(f"no base temperature given: k = 1 at the log's mean temperature "
                        f"{base_temperature:.3f} degC; pass the temperature of the system "
                        f"calibration (--base-temperature)")
    elif not np.isfinite(base_temperature):
        raise InputError(f"the base temperature must be a finite number, got {base_temperature}")

    modulus = np.linalg.norm(samples, axis=1)
    corrected = liu2022.diurnal_correction(modulus, reference)  # section 1: -(F_i - F_1)
    t_mean = float(temperature.mean())
    dt = temperature - t_mean
    sxx = float(dt @ dt)
    a = float(dt @ (corrected - corrected.mean()) / sxx)  # Eq. 1, least squares
    b = float(corrected.mean() - a * t_mean)
    residual = corrected - modulus_line(temperature, a, b)
    rss = float(residual @ residual)
    fit_rmse = float(np.sqrt(rss / n))
    sigma2 = rss / (n - 2) if n > 2 else float("nan")
    widen = standard_error_inflation(lag1_autocorrelation(residual))  # a log is a time series
    a_se = float(np.sqrt(sigma2 / sxx)) * widen
    b_se = float(np.sqrt(sigma2 * (1.0 / n + t_mean**2 / sxx))) * widen

    if span < MIN_SPAN_DEGC or not a_se <= MAX_SLOPE_RELATIVE_ERROR * abs(a):
        warnings.append(
            f"the temperature span {span:.3g} degC is too small for a meaningful slope: "
            f"a = {a:.4g} +/- {a_se:.2g} nT/degC (standard error, "
            f"{a_se / abs(a) if a else float('inf'):.0%} of a); log the static sensor over a "
            f"wider temperature range (at least {MIN_SPAN_DEGC:g} degC and a standard error "
            f"below {MAX_SLOPE_RELATIVE_ERROR:.0%} of a)")
    base_modulus = float(modulus_line(base_temperature, a, b))
    if not base_modulus > 0:
        raise InputError(f"the fitted line gives a t0 + b = {base_modulus:g} nT at the base "
                         f"temperature {base_temperature:g} degC; k(t) of Eq. 9 is undefined")
    spread = _direction_spread(samples)
    if spread > STATIC_SPREAD_DEG:
        warnings.append(f"the field direction turns by up to {spread:.2g} deg across the log; "
                        f"the drift fit expects a static sensor (attitude changes alter the "
                        f"modulus through the system errors)")
    return DriftFit(a=a, b=b, base_temperature=float(base_temperature), fit_rmse=fit_rmse, n=n,
                    temperature_range=(t_low, t_high), a_standard_error=a_se,
                    b_standard_error=b_se, diurnal_base=float(reference[0]),
                    direction_spread=spread, base_temperature_source=source, unit=unit,
                    warnings=warnings)


# --- the paper's evaluation: RMSE of Eq. 10 ----------------------------------------------------

def evaluation_row(label: str, corrected, reference=None) -> dict:
    """Table row of |B| for corrected (or raw) vectors, with the RMSE of Eq. 10 to `reference`."""
    stats = field_statistics(np.asarray(corrected, dtype=float), None, reference)
    stats.pop("max_abs_u", None)
    row = {"label": label, **stats}
    if reference is not None:
        row["rmse"] = rmse(np.linalg.norm(corrected, axis=1), reference)  # Eq. 10
    return row


def rmse_rows(samples, reference, *, params: Zhou2010Parameters | None = None, temperature=None,
              correction=None) -> list:
    """The three-row evaluation of [1] (sections 2-3): raw -> system -> system + temperature.

    samples : (N, 3) raw output. [nT]
    reference : (N,) proton values or one number. [nT]
    params : the nine parameters at the base temperature (system correction, Eq. 4 of [2]).
    temperature : (N,) temperatures [degC]; correction : a DriftFit (Eq. 9) or a
        TemperatureCalibrationResult. Both are needed for the third row.
    """
    samples = np.asarray(samples, dtype=float)
    rows = [evaluation_row("raw", samples, reference)]
    if params is not None:
        rows.append(evaluation_row("system", zhou_correct(samples, params), reference))
    if correction is not None and temperature is not None:
        if isinstance(correction, DriftFit):
            corrected = correction.correct(samples, temperature, params)
            label = "system + temperature" if params is not None else "temperature"
        else:
            corrected = correction.apply(samples, temperature)
            label = "system + temperature"
        rows.append(evaluation_row(label, corrected, reference))
    return rows


# --- beyond the paper: nine parameters and temperature coefficients in one NLP ----------------

def n_temperature_coefficients(kind: str) -> int:
    return 1 if kind == "common" else 6


def temperature_coefficient_names(kind: str) -> tuple:
    if kind == "common":
        return ("k_slope_per_degC",)
    return tuple(f"scale_slope_{a}_per_degC" for a in "xyz") + tuple(
        f"offset_slope_{a}_per_degC" for a in "xyz")


def magnitude_expression(theta, samples, dt, kind: str):
    """|B1_i(t_i)| as a 1 x N CasADi expression (Eq. 2 and 9 in [1], Eq. 4 in [2]).

    theta : z [field], s [1], angles [rad], then c [1/degC] (common) or sigma [1/degC] and
        zeta [field/degC] (per-axis). samples : 3 x N raw output; dt : 1 x N values t_i - t0.
    """
    n = samples.shape[1]
    entries = correction_matrix_entries(theta[6], theta[7], theta[8], 0.0, 0.0, 0.0,
                                        cos=ca.cos, sin=ca.sin)  # T^-1 of Eq. 4 in [2]
    t_inv = ca.blockcat([[ca.MX(v) if isinstance(v, float) else v for v in row]
                         for row in entries])
    z, s = theta[0:3], theta[3:6]
    if kind == "common":
        k = 1 + theta[9] * dt  # Eq. 9: k(t) = 1 + c (t - t0)
        gains = ca.repmat(1 + s, 1, n) * ca.repmat(k, 3, 1)  # Eq. 9: alpha = k alpha_0
        offsets = z @ k  # Eq. 9: B_b = k B_b0
    else:
        gains = ca.repmat(1 + s, 1, n) * (1 + theta[9:12] @ dt)
        offsets = ca.repmat(z, 1, n) + theta[12:15] @ dt
    corrected = t_inv @ ((samples - offsets) / gains)
    return ca.sqrt(ca.sum1(corrected * corrected))


@lru_cache(maxsize=16)
def temperature_problem(kind: str, n: int, options: IpoptOptions = IpoptOptions()):
    """The joint NLP for `kind` and N samples, and a function for residuals and their Jacobian.

    Variables x scaled to order one: theta = theta_ref + var_scale * x. Parameters p: theta_ref,
    var_scale, the data (3 x N samples, t_i - t0, F_i) and f_ref, the objective at the start.
    Built on first use and cached for the life of the process.
    """
    nx = 9 + n_temperature_coefficients(kind)
    x = ca.MX.sym("x", nx)
    theta_ref = ca.MX.sym("theta_ref", nx)
    var_scale = ca.MX.sym("var_scale", nx)
    samples = ca.MX.sym("B", 3, n)
    dt = ca.MX.sym("dt", 1, n)
    reference = ca.MX.sym("F", 1, n)
    f_ref = ca.MX.sym("f_ref")
    theta = theta_ref + var_scale * x
    residual = magnitude_expression(theta, samples, dt, kind) - reference
    f = ca.sumsqr(residual) / n  # mean square of the Eq. 10 residuals
    p = ca.vertcat(theta_ref, var_scale, ca.vec(samples), dt.T, reference.T, f_ref)
    solver = build_nlpsol(f"nlpcal_temperature_{kind.replace('-', '_')}_{n}", x, f / f_ref, p,
                          None, options)
    theta_sym = ca.MX.sym("theta", nx)
    r = (magnitude_expression(theta_sym, samples, dt, kind) - reference).T
    residuals = ca.Function(f"nlpcal_temperature_residuals_{n}",
                            [theta_sym, samples, dt, reference], [r, ca.jacobian(r, theta_sym)],
                            ["theta", "B", "dt", "F"], ["r", "J"])
    return solver, residuals


def _theta_to_model(theta, kind: str, t0: float):
    params = Zhou2010Parameters.from_vector(np.concatenate([theta[:6], np.degrees(theta[6:9])]))
    if kind == "common":
        model = TemperatureModel("common", t0, k_slope_per_degC=float(theta[9]))
    else:
        model = TemperatureModel("per-axis", t0,
                                 scale_slope_per_degC=tuple(map(float, theta[9:12])),
                                 offset_slope_per_degC=tuple(map(float, theta[12:15])))
    return params, model


def _theta_from_model(params: Zhou2010Parameters, model: TemperatureModel) -> np.ndarray:
    head = np.concatenate([params.offsets, params.scales, params.angles_rad])
    if model.kind == "common":
        return np.concatenate([head, [model.k_slope_per_degC]])
    return np.concatenate([head, model.scale_slope_per_degC, model.offset_slope_per_degC])


def _variable_scale(kind: str, radius: float, max_dt: float) -> np.ndarray:
    """Typical sizes: those of `nlpcal.problems.variable_scale`, and temperature coefficients
    that change the field by 1e-3 over the log's largest |t - t0|."""
    head = list(variable_scale(radius))
    span = max(max_dt, 1.0)
    if kind == "common":
        return np.array(head + [1e-3 / span])
    return np.array(head + [1e-3 / span] * 3 + [1e-3 * radius / span] * 3)


def objective_value(samples, temperature, reference, params: Zhou2010Parameters,
                    model: TemperatureModel) -> float:
    """The joint objective through the built CasADi problem (for checks). [field^2]"""
    samples = np.asarray(samples, dtype=float)
    n = samples.shape[0]
    _, residuals = temperature_problem(model.kind, n)
    dt = np.asarray(temperature, dtype=float) - model.base_temperature_degC
    reference = np.broadcast_to(np.asarray(reference, dtype=float), (n,))
    r = np.asarray(residuals(_theta_from_model(params, model), samples.T, dt[None, :],
                             reference[None, :])[0], dtype=float).ravel()
    return float(r @ r / n)


@dataclass
class TemperatureCalibrationResult:
    """The nine parameters at t0 and a temperature model, estimated together.

    calibration : a CalibrationResult with the nine parameters at the base temperature t0 (so a
        reader that knows nothing of temperature still gets the system correction at t0).
    temperature_model : the model of `nlpcal.models.liu2022`.
    temperature_column : the log column the model was fitted with (used by `nlpcal apply`).
    temperature_range : (min, max) of the calibration log. [degC]
    temperature_standard_errors : standard errors of the temperature coefficients.
    """

    calibration: CalibrationResult
    temperature_model: TemperatureModel
    temperature_column: str | None = None
    temperature_range: tuple = (float("nan"), float("nan"))
    temperature_standard_errors: dict | None = None

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
    def unit(self) -> str:
        return self.calibration.unit

    def apply(self, samples, temperature) -> np.ndarray:
        """Corrected field at the temperatures t (Eq. 9 in [1], Eq. 4 in [2]). [unit]"""
        samples = np.asarray(samples, dtype=float)
        if samples.ndim != 2 or samples.shape[1] != 3:
            raise InputError(f"samples must have shape (N, 3), got {samples.shape}")
        temperature = check_temperature(temperature, samples.shape[0])
        gains, _ = self.temperature_model.gains_offsets(self.model, temperature)
        if not (gains > 0).all():
            raise InputError("the temperature model gives a non-positive axis gain for "
                             f"{int((~(gains > 0)).any(axis=1).sum())} sample(s); check the "
                             f"temperature column and its unit (degC)")
        return liu2022.correct(samples, temperature, self.model, self.temperature_model)

    def table(self) -> str:
        return format_table(self.statistics, self.unit, extra=("rmse",))

    def to_dict(self) -> dict:
        document = self.calibration.to_dict()
        document["temperature_model"] = {
            **self.temperature_model.as_dict(),
            "temperature_column": self.temperature_column,
            "temperature_range_degC": [float(v) for v in self.temperature_range],
            "standard_errors": self.temperature_standard_errors,
        }
        return document

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    @classmethod
    def from_dict(cls, document: dict) -> "TemperatureCalibrationResult":
        calibration = CalibrationResult.from_dict(document)
        block = document.get("temperature_model")
        if not isinstance(block, dict):
            raise InputError("parameters file has no \"temperature_model\" object")
        try:
            model = TemperatureModel.from_dict(block)
        except KeyError as exc:
            raise InputError(f"parameters file: temperature_model misses {exc.args[0]}") from None
        except (TypeError, ValueError) as exc:
            raise InputError(f"parameters file: temperature_model: {exc}") from None
        span = block.get("temperature_range_degC") or [float("nan")] * 2
        return cls(calibration=calibration, temperature_model=model,
                   temperature_column=block.get("temperature_column"),
                   temperature_range=(float(span[0]), float(span[1])),
                   temperature_standard_errors=block.get("standard_errors"))

    def save(self, path) -> None:
        write_json_atomic(path, self.to_dict())

    @classmethod
    def load(cls, path) -> "TemperatureCalibrationResult":
        return cls.from_dict(read_json(path, "nlpcal parameters file"))


def has_temperature_model(document) -> bool:
    """Whether a parameters document carries a temperature model."""
    return isinstance(document, dict) and document.get("temperature_model") is not None


def calibrate_temperature(samples, temperature, reference, *, model: str = "common",
                          base_temperature: float | None = None, unit: str = "nT",
                          temperature_column: str | None = None,
                          options: IpoptOptions = IpoptOptions()) -> TemperatureCalibrationResult:
    """The nine parameters and temperature coefficients from one log, in one IPOPT problem.

    samples : (N, 3) raw output over many attitudes and temperatures. [nT, or `unit`]
    temperature : (N,) temperatures t_i. [degC]
    reference : (N,) reference magnitudes F_i (a proton magnetometer), or one number. [nT]
    model : "common" (Eq. 2 and 9 of [1]) or "per-axis" (linear scale and offset drift per axis).
    base_temperature : t0 of the returned nine parameters; default the log's mean temperature.
        [degC]

    Start: offsets at the centre of a sphere fitted to the samples, scales that map its radius
    onto the reference, angles and temperature coefficients zero. Raises InputError for unusable
    input and SolveError when IPOPT fails.
    """
    if model not in TEMPERATURE_MODELS:
        raise InputError(f"unknown temperature model {model!r}; expected one of "
                         f"{', '.join(TEMPERATURE_MODELS)}")
    samples = check_samples(samples)
    n = samples.shape[0]
    temperature = check_temperature(temperature, n)
    if reference is None:
        raise InputError("the temperature calibration needs a reference field per sample (a "
                         "proton magnetometer column)")
    reference = check_reference(reference, n)
    reference = np.broadcast_to(np.asarray(reference, dtype=float), (n,)).copy()
    nx = 9 + n_temperature_coefficients(model)
    if n <= nx:
        raise InputError(f"got {n} samples, need more than {nx} for the {model} model")
    if base_temperature is None:
        base_temperature = float(np.mean(temperature))
    elif not np.isfinite(base_temperature):
        raise InputError(f"the base temperature must be a finite number, got {base_temperature}")
    t_low, t_high = float(temperature.min()), float(temperature.max())
    if t_high == t_low:
        raise InputError(f"all {n} temperatures equal {t_low:g} degC; the temperature "
                         f"coefficients need a log over a range of temperatures (calibrate "
                         f"without --temperature-column for a log at one temperature)")
    dt = temperature - base_temperature

    frame = sphere_frame(samples)
    field_rms = float(np.sqrt(np.mean(reference**2)))
    theta_ref = np.zeros(nx)
    theta_ref[0:3] = frame.centre
    theta_ref[3:6] = frame.radius / field_rms - 1.0
    scale = _variable_scale(model, frame.radius, float(np.max(np.abs(dt))))
    solver, residuals = temperature_problem(model, n, options)
    data = (samples.T, dt[None, :], reference[None, :])
    r0 = np.asarray(residuals(theta_ref, *data)[0], dtype=float).ravel()
    f_start = float(r0 @ r0 / n)
    f_ref = max(f_start, 1e-24 * frame.radius**2)
    p = np.concatenate([theta_ref, scale, samples.ravel(), dt, reference, [f_ref]])
    started = time.perf_counter()
    outcome = solve(solver, x0=np.zeros(nx), p=p)
    wall = time.perf_counter() - started
    if not outcome.success:
        raise SolveError(f"IPOPT did not solve the joint temperature calibration ({model})",
                         outcome.status)
    theta = theta_ref + scale * outcome.x
    params, temperature_model = _theta_to_model(theta, model, float(base_temperature))
    r, jac = (np.asarray(v, dtype=float) for v in residuals(theta, *data))
    r = r.ravel()
    objective = float(r @ r / n)

    # Gauss-Newton covariance, cov = s^2 (J^T J)^-1 with s^2 = sum r^2 / (N - p), in scaled
    # variables for conditioning.
    js = jac * scale[None, :]
    normal = js.T @ js
    values, vectors = np.linalg.eigh(0.5 * (normal + normal.T))
    weak = values < WEAK_EIGENVALUE * max(values[-1], 1e-300)
    names = PARAMETER_NAMES + temperature_coefficient_names(model)
    not_identifiable = set()
    for k in np.flatnonzero(weak):
        for i in np.flatnonzero(np.abs(vectors[:, k]) > 0.3):
            not_identifiable.add(names[i])
    errors = temperature_errors = None
    poor = []
    if not weak.any():
        sd = np.sqrt(np.clip(np.diag(np.linalg.inv(normal)), 0, None) * objective * n / (n - nx))
        sd_theta = sd * scale * standard_error_inflation(lag1_autocorrelation(r))
        sd_theta[6:9] = np.degrees(sd_theta[6:9])
        errors = {name: float(v) for name, v in zip(PARAMETER_NAMES, sd_theta[:9])}
        temperature_errors = {name: float(v) for name, v in
                              zip(temperature_coefficient_names(model), sd_theta[9:])}
        poor = [name for name, v, size in zip(names[9:], sd_theta[9:], scale[9:])
                if v > POOR_TEMPERATURE_SE * size]

    warnings = []
    span = t_high - t_low
    if span < MIN_SPAN_DEGC:
        warnings.append(f"the temperature span {span:.3g} degC is too small to determine the "
                        f"temperature coefficients; calibrate over a wider temperature range (at "
                        f"least {MIN_SPAN_DEGC:g} degC)")
    if not_identifiable:
        warnings.append("not identifiable from this log: "
                        + ", ".join(sorted(not_identifiable, key=names.index))
                        + "; log more attitudes at more temperatures")
    elif poor:
        warnings.append("poorly determined (standard error above half the typical size): "
                        + ", ".join(poor) + "; log more attitudes over a wider temperature "
                        "range")

    rows = [
        {**evaluation_row("measured", samples, reference), "iterations": 0, "wall_s": 0.0},
        {**evaluation_row("system (t0 only)", zhou_correct(samples, params), reference),
         "iterations": 0, "wall_s": 0.0},
        {**evaluation_row(f"system + temperature ({model})",
                          liu2022.correct(samples, temperature, params, temperature_model),
                          reference),
         "iterations": outcome.iterations, "wall_s": wall},
    ]
    calibration = CalibrationResult(
        parameters=params.as_dict(),
        statistics=rows,
        method=f"joint-temperature-{model}",
        reference={"mode": "series", "field_mean": float(np.mean(reference))},
        gauge=None,
        solver={"name": "ipopt", "status": outcome.status, "success": True,
                "iterations": outcome.iterations, "stop_reason": "solved",
                "stages": [{"cycle": 1, "stage": f"joint-temperature-{model}",
                            "status": outcome.status, "iterations": outcome.iterations}]},
        unit=unit,
        standard_errors=errors,
        identifiability={"not_identifiable": sorted(not_identifiable, key=names.index),
                         "poorly_determined": poor,
                         "gauss_newton_eigenvalues_scaled": [float(v) for v in values]},
        warnings=warnings,
        n_samples=n,
    )
    return TemperatureCalibrationResult(
        calibration=calibration, temperature_model=temperature_model,
        temperature_column=temperature_column, temperature_range=(t_low, t_high),
        temperature_standard_errors=temperature_errors)


# --- nlpcal simulate --preset liu2022 ----------------------------------------------------------

#: System errors of the replica sensor at t0. The paper's Table 1 (the HSF parameters at 7.3 degC)
#: was an image and is lost; these are chosen so that the replica's raw RMSE is close to the
#: paper's (about 890 nT on the drift log, about 1100 nT on the field log; paper 891.43, 1064.70).
REPLICA_PARAMETERS = Zhou2010Parameters(
    z_x=-236.0, z_y=128.0, z_z=72.0,
    s_x=0.0212, s_y=0.0179, s_z=0.0226,
    alpha_deg=0.42, beta_deg=-0.31, gamma_deg=0.18,
)
#: Inclination of the replica's field. [deg]
REPLICA_INCLINATION_DEG = 60.0
#: Default white noise per axis of the averaged fluxgate output. [nT]
REPLICA_NOISE_NT = 0.5
#: White noise of the proton magnetometer. [nT]
REPLICA_PROTON_NOISE_NT = 0.1
#: Default number of attitudes in the base calibration log and in the temperature sweep.
REPLICA_ATTITUDES = 600
#: Samples of the static drift log (one hour at the proton's 0.5 Hz) and of the field log.
REPLICA_DRIFT_SAMPLES = 1800
REPLICA_FIELD_SAMPLES = 200
REPLICA_FIELD_ATTITUDES = 80
#: Temperature range of the sweep log (beyond the paper, for the joint calibration). [degC]
REPLICA_SWEEP_RANGE_DEGC = (4.0, 14.0)


def replica_field(params: Zhou2010Parameters = REPLICA_PARAMETERS,
                  a: float = liu2022.PAPER_A_NT_PER_DEGC, b: float = liu2022.PAPER_B_NT,
                  t0: float = liu2022.PAPER_BASE_TEMPERATURE_DEGC,
                  inclination_deg: float = REPLICA_INCLINATION_DEG):
    """The field F0 [nT] and static direction (ideal sensor frame) that make Eq. 1 exact.

    The static sensor of the drift log is level with x north, so it sees the field along
    u = (cos I, 0, sin I). F0 solves |diag(1 + s) T u F0 + Z_p| = a t0 + b: the static modulus is
    then k(t)(a t0 + b) = a t + b, the paper's line.
    """
    inc = np.radians(inclination_deg)
    u = np.array([np.cos(inc), 0.0, np.sin(inc)])
    g = zhou_forward(u[None, :], params)[0] - params.offsets  # diag(1 + s) T u
    z = params.offsets
    target = float(modulus_line(t0, a, b))
    # |F g + z|^2 = target^2, the positive root
    qa, qb, qc = g @ g, 2.0 * g @ z, z @ z - target**2
    f0 = (-qb + np.sqrt(qb * qb - 4.0 * qa * qc)) / (2.0 * qa)
    return float(f0), u


def _smooth_noise(n: int, rng: np.random.Generator, width: int, peak: float) -> np.ndarray:
    """Band-limited noise with largest |value| = peak (moving average of white noise)."""
    white = rng.normal(size=n + width)
    series = np.convolve(white, np.ones(width) / width, mode="valid")[:n]
    series -= series.mean()
    return peak * series / (np.max(np.abs(series)) or 1.0)


def write_liu2022_replica(out_dir, *, seed: int = 0, noise: float | None = None,
                          n: int | None = None) -> list:
    """Write a replica of the experiment of [1] to `out_dir`; returns the paths written.

    Files (columns time_s, bx, by, bz [nT], temp_c [degC], proton_nT [nT]):

    * base.csv: calibration log at t0 = 7.3 degC, `n` attitudes (default 600).
    * drift.csv: static sensor, temperature falling from 6.8 to 5.1 degC over one hour at 0.5 Hz,
      with a diurnal trend and disturbances of up to 10 nT in the reference.
    * field.csv: 200 points over 80 attitudes at 12.8 degC, the reference varying by about
      100 nT.
    * sweep.csv: `n` attitudes while the temperature sweeps 4 -> 14 degC (beyond the paper: one log
      for the joint temperature calibration).
    * truth.json: the true parameters, a, b, t0 and field.

    The truth follows Eq. 2 and 9 of [1] with the paper's a = 7.0805 nT/degC, b = 50 906 nT and
    t0 = 7.3 degC; the field F0 makes the static modulus exactly a t + b (`replica_field`).
    """
    out_dir = Path(out_dir)
    noise = REPLICA_NOISE_NT if noise is None else float(noise)
    if noise < 0 or not np.isfinite(noise):
        raise InputError(f"--noise must be a non-negative number, got {noise}")
    attitudes = REPLICA_ATTITUDES if n is None else int(n)
    if attitudes < 20:
        raise InputError(f"-n must be at least 20 attitudes for the liu2022 replica, got {n}")
    rng = np.random.default_rng(seed)
    a, b = liu2022.PAPER_A_NT_PER_DEGC, liu2022.PAPER_B_NT
    t0 = liu2022.PAPER_BASE_TEMPERATURE_DEGC
    params = REPLICA_PARAMETERS
    model = TemperatureModel.from_drift(a, b, t0)
    f0, u_static = replica_field(params, a, b, t0)
    inc = np.radians(REPLICA_INCLINATION_DEG)
    world = np.array([np.cos(inc), 0.0, np.sin(inc)])  # north-east-down unit vector

    def log(directions, temperature, proton_true, period_s):
        count = directions.shape[0]
        field = directions * proton_true[:, None]  # the fluxgate sees the same field
        raw = liu2022.forward(field, temperature, params, model)  # Eq. 2
        raw = raw + noise * rng.normal(size=raw.shape)
        proton = proton_true + REPLICA_PROTON_NOISE_NT * rng.normal(size=count)
        return pd.DataFrame({"time_s": np.arange(count) * period_s, "bx": raw[:, 0],
                             "by": raw[:, 1], "bz": raw[:, 2], "temp_c": np.round(temperature, 3),
                             "proton_nT": proton})

    # base calibration log at t0
    rot = random_rotations(attitudes, rng)
    t_base = t0 + 0.02 * rng.normal(size=attitudes)
    f_base = f0 + _smooth_noise(attitudes, rng, 50, 3.0)
    base = log(rot @ world, t_base, f_base, 2.0)

    # static drift log: temperature ramp 6.8 -> 5.1 degC, diurnal trend and disturbances
    count = REPLICA_DRIFT_SAMPLES
    hi, lo = liu2022.PAPER_DRIFT_RANGE_DEGC[1], liu2022.PAPER_DRIFT_RANGE_DEGC[0]
    t_drift = np.linspace(hi, lo, count) + 0.01 * rng.normal(size=count)
    trend = 4.0 * np.sin(np.linspace(0.0, 0.5 * np.pi, count))
    f_drift = f0 + trend + _smooth_noise(count, rng, 15, 10.0)
    drift = log(np.tile(u_static, (count, 1)), t_drift, f_drift, 2.0)

    # field log at 12.8 degC: 80 attitudes, 200 points, the reference varying by about 100 nT
    count = REPLICA_FIELD_SAMPLES
    which = np.sort(np.arange(count) * REPLICA_FIELD_ATTITUDES // count)
    rot = random_rotations(REPLICA_FIELD_ATTITUDES, rng)[which]
    t_field = liu2022.PAPER_FIELD_TEMPERATURE_DEGC + 0.02 * rng.normal(size=count)
    f_field = f0 + 40.0 * np.sin(np.linspace(0.0, 2.5 * np.pi, count)) + \
        _smooth_noise(count, rng, 5, 10.0)
    field_log = log(rot @ world, t_field, f_field, 2.0)

    # temperature sweep with many attitudes (beyond the paper)
    rot = random_rotations(attitudes, rng)
    t_sweep = np.linspace(*REPLICA_SWEEP_RANGE_DEGC, attitudes) + 0.02 * rng.normal(size=attitudes)
    f_sweep = f0 + _smooth_noise(attitudes, rng, 50, 8.0)
    sweep = log(rot @ world, t_sweep, f_sweep, 2.0)

    written = []
    for name, frame in (("base.csv", base), ("drift.csv", drift), ("field.csv", field_log),
                        ("sweep.csv", sweep)):
        path = out_dir / name
        write_csv_atomic(path, frame)
        written.append(path)
    truth = {
        "description": "replica of Liu et al. (2022): nine parameters at t0 (Eq. 4 of Zhou et al."
                       " 2010) and the temperature factor k(t) of Eq. 9",
        "parameters": params.as_dict(),
        "a_nT_per_degC": a,
        "b_nT": b,
        "base_temperature_degC": t0,
        "temperature_model": model.as_dict(),
        "field_nT": f0,
        "inclination_deg": REPLICA_INCLINATION_DEG,
        "noise_nT": noise,
        "proton_noise_nT": REPLICA_PROTON_NOISE_NT,
        "seed": seed,
        "files": {"base.csv": f"calibration log, {attitudes} attitudes at {t0} degC",
                  "drift.csv": "static sensor, temperature 6.8 -> 5.1 degC, 1800 points at 0.5 Hz",
                  "field.csv": "200 points over 80 attitudes at 12.8 degC",
                  "sweep.csv": f"{attitudes} attitudes, temperature "
                               f"{REPLICA_SWEEP_RANGE_DEGC[0]} -> {REPLICA_SWEEP_RANGE_DEGC[1]} "
                               f"degC"},
    }
    path = out_dir / "truth.json"
    write_json_atomic(path, truth)
    written.append(path)
    return written


def replica_truth(path) -> tuple:
    """(params, TemperatureModel) from a replica's truth.json."""
    document = read_json(path, "replica truth file")
    try:
        params = Zhou2010Parameters.from_dict(document["parameters"])
        model = TemperatureModel.from_dict(document["temperature_model"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: not a replica truth file ({exc})") from None
    return params, model


__all__ = [
    "DriftFit", "fit_drift", "rmse", "rmse_rows", "evaluation_row", "calibrate_temperature",
    "TemperatureCalibrationResult", "TemperatureModel", "write_liu2022_replica", "replica_field",
    "has_temperature_model",
]
