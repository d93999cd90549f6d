"""The paper's drift pipeline (Liu et al. 2022): diurnal correction, the line of Eq. 1 on a static
log, and the factor k(t) of Eq. 9 that divides the raw vector before the system correction.

References
----------
[1] Liu H., Li Y., Ding X., Feng C. (2022), see `nlpcal.models.liu2022`.
[2] Zhou C., Jin J., Li H., Zhang B., Yan H. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import inference, units, validation
from ..errors import InputError
from ..models import liu2022
from ..models.liu2022 import TemperatureModel, k_factor, modulus_line
from ..models.zhou2010 import Zhou2010Parameters
from ..models.zhou2010 import correct as zhou_correct
from ..results import Document, DocumentReader
from ..verdict import Verdict, judge
from ..version import __version__

#: Fewest samples of a drift fit: two for the line of Eq. 1, one more for its standard errors.
MIN_DRIFT_SAMPLES = 3
#: A temperature span below this is too small for a meaningful slope. [degC]
MIN_SPAN_DEGC = 0.5
#: Warn when the standard error of the slope a exceeds this fraction of |a|. [1]
MAX_SLOPE_RELATIVE_ERROR = 0.1
#: Warn when the field direction of a "static" drift log turns by more than this. [deg]
STATIC_SPREAD_DEG = 1.0
#: How the diurnal variation of the field leaves the modulus before the line of Eq. 1:
#: "fitted" (default) estimates with the line how strongly the modulus follows the reference,
#: |B_m,i| = a t_i + b + g (F_i - F_1); "paper" adds -(F_i - F_1) to the modulus (section 1 of
#: [1]), which assumes g = 1. A raw modulus that is 1.8 % too large follows the field 1.8 % too
#: strongly, so on the liu2022 replica "paper" biases a by about -0.05 nT/degC (2 standard errors;
#: its +/-1.96 SE interval covers the truth in about half of the seeds).
DIURNAL_METHODS = ("fitted", "paper")


@dataclass
class DriftFit(Document):
    """The line |B_m| = a t + b of Eq. 1 in [1] and the factor k(t) of Eq. 9.

    Attributes
    ----------
    a : float
        Slope. [nT/degC]
    b : float
        Intercept (the modulus at 0 degC). [nT]
    base_temperature : float
        t0, where k = 1 (the temperature of the system calibration). [degC]
    fit_rmse : float
        RMSE of the diurnal-corrected modulus about the line. [nT]
    n : int
        Samples fitted.
    temperature_range : tuple
        (min, max) of the log's temperatures. [degC]
    a_standard_error, b_standard_error : float
        Standard errors of a [nT/degC] and b [nT], from the residual variance with n - 2 degrees
        of freedom.
    diurnal_base : float
        F_1, the first reference value (base of the diurnal correction). [nT]
    direction_spread : float
        Largest angle of a raw vector from their mean direction. [deg]
    diurnal : str
        How the diurnal variation was removed ("fitted" or "paper").
    diurnal_gain, diurnal_gain_standard_error : float or None
        g, how strongly the modulus follows the reference (1 by assumption with "paper"; None
        where the reference does not vary). [1]
    base_temperature_source : str
        Where t0 came from ("argument" or the log's mean).
    unit : str
        The unit of a and b ("nT" or "raw").
    warnings : list of str
        What looks wrong, each a sentence.
    input : dict
        Where the samples came from.

    References
    ----------
    [1] Liu et al. (2022), see `nlpcal.models.liu2022`.

    Examples
    --------
    >>> import numpy as np
    >>> import nlpcal
    >>> t = np.linspace(5.0, 7.0, 200)
    >>> samples = np.outer(7.08 * t + 50906.0, [0.6, 0.0, 0.8])
    >>> fit = nlpcal.fit_drift(samples, t, np.full(200, 50950.0), base_temperature=7.3)
    >>> fit.unit, fit.temperature_range
    ('nT', (5.0, 7.0))
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
    diurnal: str = "paper"
    diurnal_gain: float | None = 1.0
    diurnal_gain_standard_error: float | None = 0.0
    base_temperature_source: str = "argument"
    unit: str = "nT"
    warnings: list = field(default_factory=list)
    input: dict = field(default_factory=dict)

    FORMAT = "nlpcal-drift"
    LEGACY_FORMATS = (("a_nT_per_degC", None),)
    WHAT = "nlpcal drift file"
    #: It needs the nine parameters of a system calibration beside it.
    carries_parameters = False

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

    @property
    def verdict(self) -> Verdict:
        """Poorly determined when the slope's standard error exceeds MAX_SLOPE_RELATIVE_ERROR
        of the slope, with the warnings."""
        poor = []
        if not self.a_standard_error <= MAX_SLOPE_RELATIVE_ERROR * abs(self.a):
            poor.append(f"a: standard error above {MAX_SLOPE_RELATIVE_ERROR:.0%} of a")
        return judge([], poor, self.warnings)

    def correct(self, samples, temperature, params: Zhou2010Parameters | None) -> np.ndarray:
        """Eq. 9 (divide the raw vector by k(t)), then Eq. 4 with `params` (None: Eq. 9 only)."""
        k = check_k(self.k(temperature), "the drift file")
        scaled = np.asarray(samples, dtype=float) / k[:, None]  # Eq. 9
        if params is None:
            return scaled
        return zhou_correct(scaled, params)  # Eq. 4 of [2]

    def body(self) -> dict:
        return {
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
            "diurnal": self.diurnal,
            "diurnal_gain": self.diurnal_gain,
            "diurnal_gain_standard_error": self.diurnal_gain_standard_error,
            "direction_spread_deg": self.direction_spread,
            "unit": self.unit,
            "warnings": list(self.warnings),
            "input": dict(self.input),
            "nlpcal_version": __version__,
        }

    @classmethod
    def accepts(cls, document: dict) -> bool:
        if "parameters" in document and "a_nT_per_degC" not in document:
            raise InputError(
                "this is a parameters file, not a drift file; pass the output of "
                "'nlpcal drift fit' to --drift"
            )
        return super().accepts(document)

    @classmethod
    def from_body(cls, reader: DocumentReader) -> DriftFit:
        a = reader.number("a_nT_per_degC")
        b = reader.number("b_nT")
        t0 = reader.number("base_temperature_degC", minimum=-273.15, maximum=1000.0)
        if not modulus_line(t0, a, b) > 0:
            raise InputError(
                f"{reader.source}: a t0 + b = {float(modulus_line(t0, a, b)):g} nT, "
                f"but the modulus at the base temperature must be positive"
            )
        span = reader.array("temperature_range_degC", (2,), np.array([t0, t0]))
        # files before the "fitted" correction hold the paper's, whose gain is 1 by assumption
        diurnal = reader.string("diurnal", "paper", options=DIURNAL_METHODS)
        assumed = (1.0, 0.0) if diurnal == "paper" else (None, None)
        nan = float("nan")
        return cls(
            a=a,
            b=b,
            base_temperature=t0,
            fit_rmse=reader.number("fit_rmse_nT", nan, minimum=0.0),
            n=reader.integer("n", 0),
            temperature_range=(float(span[0]), float(span[1])),
            a_standard_error=reader.number("a_standard_error_nT_per_degC", nan, minimum=0.0),
            b_standard_error=reader.number("b_standard_error_nT", nan, minimum=0.0),
            diurnal_base=reader.number("diurnal_base_nT", nan),
            diurnal=diurnal,
            diurnal_gain=reader.number("diurnal_gain", assumed[0]),
            diurnal_gain_standard_error=reader.number(
                "diurnal_gain_standard_error", assumed[1], minimum=0.0
            ),
            direction_spread=reader.number("direction_spread_deg", 0.0, minimum=0.0),
            base_temperature_source=reader.string("base_temperature_source", "argument"),
            unit=reader.string("unit", "nT"),
            warnings=reader.strings("warnings", []),
            input=reader.provenance(
                strings=("log", "temperature_column", "reference_column"), lists=("columns",)
            ),
        )


def check_k(k, source: str) -> np.ndarray:
    """k(t) must be finite and positive for every sample (a sign change would flip the field)."""
    k = np.asarray(k, dtype=float)
    if not np.isfinite(k).all() or (k <= 0).any():
        raise InputError(
            f"{source} gives a non-positive temperature factor k(t) for "
            f"{int((~(k > 0)).sum())} sample(s); check the temperature column and "
            f"its unit (degC)"
        )
    return k


def _direction_spread(samples: np.ndarray) -> float:
    """Largest angle between a sample and the mean direction of all samples. [deg]"""
    norms = np.linalg.norm(samples, axis=1)
    unit = samples[norms > 0] / norms[norms > 0, None]
    if unit.size == 0:
        return 0.0
    mean = unit.mean(axis=0)
    mean /= np.linalg.norm(mean) or 1.0
    return float(np.degrees(np.arccos(np.clip(unit @ mean, -1.0, 1.0)).max()))


def fit_drift(
    samples,
    temperature,
    reference,
    *,
    base_temperature: float | None = None,
    unit: str = "nT",
    reference_unit: str | None = None,
    diurnal: str = "fitted",
) -> DriftFit:
    """The paper's drift fit on a static log (section 1 of [1]): the line |B_m| = a t + b of Eq. 1.

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        Raw fluxgate output of a static sensor. [unit]
    temperature : array_like, shape (N,)
        Temperatures t_i (`--temperature-column`). [degC]
    reference : array_like, shape (N,)
        Proton magnetometer values F_i, sampled with the fluxgate (`--reference-column`).
        [reference_unit]
    base_temperature : float, optional
        t0, the temperature of the system calibration, where k = 1 (`--base-temperature`). Without
        it the mean temperature of the log is used, with a warning. [degC]
    unit : str
        The unit of the samples; the fit is in nT (a [nT/degC], b [nT]), or raw for counts.
    reference_unit : str, optional
        The unit of the reference (default: `unit`).
    diurnal : {"fitted", "paper"}
        "fitted" (default): a, b and the gain g of |B_m,i| = a t_i + b + g (F_i - F_1) by least
        squares; "paper": the modulus gets the diurnal correction -(F_i - F_1) of [1], then a and b
        are the least-squares line through (t_i, corrected modulus_i) (`--diurnal`).

    Returns
    -------
    DriftFit
        a, b, their standard errors, and the factor k(t) of Eq. 9.

    Raises
    ------
    InputError
        Unusable input.

    References
    ----------
    [1] Liu et al. (2022), see `nlpcal.models.liu2022`.

    Examples
    --------
    >>> import numpy as np
    >>> import nlpcal
    >>> t = np.linspace(5.0, 7.0, 200)  # a static sensor warming up [degC]
    >>> samples = np.outer(7.08 * t + 50906.0, [0.6, 0.0, 0.8])  # |B_m| = a t + b [nT]
    >>> fit = nlpcal.fit_drift(samples, t, np.full(200, 50950.0), base_temperature=7.3)
    >>> round(fit.a, 3), round(fit.b, 1)  # [nT/degC], [nT]
    (7.08, 50906.0)
    """
    validation.choice(diurnal, "diurnal", DIURNAL_METHODS)
    samples = validation.finite_vectors(
        samples, minimum=MIN_DRIFT_SAMPLES, purpose="for the line of Eq. 1 and its standard errors"
    )
    n = samples.shape[0]
    temperature = validation.temperature(temperature, n)
    reference = validation.reference(np.asarray(reference, dtype=float).reshape(-1), n)
    units.check_compatible(unit, reference_unit or unit)
    samples = units.to_base(samples, unit)
    reference = units.to_base(reference, reference_unit or unit)
    t_low, t_high = float(temperature.min()), float(temperature.max())
    span = t_high - t_low
    if span <= 0:
        raise InputError(
            f"all {n} temperatures equal {t_low:g} degC; the slope of Eq. 1 needs a "
            f"log over a range of temperatures"
        )
    base_temperature, source, warnings = _base_temperature(base_temperature, temperature)

    modulus = np.linalg.norm(samples, axis=1)
    validation.reference_scale(reference, float(modulus.mean()), "the reference (proton) field")
    line = diurnal_line(modulus, temperature, reference, diurnal)
    a, b = line.a, line.b
    a_se, b_se = line.a_standard_error, line.b_standard_error
    if line.collinear:
        warnings.append(
            "the reference field changes in step with the temperature, so the slope a and "
            "how strongly the modulus follows the reference cannot be told apart; "
            "--diurnal paper assumes the modulus follows it one for one"
        )

    if span < MIN_SPAN_DEGC or not a_se <= MAX_SLOPE_RELATIVE_ERROR * abs(a):
        warnings.append(
            f"the temperature span {span:.3g} degC is too small for a meaningful slope: "
            f"a = {a:.4g} +/- {a_se:.2g} nT/degC (standard error, "
            f"{a_se / abs(a) if a else float('inf'):.0%} of a); log the static sensor over a "
            f"wider temperature range (at least {MIN_SPAN_DEGC:g} degC and a standard error "
            f"below {MAX_SLOPE_RELATIVE_ERROR:.0%} of a)"
        )
    base_modulus = float(modulus_line(base_temperature, a, b))
    if not base_modulus > 0:
        raise InputError(
            f"the fitted line gives a t0 + b = {base_modulus:g} nT at the base "
            f"temperature {base_temperature:g} degC; k(t) of Eq. 9 is undefined"
        )
    spread = _direction_spread(samples)
    if spread > STATIC_SPREAD_DEG:
        warnings.append(
            f"the field direction turns by up to {spread:.2g} deg across the log; "
            f"the drift fit expects a static sensor (attitude changes alter the "
            f"modulus through the system errors)"
        )
    return DriftFit(
        a=a,
        b=b,
        base_temperature=float(base_temperature),
        fit_rmse=line.rmse,
        n=n,
        temperature_range=(t_low, t_high),
        a_standard_error=a_se,
        b_standard_error=b_se,
        diurnal_base=float(reference[0]),
        direction_spread=spread,
        diurnal=diurnal,
        diurnal_gain=line.gain,
        diurnal_gain_standard_error=line.gain_standard_error,
        base_temperature_source=source,
        unit=units.base_unit(unit),
        warnings=warnings,
    )


def _base_temperature(base_temperature, temperature) -> tuple:
    """The temperature t0 where k = 1 [degC], where it came from ("argument", or "log mean"
    when none was given: the log's mean temperature, with a warning) and that warning in a
    list."""
    warnings = []
    source = "argument"
    if base_temperature is None:
        base_temperature = float(np.mean(temperature))
        source = "log mean"
        warnings.append(
            f"no base temperature given: k = 1 at the log's mean temperature "
            f"{base_temperature:.3f} degC; pass the temperature of the system "
            f"calibration (--base-temperature)"
        )
    elif not np.isfinite(base_temperature):
        raise InputError(f"the base temperature must be a finite number, got {base_temperature}")
    return base_temperature, source, warnings


@dataclass(frozen=True)
class DiurnalLine:
    """The line of Eq. 1 through a static log with its diurnal variation removed: a [nT/degC],
    b [nT], their standard errors, the gain g of the modulus on the reference [1] (with its
    standard error; 1 and 0 with the paper's correction, None when the reference is constant),
    the RMSE about the line [nT] and whether g and a could not be told apart."""

    a: float
    b: float
    a_standard_error: float
    b_standard_error: float
    gain: float | None
    gain_standard_error: float | None
    rmse: float
    collinear: bool = False


def diurnal_line(modulus, temperature, reference, diurnal: str = "fitted") -> DiurnalLine:
    """Least squares of Eq. 1 with the diurnal variation -(F_i - F_1) removed as `diurnal` says.

    "paper" (section 1 of [1]): |B_m,i| - (F_i - F_1) = a t_i + b. "fitted": |B_m,i| =
    a t_i + b + g (F_i - F_1), g estimated with a and b: the modulus of a sensor whose raw
    output is too large by a factor follows the field by that factor, which the paper's g = 1
    leaves in the slope wherever the field drifts with the temperature. The standard errors are
    the sandwich of the scores r_i x_i, following their dependence on their neighbours
    (`nlpcal.inference.least_squares_uncertainty`; s^2 (X^T X)^-1 with n - p degrees of
    freedom when they show none).
    modulus : |B_m,i| [nT]; temperature : t_i [degC]; reference : F_i [nT].
    """
    modulus = np.asarray(modulus, dtype=float)
    temperature = np.asarray(temperature, dtype=float)
    change = np.asarray(reference, dtype=float) - float(reference[0])  # F_i - F_1
    columns = [temperature, np.ones_like(temperature)]
    fitted = diurnal == "fitted" and bool(np.any(change != 0.0))
    if fitted:
        columns.append(change)
    else:
        modulus = liu2022.diurnal_correction(modulus, reference)  # section 1 of [1]
    design = np.column_stack(columns)
    t_mean = float(temperature.mean())
    centred = design.copy()  # the temperature about its mean: a well-conditioned solve
    centred[:, 0] -= t_mean
    coefficients = np.linalg.lstsq(centred, modulus, rcond=None)[0]
    residual = modulus - centred @ coefficients
    a = float(coefficients[0])
    b = float(coefficients[1] - a * t_mean)
    rss = float(residual @ residual)
    n, p = design.shape
    # the line's Jacobian is the design (Gauss-Newton is exact here); the scores follow the
    # dependence of neighbouring samples (a drift log is a slow time series)
    line = inference.least_squares_uncertainty(design, residual, n - p)[0]
    errors = line.standard_errors if line.standard_errors is not None else np.full(p, np.nan)
    gain = float(coefficients[2]) if fitted else (1.0 if diurnal == "paper" else None)
    gain_se = float(errors[2]) if fitted and np.isfinite(errors[2]) else None
    gain_se = 0.0 if diurnal == "paper" else gain_se
    return DiurnalLine(
        a=a,
        b=b,
        a_standard_error=float(errors[0]),
        b_standard_error=float(errors[1]),
        gain=gain,
        gain_standard_error=gain_se,
        rmse=float(np.sqrt(rss / n)),
        collinear=fitted and bool(line.weak),
    )


def fit_drift_log(
    log,
    temperature_column: str,
    *,
    base_temperature: float | None = None,
    diurnal: str = "fitted",
) -> DriftFit:
    """`fit_drift` on a log read by `nlpcal.io.read_log` with its reference column and
    `temperature_column` [degC]; the fit records the log under `input`."""
    temperature_column = log.column(temperature_column)
    if temperature_column == log.reference_column:
        raise InputError(
            f"--temperature-column and --reference-column are both "
            f"{temperature_column!r}; they must be different columns"
        )
    fit = fit_drift(
        log.samples,
        log.values(temperature_column),
        log.reference,
        base_temperature=base_temperature,
        unit=log.base_unit,
        diurnal=diurnal,
    )
    fit.input = log.metadata(
        temperature_column=temperature_column, reference_column=log.reference_column
    )
    return fit
