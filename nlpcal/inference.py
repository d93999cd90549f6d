"""Standard errors and identifiability: one covariance routine for every estimate in nlpcal.

Every estimate minimises a mean (or sum) of squared residuals r_i(x). Near the optimum its
Gauss-Newton information is I = J^T J (J the Jacobian of the residuals), or equivalently
N H / 2 with H the Hessian of the mean square, and

    cov(x) = s^2 I^-1,        s^2 = sum_i r_i^2 / (N - p)

with p the number of parameters. `estimate` does this once for everyone:

* in variables scaled to order one (x = D y, D the typical size of each parameter), so that
  offsets in nT, scale errors of 1e-3 and angles of 1e-2 rad are compared on one footing;
* on a subspace when a gauge constraint fixes a direction (the columns of `basis`);
* with one singularity rule: an eigenvalue of the scaled information below WEAK_EIGENVALUE times
  the largest marks a direction the data do not determine; the parameters that take part in it
  (|component| > INVOLVED) are reported, and no standard errors are given;
* widened for the autocorrelation of the residuals: a log is a time series, and when neighbouring
  residuals are alike (lag-1 correlation rho > 0) the samples carry less information than their
  number says. Standard errors are multiplied by sqrt((1 + rho) / (1 - rho)), the AR(1) variance
  inflation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: An eigenvalue of the scaled information below this fraction of the largest is a direction the
#: data do not determine. [1]
WEAK_EIGENVALUE = 1e-9
#: A parameter takes part in a weak direction when its share of the unit eigenvector exceeds
#: this. [1]
INVOLVED = 0.3
#: Largest lag-1 autocorrelation used for the widening (rho -> 1 would give infinite widths). [1]
MAX_RHO = 0.99


def lag1_autocorrelation(residuals) -> float:
    """Correlation of neighbouring residuals of a time series. [1]"""
    r = np.asarray(residuals, dtype=float)
    r = r - r.mean()
    spread = float(r @ r)
    return float(r[:-1] @ r[1:]) / spread if r.size > 1 and spread > 0 else 0.0


def standard_error_inflation(rho: float) -> float:
    """sqrt((1 + rho) / (1 - rho)): how much wider standard errors are when neighbouring
    residuals correlate by rho (an AR(1) approximation; rho <= 0 leaves them as they are). [1]"""
    rho = min(max(float(rho), 0.0), MAX_RHO)
    return float(np.sqrt((1 + rho) / (1 - rho)))


@dataclass
class Uncertainty:
    """What the data determine about a set of parameters.

    covariance : (p, p) covariance in the parameters' own units, widened for autocorrelation, or
        None when a direction is not determined (or there are no degrees of freedom left).
    standard_errors : (p,) square roots of its diagonal, or None.
    eigenvalues : eigenvalues of the scaled information on the free subspace, ascending.
    weak : indices of the parameters taking part in a direction the data do not determine.
    weakest : indices of the parameters taking part in the least determined direction.
    autocorrelation : lag-1 autocorrelation of the residuals. [1]
    inflation : the widening applied to the standard errors. [1]
    """

    covariance: np.ndarray | None
    standard_errors: np.ndarray | None
    eigenvalues: np.ndarray
    weak: list
    weakest: list
    autocorrelation: float
    inflation: float

    @property
    def identifiable(self) -> bool:
        return not self.weak

    def correlation(self) -> np.ndarray | None:
        """Correlation matrix of the parameters, or None without a covariance. [1]"""
        return correlation(self.covariance)


def correlation(covariance) -> np.ndarray | None:
    """The correlation matrix of a covariance (None gives None). [1]"""
    if covariance is None:
        return None
    covariance = np.asarray(covariance, dtype=float)
    sd = np.sqrt(np.clip(np.diag(covariance), 0, None))
    scale = np.where(sd > 0, sd, 1.0)
    return covariance / np.outer(scale, scale)


def estimate(
    information,
    *,
    residual_variance: float = 1.0,
    meat=None,
    scale=None,
    basis=None,
    autocorrelation: float = 0.0,
    dof: int = 1,
) -> Uncertainty:
    """Covariance and identifiability from the Gauss-Newton information of a least-squares fit.

    information : (p, p) J^T J of the residuals in the parameters' own units, or already in the
        scaled variables when `scale` is None.
    residual_variance : s^2 = sum r^2 / (N - p). [residual unit^2]
    meat : for an M-estimate (a robust loss), B = sum psi(r_i)^2 J_i J_i^T in the same variables
        as `information`, which is then A = sum psi'(r_i) J_i J_i^T: the covariance is the
        sandwich A^-1 B A^-1 (residual_variance is not used).
    scale : (p,) typical sizes D of the parameters (x = D y); None when `information` is scaled.
    basis : (p, q) orthonormal columns of the scaled variables left free by a gauge; None: all.
    autocorrelation : lag-1 autocorrelation of the residuals, for the widening. [1]
    dof : degrees of freedom left (N - p); none left gives no covariance.
    """
    information = np.asarray(information, dtype=float)
    p = information.shape[0]
    d = np.ones(p) if scale is None else np.asarray(scale, dtype=float)
    b = np.eye(p) if basis is None else np.asarray(basis, dtype=float)
    scaled = d[:, None] * information * d[None, :]
    reduced = b.T @ scaled @ b
    reduced = 0.5 * (reduced + reduced.T)
    values, vectors = np.linalg.eigh(reduced)
    top = max(abs(values[-1]), 1e-300) if values.size else 1.0
    weak_directions = np.flatnonzero(values < WEAK_EIGENVALUE * top)

    def involved(k) -> set:
        direction = b @ vectors[:, k]
        return set(np.flatnonzero(np.abs(direction) > INVOLVED).tolist())

    weak = sorted(set().union(*(involved(k) for k in weak_directions)))
    inflation = standard_error_inflation(autocorrelation)
    covariance = errors = None
    if not weak and dof > 0 and np.isfinite(residual_variance):
        inverse = b @ np.linalg.inv(reduced) @ b.T
        if meat is None:
            cov_scaled = inverse * (float(residual_variance) * inflation**2)
        else:
            meat_scaled = d[:, None] * np.asarray(meat, dtype=float) * d[None, :]
            cov_scaled = inverse @ meat_scaled @ inverse * inflation**2
        covariance = d[:, None] * cov_scaled * d[None, :]
        errors = np.sqrt(np.clip(np.diag(covariance), 0, None))
    return Uncertainty(
        covariance=covariance,
        standard_errors=errors,
        eigenvalues=values,
        weak=weak,
        weakest=sorted(involved(0)) if values.size else [],
        autocorrelation=float(autocorrelation),
        inflation=inflation,
    )


def information_from_hessian(hessian, n: int) -> np.ndarray:
    """J^T J of the residuals from the Hessian H of their mean square: N H / 2."""
    return 0.5 * n * np.asarray(hessian, dtype=float)


def rounded(value: float, error: float | None, digits: int = 6) -> tuple:
    """(value, error) as text, rounded by the standard error: two significant digits of the
    error and the value to the same decimal (-71.518015 +/- 0.0417 -> "-71.518", "0.042"); with
    no usable error, the value to `digits` significant digits and the error as "-"."""
    if error is None or not np.isfinite(error) or error <= 0:
        return f"{value:.{digits}g}", "-"
    decimals = 1 - int(np.floor(np.log10(error)))
    if decimals > 0:
        return f"{value:.{decimals}f}", f"{error:.{decimals}f}"
    return f"{round(value, decimals):.0f}", f"{round(error, decimals):.0f}"
