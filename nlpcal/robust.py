"""Robust losses for the |B1| objectives: least squares, Huber and Cauchy.

With r_i the residual of sample i (|B1_i| minus the reference, or minus the centre of |B1|
without one) and delta the loss scale, the estimate minimises sum_i rho(r_i):

    l2      rho(r) = r^2 / 2
    huber   rho(r) = r^2 / 2 for |r| <= delta, delta |r| - delta^2 / 2 beyond
    cauchy  rho(r) = delta^2 / 2 log(1 + (r / delta)^2)

Its minimum satisfies sum_i psi(r_i) dr_i/dx = 0 with psi = rho'. Iteratively reweighted least
squares reaches it: with weights w_i = psi(r_i) / r_i frozen at the current estimate, the weighted
least-squares problem sum_i w_i r_i^2 has the same stationary condition at a fixed point, and the
weighted problem is a moment problem of fixed size (`nlpcal.moments.accumulate` with weights).

Residuals within delta are inliers, weighted fully by Huber; beyond it a sample is down-weighted.
Without a given scale, delta = k s with s = 1.4826 MAD, the median absolute deviation of the
residuals scaled to the standard deviation of a Gaussian, and k the usual tuning constant
(1.345 for Huber, 2.385 for Cauchy: 95 % efficiency on Gaussian residuals).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import validation

LOSSES = ("l2", "huber", "cauchy")
#: Tuning constants: delta = k times the robust standard deviation of the residuals. [1]
TUNING = {"l2": np.inf, "huber": 1.345, "cauchy": 2.385}
#: 1 / Phi^-1(3/4): the MAD of a Gaussian times this is its standard deviation. [1]
MAD_TO_STD = 1.4826
#: Most residuals used for the median absolute deviation (an even stride over the log: the MAD
#: of 50 000 residuals is within about 0.5 % of that of all of them).
MAD_SAMPLES = 50_000


def robust_std(residuals) -> float:
    """1.4826 times the median absolute deviation of the residuals from their median. [residual
    unit]"""
    r = np.asarray(residuals, dtype=float)
    r = r[:: max(1, r.size // MAD_SAMPLES)]
    return float(MAD_TO_STD * median(np.abs(r - median(r))))


def median(values) -> float:
    """The median of a vector, as `np.median` takes it (the mean of the two middle values of
    an even count; NaN when one is NaN), by one partial sort. [value unit]"""
    a = np.asarray(values, dtype=float).ravel()
    n = a.size
    if n == 0 or np.isnan(a).any():
        return float(np.median(a))
    half = n // 2
    if n % 2:
        return float(np.partition(a, half)[half])
    middle = np.partition(a, (half - 1, half))[half - 1 : half + 1]
    return float(np.mean(middle))


@dataclass(frozen=True)
class Loss:
    """A loss and its scale.

    kind : "l2", "huber" or "cauchy".
    scale : delta, where residuals stop counting fully; None estimates it from the residuals
        (`from_residuals`). [field unit]
    """

    kind: str = "l2"
    scale: float | None = None

    def __post_init__(self):
        validation.choice(self.kind, "loss", LOSSES)
        if self.scale is not None:  # within the sizes a sample may have, so r / delta and
            validation.number(  # delta^2 stay representable
                self.scale,
                "the loss scale",
                positive=True,
                minimum=validation.MIN_SAMPLE_MAGNITUDE,
                maximum=validation.MAX_SAMPLE_VALUE,
            )

    @property
    def robust(self) -> bool:
        return self.kind != "l2"

    def with_scale_from(self, residuals) -> Loss:
        """This loss with delta = k * robust_std(residuals) (a given scale is kept)."""
        if self.scale is not None or not self.robust:
            return self
        spread = robust_std(residuals)
        if not spread > 0:  # noise-free residuals: nothing to down-weight
            spread = float(np.max(np.abs(residuals))) or 1.0
        return Loss(self.kind, TUNING[self.kind] * spread)

    def _t(self, r) -> np.ndarray:
        return np.asarray(r, dtype=float) / float(self.scale or np.inf)

    def rho(self, r) -> np.ndarray:
        """rho(r). [residual unit^2]"""
        r = np.asarray(r, dtype=float)
        if self.kind == "l2":
            return 0.5 * r * r
        delta = float(self.scale)  # type: ignore[arg-type]
        if self.kind == "huber":
            a = np.abs(r)
            return np.where(a <= delta, 0.5 * r * r, delta * a - 0.5 * delta * delta)
        return 0.5 * delta * delta * np.log1p(self._t(r) ** 2)

    def weight(self, r) -> np.ndarray:
        """w = psi(r) / r, the IRLS weight. [1]"""
        r = np.asarray(r, dtype=float)
        if self.kind == "l2":
            return np.ones_like(r)
        t = np.abs(self._t(r))
        if self.kind == "huber":
            return np.minimum(1.0, 1.0 / np.maximum(t, 1e-300))
        return 1.0 / (1.0 + t * t)

    def slope(self, r) -> np.ndarray:
        """psi'(r), clipped at zero (the bread of the sandwich covariance). [1]"""
        r = np.asarray(r, dtype=float)
        if self.kind == "l2":
            return np.ones_like(r)
        t = self._t(r)
        if self.kind == "huber":
            return (np.abs(t) <= 1.0).astype(float)
        return np.maximum((1.0 - t * t) / (1.0 + t * t) ** 2, 0.0)

    def outliers(self, r) -> np.ndarray:
        """Residuals beyond the scale: the samples this loss down-weights."""
        if not self.robust:
            return np.zeros(np.shape(r), dtype=bool)
        return np.abs(self._t(r)) > 1.0

    def to_dict(self) -> dict:
        return {"loss": self.kind, "scale": self.scale}
