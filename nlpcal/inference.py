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
* optionally from the scores of the samples (a residual times its sensitivity to each
  parameter) by a block jackknife (`block_jackknife`), its groups as long as the scores'
  dependence (`bartlett_bandwidth`): a log is a time series, and when the scores of neighbouring
  samples are alike the samples carry less information than their number says.

The widening by the residuals' lag-1 autocorrelation that other estimators still use
(`standard_error_inflation`) is the AR(1) variance inflation sqrt((1 + rho) / (1 - rho)).

References
----------
[K89] Kunsch, H. R. (1989). The jackknife and the bootstrap for general stationary
    observations. Annals of Statistics 17(3), 1217-1241.
[A91] Andrews, D. W. K. (1991). Heteroskedasticity and autocorrelation consistent covariance
    matrix estimation. Econometrica 59(3), 817-858.
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


#: The 97.5 % quantile of the standard normal distribution. [1]
Z_975 = 1.959963984540054
#: Groups of the block jackknife are this many times the automatic Bartlett bandwidth long. [1]
GROUP_BANDWIDTHS = 3.0
#: Fewest groups of the block jackknife: with fewer, its variance rests on too few degrees of
#: freedom (Student's t on MIN_GROUPS - 1 = 5 widens a standard error by 1.31). [1]
MIN_GROUPS = 6
#: Largest AR(1) coefficient of a score series the bandwidth rule takes (`bartlett_bandwidth`). [1]
MAX_SCORE_RHO = 0.97


def bartlett_bandwidth(series) -> float:
    """The automatic bandwidth S_T of the Bartlett kernel for a (T, q) series of zero-mean
    vectors: Andrews' AR(1) plug-in [A91, Eq. 6.4 and p. 830], each column an AR(1) with its own
    coefficient rho_a and innovation variance sigma_a^2, all columns weighted alike:

        alpha(1) = sum 4 rho^2 sigma^4 / ((1 - rho)^6 (1 + rho)^2) / sum sigma^4 / (1 - rho)^4,
        S_T = 1.1447 (alpha(1) T)^(1/3).  [blocks]
    """
    series = np.asarray(series, dtype=float)
    t = series.shape[0]
    if t < 3:
        return 0.0
    lead, lag = series[1:], series[:-1]
    denominator = np.einsum("ij,ij->j", lag, lag)
    rho = np.divide(
        np.einsum("ij,ij->j", lead, lag),
        denominator,
        out=np.zeros_like(denominator),
        where=denominator > 0,
    )
    rho = np.clip(rho, -MAX_SCORE_RHO, MAX_SCORE_RHO)
    sigma2 = np.mean((lead - rho * lag) ** 2, axis=0)
    top = np.sum(4 * rho**2 * sigma2**2 / ((1 - rho) ** 6 * (1 + rho) ** 2))
    bottom = np.sum(sigma2**2 / (1 - rho) ** 4)
    alpha = top / bottom if bottom > 0 else 0.0
    return float(min(1.1447 * (alpha * t) ** (1 / 3), t - 1))


def group_length(bandwidth: float, blocks: int) -> int:
    """Blocks per group of the jackknife: GROUP_BANDWIDTHS automatic bandwidths, but no longer
    than leaves MIN_GROUPS groups (a short log, or scores alike across most of it: the variance
    is then estimated on few degrees of freedom, which `t_widening` states). [blocks]"""
    length = int(np.ceil(GROUP_BANDWIDTHS * bandwidth))
    return max(1, min(length, blocks // MIN_GROUPS))


def block_jackknife(series, informations, length: int) -> tuple:
    """(V, G): the covariance of an estimate by the delete-a-group jackknife over groups of
    consecutive samples [K89], and the number of groups G.

    series : (K, q) block sums of the scores psi(r_i) J_i at the estimate. informations :
    (K, q, q) the blocks' shares A_k of the information A = sum A_k. length : blocks per group.

    Without group g the gradient at the estimate is -S_g, so one Newton step gives the estimate
    without it, delta_g = (A - A_g)^-1 S_g, and V = (G - 1) / G sum_g (delta_g - mean)(...)^T.
    Groups longer than the scores' dependence are nearly independent, so V follows the
    dependence of the scores; and since each delta_g is the estimate refitted without its group,
    V keeps what the fit absorbs of slow errors (a smooth trajectory in a slowly changing field:
    the parameters take up part of the slow errors, and sandwich estimates from the residuals
    fall short of the spread). For independent samples it is the sandwich A^-1 (sum S S^T) A^-1
    with a leverage correction, s^2 A^-1 to within its noise.
    """
    series = np.asarray(series, dtype=float)
    blocks = np.asarray(informations, dtype=float)
    starts = np.arange(0, series.shape[0], max(1, int(length)))
    sums = np.add.reduceat(series, starts, axis=0)
    shares = np.add.reduceat(blocks, starts, axis=0)
    total = blocks.sum(axis=0)
    deltas = np.array([np.linalg.lstsq(total - a, s, rcond=None)[0] for a, s in zip(shares, sums)])
    groups = len(starts)
    centred = deltas - deltas.mean(axis=0)
    return (groups - 1) / groups * centred.T @ centred, groups


def loewner_max(meat, floor, basis) -> np.ndarray:
    """The smallest matrix at least as large as both `meat` and `floor` along every direction of
    `basis` (q columns) that keeps their eigen-directions relative to `floor`: with floor = L L^T
    on the basis, the eigenvalues of L^-1 meat L^-T clipped below at 1. Sandwiched by A^-1 (a
    congruence, which keeps the order) every variance of the result is at least the floor's
    and at least the meat's. Where the floor is singular the meat is kept."""
    reduced = basis.T @ np.asarray(meat, dtype=float) @ basis
    bottom = basis.T @ np.asarray(floor, dtype=float) @ basis
    try:
        lower = np.linalg.cholesky(0.5 * (bottom + bottom.T))
    except np.linalg.LinAlgError:
        return np.asarray(meat, dtype=float)
    relative = np.linalg.solve(lower, np.linalg.solve(lower, reduced).T)
    values, vectors = np.linalg.eigh(0.5 * (relative + relative.T))
    clipped = lower @ (vectors * np.maximum(values, 1.0)) @ vectors.T @ lower.T
    return basis @ clipped @ basis.T


def t_widening(dof: int) -> float:
    """t_{0.975, dof} / z_{0.975}: how much wider a standard error estimated with `dof` degrees
    of freedom is stated so that +/-1.96 standard errors cover 95 % (the Cornish-Fisher
    expansion of Student's t quantile, Abramowitz & Stegun 26.7.5; within 1e-3 from dof 3). [1]"""
    z = Z_975
    nu = max(float(dof), 2.0)
    t = (
        z
        + (z**3 + z) / (4 * nu)
        + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * nu**2)
        + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * nu**3)
        + (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / (92160 * nu**4)
    )
    return float(t / z)


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
