"""The temperature-drift model of Liu, Li, Ding and Feng (2022) for triaxial fluxgates.

A static fluxgate next to a proton magnetometer (the scalar reference F, nearly free of temperature
effects) shows a total field |B_m| that follows the temperature t. After the diurnal correction
(the first proton value F_1 is the base; -(F_i - F_1) is added to the fluxgate modulus), the
paper fits

    |B_m| = a t + b                                                   Eq. 1 in [1]

and assumes that scale and offset drift linearly with t, by the same relative amount on all three
axes, while the non-orthogonality does not drift. Per axis, at temperature t,

    B_m = alpha B_T + B_b = k (alpha_0 B_T + B_b0),   k(t0) = 1        Eq. 2 in [1]

so that |B_m| = k |B_m0| with |B_m0| = a t0 + b (Eq. 3-8, lost images restated in
../shared/REFERENCE.md), and

    k(t) = (a t + b) / (a t0 + b) = 1 + a (t - t0) / (a t0 + b)
    alpha(t) = k alpha_0,   B_b(t) = k B_b0                           Eq. 9 in [1]

In nlpcal's terms (`nlpcal.models.zhou2010`), alpha_0 B_T + B_b0 is the output of the nine-parameter
model at the base temperature t0, diag(1 + s) T (A B) + Z_p, so the raw vector is divided by k(t)
before the correction of Eq. 4 of Zhou et al. (2010). The quality measure is the RMSE of the
corrected modulus against the proton values,

    RMSE = sqrt( (1/N) sum_i (|B_m,i| - |B_T,i|)^2 )                  Eq. 10 in [1]

Beyond the paper, `TemperatureModel` also holds a per-axis generalisation: each axis has its own
linear scale and offset drift, gain_j(t) = (1 + s_j)(1 + sigma_j (t - t0)) and
z_j(t) = z_j + zeta_j (t - t0), while the angles stay temperature-free. The paper's model is the
special case sigma_j = c and zeta_j = c z_j with c = a / (a t0 + b). The "full" model adds a
linear temperature coefficient to each angle, alpha(t) = alpha + eta_alpha (t - t0) (beta and
gamma alike): the temperature dependence of scales, offsets and non-orthogonalities that
satellite vector magnetometers are calibrated with in flight (Swarm VFM [2]).

References
----------
[1] Liu H., Li Y., Ding X., Feng C. (2022). Temperature drift error analysis of triaxial fluxgate
    sensors and its correction method (in Chinese). Ocean University of China. The source text
    names neither the journal nor a DOI (seed 002, ../shared/seeds/002_b5124ef138e20f0b.txt).
[2] Toffner-Clausen L., Lesur V., Olsen N., Finlay C. C. (2016). In-flight scalar calibration
    and characterisation of the Swarm magnetometry package. Earth, Planets and Space 68, 129.
    https://doi.org/10.1186/s40623-016-0501-6
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .zhou2010 import (
    Zhou2010Parameters,
    axis_matrix,
    axis_matrix_entries,
    correction_matrix_entries,
    triangular,
)
from .zhou2010 import correct as zhou_correct
from .zhou2010 import forward as zhou_forward

#: Temperature compensation parameters of the HSF sensor in [1] (section 1). [nT/degC], [nT]
PAPER_A_NT_PER_DEGC = 7.0805
PAPER_B_NT = 50906.0
#: RMSE of the fitted line of Eq. 1 over the drift experiment in [1]. [nT]
PAPER_FIT_RMSE_NT = 0.0113
#: Temperature of the system calibration in [1], the base temperature t0. [degC]
PAPER_BASE_TEMPERATURE_DEGC = 7.3
#: Temperature range of the drift experiment in [1] (it fell from 6.8 to 5.1). [degC]
PAPER_DRIFT_RANGE_DEGC = (5.1, 6.8)
#: Temperature of the field check at the verification point in [1]. [degC]
PAPER_FIELD_TEMPERATURE_DEGC = 12.8
#: RMSE of Eq. 10 in [1]: raw, system-corrected, system + temperature. [nT]
PAPER_DRIFT_RMSE_NT = (891.43, 15.50, 2.76)
PAPER_FIELD_RMSE_NT = (1064.70, 41.25, 9.40)

TEMPERATURE_MODELS = ("common", "per-axis", "full")


def modulus_line(temperature, a: float, b: float) -> np.ndarray:
    """|B_m| = a t + b, Eq. 1 in [1].

    temperature : t. [degC]
    a : slope. [nT/degC]
    b : intercept, the modulus at 0 degC. [nT]
    Returns the modulus. [nT]
    """
    return a * np.asarray(temperature, dtype=float) + b


def k_factor(temperature, a: float, b: float, base_temperature: float) -> np.ndarray:
    """k(t) = (a t + b) / (a t0 + b), Eq. 9 in [1]. [1]

    temperature : t. [degC]
    a : slope of Eq. 1. [nT/degC]
    b : intercept of Eq. 1. [nT]
    base_temperature : t0, where the system parameters hold and k = 1. [degC]
    """
    return modulus_line(temperature, a, b) / modulus_line(base_temperature, a, b)  # Eq. 9


def diurnal_correction(modulus, reference) -> np.ndarray:
    """The fluxgate modulus with the diurnal variation removed (section 1 of [1]).

    The first reference value F_1 is the base; the correction of sample i is -(F_i - F_1), added to
    the modulus.

    modulus : |B_m,i| of the fluxgate. [nT]
    reference : F_i of the proton magnetometer, sampled with the fluxgate. [nT]
    Returns |B_m,i| - (F_i - F_1). [nT]
    """
    reference = np.asarray(reference, dtype=float)
    return np.asarray(modulus, dtype=float) - (reference - reference[0])


def rmse(magnitude, reference) -> float:
    """RMSE of a total field against the reference, Eq. 10 in [1]. [nT]

    magnitude : |B_m,i|, corrected or not. [nT]
    reference : |B_T,i|, the proton values (or one number). [nT]
    """
    residual = np.asarray(magnitude, dtype=float) - np.asarray(reference, dtype=float)
    return float(np.sqrt(np.mean(residual**2)))  # Eq. 10


@dataclass(frozen=True)
class TemperatureModel:
    """How the nine parameters of Eq. 4 (Zhou et al. 2010) change with temperature.

    Attributes
    ----------
    kind : str
        "common" (the paper's Eq. 9: one factor k(t) = 1 + c (t - t0) on scale and offset of all
        axes), "per-axis" (each axis its own linear scale and offset drift) or "full" (per-axis,
        and each angle its own linear drift).
    base_temperature_degC : float
        t0, where the nine parameters hold. [degC]
    k_slope_per_degC : float
        c of the common model, a / (a t0 + b) in the terms of Eq. 1. [1/degC]
    scale_slope_per_degC : tuple
        sigma, gain_j(t) = (1 + s_j)(1 + sigma_j (t - t0)), per-axis. [1/degC]
    offset_slope_per_degC : tuple
        zeta, z_j(t) = z_j + zeta_j (t - t0), per-axis and full. [field unit/degC]
    angle_slope_deg_per_degC : tuple
        eta of alpha, beta, gamma: alpha(t) = alpha + eta_alpha (t - t0), full only. [deg/degC]

    Examples
    --------
    >>> import nlpcal
    >>> model = nlpcal.TemperatureModel("common", 7.3, k_slope_per_degC=1.39e-4)
    >>> model.kind, model.base_temperature_degC
    ('common', 7.3)
    """

    kind: str
    base_temperature_degC: float
    k_slope_per_degC: float = 0.0
    scale_slope_per_degC: tuple = (0.0, 0.0, 0.0)
    offset_slope_per_degC: tuple = (0.0, 0.0, 0.0)
    angle_slope_deg_per_degC: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if self.kind not in TEMPERATURE_MODELS:
            raise ValueError(
                f"unknown temperature model {self.kind!r}; expected one of "
                f"{', '.join(TEMPERATURE_MODELS)}"
            )

    @classmethod
    def from_drift(cls, a: float, b: float, base_temperature: float) -> TemperatureModel:
        """The common model of Eq. 9 in [1] from the line of Eq. 1."""
        return cls(
            "common",
            float(base_temperature),
            k_slope_per_degC=float(a / modulus_line(base_temperature, a, b)),
        )

    def k(self, temperature) -> np.ndarray:
        """k(t) = 1 + c (t - t0) of the common model, Eq. 9 in [1]. [1]"""
        if self.kind != "common":
            raise ValueError("k(t) is defined for the common model only")
        return 1.0 + self.k_slope_per_degC * (
            np.asarray(temperature, dtype=float) - self.base_temperature_degC
        )

    def gains_offsets(self, params: Zhou2010Parameters, temperature):
        """Axis gains (N, 3) [1] and offsets (N, 3) [field unit] at the temperatures t [degC]."""
        dt = np.asarray(temperature, dtype=float).reshape(-1, 1) - self.base_temperature_degC
        if self.kind == "common":
            k = 1.0 + self.k_slope_per_degC * dt
            return (1.0 + params.scales) * k, params.offsets * k  # Eq. 9: k alpha_0, k B_b0
        sigma = np.asarray(self.scale_slope_per_degC, dtype=float)
        zeta = np.asarray(self.offset_slope_per_degC, dtype=float)
        return (1.0 + params.scales) * (1.0 + sigma * dt), params.offsets + zeta * dt

    def angles_rad(self, params: Zhou2010Parameters, temperature) -> tuple:
        """alpha, beta, gamma at the temperatures t [degC]: (N,) arrays for the full model,
        the constant angles otherwise. [rad]"""
        if self.kind != "full":
            return tuple(params.angles_rad)
        dt = np.asarray(temperature, dtype=float) - self.base_temperature_degC
        eta = np.radians(np.asarray(self.angle_slope_deg_per_degC, dtype=float))
        return tuple(angle + slope * dt for angle, slope in zip(params.angles_rad, eta))

    def to_dict(self) -> dict:
        document = {"kind": self.kind, "base_temperature_degC": self.base_temperature_degC}
        if self.kind == "common":
            document["k_slope_per_degC"] = self.k_slope_per_degC
        else:
            document["scale_slope_per_degC"] = [float(v) for v in self.scale_slope_per_degC]
            document["offset_slope_per_degC"] = [float(v) for v in self.offset_slope_per_degC]
        if self.kind == "full":
            document["angle_slope_deg_per_degC"] = [float(v) for v in self.angle_slope_deg_per_degC]
        return document

    as_dict = to_dict  # the name of nlpcal 0.1; kept for one release

    @classmethod
    def from_dict(cls, document: dict) -> TemperatureModel:
        """Inverse of `as_dict`; raises KeyError, TypeError or ValueError on a bad document."""
        kind = document["kind"]
        t0 = float(document["base_temperature_degC"])
        if kind == "common":
            return cls(kind, t0, k_slope_per_degC=float(document["k_slope_per_degC"]))
        sigma = tuple(float(v) for v in document["scale_slope_per_degC"])
        zeta = tuple(float(v) for v in document["offset_slope_per_degC"])
        if len(sigma) != 3 or len(zeta) != 3:
            raise ValueError("scale_slope_per_degC and offset_slope_per_degC need three values")
        eta = tuple(float(v) for v in document.get("angle_slope_deg_per_degC", (0.0,) * 3))
        if len(eta) != 3:
            raise ValueError("angle_slope_deg_per_degC needs three values")
        return cls(
            kind, t0, scale_slope_per_degC=sigma, offset_slope_per_degC=zeta,
            angle_slope_deg_per_degC=eta,
        )  # fmt: skip


def forward(
    field_sensor_ideal, temperature, params: Zhou2010Parameters, model: TemperatureModel
) -> np.ndarray:
    """Sensor output B_m at temperature t for the true field A B in the ideal sensor frame.

    Eq. 2 in [1] written with the nine parameters: B_m = k (diag(1 + s) T (A B) + Z_p) for the
    common model, B_m = diag(gain(t)) T (A B) + z(t) per axis, with T(t) for the full model.

    field_sensor_ideal : (N, 3) true field in the ideal orthogonal sensor frame. [nT]
    temperature : (N,) temperatures. [degC]
    Returns (N, 3) sensor output. [nT]
    """
    field = np.asarray(field_sensor_ideal, dtype=float)
    if model.kind == "common":
        return model.k(temperature)[:, None] * zhou_forward(field, params)  # Eq. 2
    gains, offsets = model.gains_offsets(params, temperature)
    if model.kind == "per-axis":
        return (field @ axis_matrix(params).T) * gains + offsets
    alpha, beta, gamma = model.angles_rad(params, temperature)
    rows = axis_matrix_entries(alpha, beta, gamma)
    along = np.column_stack([sum(e * field[:, k] for k, e in enumerate(row)) for row in rows])
    return along * gains + offsets


def correct(
    samples, temperature, params: Zhou2010Parameters, model: TemperatureModel, time_gains=None
) -> np.ndarray:
    """Corrected field at temperature t: Eq. 9 in [1], then Eq. 4 of Zhou et al. (2010).

    Common model: B1 = O_p S_p (B_m / k(t) - Z_p). Per-axis and full models:
    B1 = T(t)^-1 diag(gain(t))^-1 (B_m - z(t)), T constant per axis.

    samples : (N, 3) sensor output B_m. [nT]
    temperature : (N,) temperatures. [degC]
    time_gains : (N, 3) factors of a scale drift in time that multiply the gains, or None
        (`nlpcal.models.time_drift.TimeDrift.gains`). [1]
    Returns (N, 3) corrected field. [nT]
    """
    samples = np.asarray(samples, dtype=float)
    if model.kind == "common" and time_gains is None:
        return zhou_correct(samples / model.k(temperature)[:, None], params)  # Eq. 9, then Eq. 4
    gains, offsets = model.gains_offsets(params, temperature)
    gains = gains if time_gains is None else gains * time_gains
    along = (samples - offsets) / gains
    alpha, beta, gamma = model.angles_rad(params, temperature)
    inverse = correction_matrix_entries(alpha, beta, gamma, 0.0, 0.0, 0.0)
    return np.column_stack(triangular(inverse, along[:, 0], along[:, 1], along[:, 2]))
