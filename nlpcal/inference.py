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
  parameter): when they show dependence (`scores_dependent`), by a moving-block jackknife
  (`moving_block_jackknife`), its blocks as long as the scores' dependence
  (`bartlett_bandwidth`), widened by Student's t on its degrees of freedom (`t_widening`): a
  log is a time series, and when the scores of neighbouring samples are alike the samples carry
  less information than their number says. Independent samples keep s^2 A^-1.

The widening by the residuals' lag-1 autocorrelation that other estimators still use
(`standard_error_inflation`) is the AR(1) variance inflation sqrt((1 + rho) / (1 - rho)).

References
----------
[K89] Kunsch, H. R. (1989). The jackknife and the bootstrap for general stationary
    observations. Annals of Statistics 17(3), 1217-1241.
[MS84] Meketon, M. S., Schmeiser, B. (1984). Overlapping batch means: something for nothing?
    Proceedings of the 1984 Winter Simulation Conference, 226-230.
[S46] Satterthwaite, F. E. (1946). An approximate distribution of estimates of variance
    components. Biometrics Bulletin 2(6), 110-114.
[BM02] Bell, R. M., McCaffrey, D. F. (2002). Bias reduction in standard errors for linear
    regression with multi-stage samples. Survey Methodology 28(2), 169-181.
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
#: The deleted blocks of the jackknife are this many times the automatic Bartlett bandwidth
#: long. [1]
GROUP_BANDWIDTHS = 3.0
#: The deleted blocks of the jackknife are at most a MIN_GROUPS-th of the log, and its variances
#: count at least MIN_GROUPS - 1 degrees of freedom (Student's t on 5 widens a standard error by
#: 1.31 at most): with fewer, a variance would rest on one or two stretches of the log. [1]
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


#: The scores' lag-1 autocorrelation counts as dependence above this many standard errors of an
#: independent series' (1 / sqrt(K)): with nine score series, by chance in about 1 % of logs. [1]
DEPENDENCE_Z = 3.0


def scores_dependent(series) -> bool:
    """Whether the (K, q) block sums of the scores are clearly dependent: the largest lag-1
    autocorrelation of a column above DEPENDENCE_Z / sqrt(K). Independent samples get the
    independent-sample sandwich (s^2 A^-1 for least squares) rather than a jackknife whose few
    groups of a short log state standard errors wider than the spread. [1]"""
    series = np.asarray(series, dtype=float)
    count = series.shape[0]
    if count < 3:
        return False
    lead, lag = series[1:], series[:-1]
    spread = np.sqrt(np.einsum("ij,ij->j", lead, lead) * np.einsum("ij,ij->j", lag, lag))
    rho = np.divide(
        np.einsum("ij,ij->j", lead, lag), spread, out=np.zeros_like(spread), where=spread > 0
    )
    return bool(rho.max() > DEPENDENCE_Z / np.sqrt(count))


def group_length(bandwidth: float, blocks: int) -> int:
    """Blocks per deleted block of the jackknife: GROUP_BANDWIDTHS automatic bandwidths, but no
    longer than a MIN_GROUPS-th of the log (a short log, or scores alike across most of it: the
    variance is then estimated on few degrees of freedom, which `t_widening` states). [blocks]"""
    length = int(np.ceil(GROUP_BANDWIDTHS * bandwidth))
    return max(1, min(length, blocks // MIN_GROUPS))


def moving_block_jackknife(series, informations, length: int, directions) -> tuple:
    """(V, dof): the covariance of an estimate by Kunsch's delete-a-block jackknife over the
    M = K - L + 1 overlapping blocks of L = `length` consecutive blocks [K89], normalised as
    overlapping batch means [MS84], and the degrees of freedom of each of its variances along
    `directions`.

    series : (K, q) block sums of the scores psi(r_i) J_i at the estimate. informations :
    (K, q, q) the blocks' shares A_k of the information A = sum A_k. directions : (p, q) the
    parameters in the q coordinates of the series (the gauge's basis).

    Without block j the gradient at the estimate is -S_j, so one Newton step gives the estimate
    without it, delta_j = (A - A_j)^-1 S_j, and

        V = (K - L) / (L M) sum_j (delta_j - mean)(delta_j - mean)^T.

    Kunsch's (K - L)^2 / (K L M) [K89, Eq. 2.5] is this times 1 - L / K, the share of a block's
    variance its centring removes: with blocks a sixth of the log, it states independent
    samples' variance 0.77 times too small; the batch means' (K - L) / (L M) is unbiased there.

    Blocks longer than the scores' dependence see it whole, so V follows it; each delta_j is the
    estimate refitted without the block, so V keeps what the fit absorbs of slow errors (a smooth
    trajectory in a slowly changing field). Overlapping blocks use every start: V changes
    little when K or L does by one (non-overlapping groups jumped with their count), and it
    rests on about 3/2 as many degrees of freedom as K / L separate groups [MS84].

    The degrees of freedom: the blocks are not alike (along a smooth trajectory each covers its
    own patch of directions), and a few with much leverage carry the variance. Under independent
    samples a block's share of the variance of parameter k is lambda_jk = (D C_j A_j C_j^T D^T)_kk,
    C_j = (A - A_j)^-1, and Satterthwaite's effective number of blocks is h_k K / L with
    h_k = mean(lambda_k)^2 / mean(lambda_k^2) <= 1 [S46; the design-based degrees of freedom of
    BM02]: dof_k = 3/2 h_k K / L - 1, no fewer than MIN_GROUPS - 1.
    """
    series = np.asarray(series, dtype=float)
    blocks = np.asarray(informations, dtype=float)
    directions = np.asarray(directions, dtype=float)
    count = series.shape[0]
    length = max(1, min(int(length), count - 1))
    running = np.concatenate([np.zeros((1, series.shape[1])), np.cumsum(series, axis=0)])
    shared = np.concatenate([np.zeros((1,) + blocks.shape[1:]), np.cumsum(blocks, axis=0)])
    sums = running[length:] - running[:-length]  # (M, q): S_j
    shares = shared[length:] - shared[:-length]  # (M, q, q): A_j
    remaining = blocks.sum(axis=0)[None] - shares  # A - A_j
    try:
        inverses = np.linalg.inv(remaining)  # C_j
    except np.linalg.LinAlgError:  # a block that holds all the information along a direction
        inverses = np.linalg.pinv(remaining, hermitian=True)
    deltas = np.matmul(inverses, sums[:, :, None])[:, :, 0]
    centred = deltas - deltas.mean(axis=0)
    starts = count - length + 1
    covariance = (count - length) / (length * starts) * centred.T @ centred
    mapped = np.matmul(directions, inverses)  # D C_j
    shares_of_variance = np.sum(np.matmul(mapped, shares) * mapped, axis=2)  # lambda_jk
    mean_square = np.mean(shares_of_variance**2, axis=0)
    alike = np.divide(
        np.mean(shares_of_variance, axis=0) ** 2,
        mean_square,
        out=np.ones_like(mean_square),
        where=mean_square > 0,
    )
    dof = np.maximum(1.5 * alike * count / length - 1.0, MIN_GROUPS - 1.0)
    return covariance, dof


#: Largest number of blocks of a score series: a longer log sums neighbours into blocks of
#: several samples (the series stays small whatever the log's length, and a jackknife over
#: blocks of consecutive blocks estimates the same long-run covariance as over samples).
MAX_BLOCKS = 4096


def block_rows(n: int) -> int:
    """Samples per block of the score series of `n` samples (at most MAX_BLOCKS blocks)."""
    return max(1, -(-int(n) // MAX_BLOCKS))


def block_sums(scores, informations) -> tuple:
    """(S, A, rows): per-sample scores (N, p) and information shares (N, p, p) summed over
    blocks of `block_rows(N)` consecutive samples (counted from the first)."""
    scores = np.asarray(scores, dtype=float)
    rows = block_rows(scores.shape[0])
    starts = np.arange(0, scores.shape[0], rows)
    shares = np.add.reduceat(np.asarray(informations, dtype=float), starts, axis=0)
    return np.add.reduceat(scores, starts, axis=0), shares, rows


def dependence_meat(series, informations, independent, dof: int, basis=None) -> tuple:
    """(Omega, description, dof): the meat of the sandwich covariance A^-1 Omega A^-1 of an
    estimate from the (K, p) block sums of its scores psi(r_i) J_i at the estimate (`series`)
    and the blocks' (K, p, p) shares of the information A (`informations`, or a function that
    forms them: only a jackknife reads them), on the directions of `basis` (p, q orthonormal
    columns; None: all).

    independent : (p, p) the meat of independent samples (s^2 A for least squares, sum psi^2
        J J^T for an M-estimate). dof : the degrees of freedom of the fit (N - p).

    Scores without clear dependence (`scores_dependent`): Omega = independent, widened by
    Student's t on `dof`. Otherwise A V A, V the moving-block jackknife's covariance
    (`moving_block_jackknife`, blocks of GROUP_BANDWIDTHS automatic Bartlett bandwidths
    `bartlett_bandwidth`), each parameter's variance widened by `t_widening` for its own degrees
    of freedom, and never narrower than `independent` along any direction (`loewner_max`: a
    jackknife on few blocks can fall below it by chance, and dependence seldom makes a fit more
    precise). The description is what a result records of it (`score_dependence`); the last
    item the degrees of freedom of each of the p variances.
    """
    series = np.asarray(series, dtype=float)
    p = series.shape[1]
    basis = np.eye(p) if basis is None else np.asarray(basis, dtype=float)
    projected = series @ basis
    bandwidth = bartlett_bandwidth(projected)
    student = t_widening(dof)
    description: dict = {
        "method": "independent",
        "bandwidth_blocks": bandwidth,
        "group_blocks": 1,
        "groups": len(projected),
        "t_widening": student,
    }
    if not scores_dependent(projected):
        freedom = np.full(p, float(max(dof, 1)))
        return np.asarray(independent) * student**2, description, freedom
    shares = projected_shares(informations() if callable(informations) else informations, basis)
    length = group_length(bandwidth, len(projected))
    covariance, freedom = moving_block_jackknife(projected, shares, length, basis)
    widening = np.array([t_widening(v) for v in freedom])
    # each parameter's standard error widened by its own t: V -> P W V W P, P = basis basis^T
    across = basis.T @ (widening[:, None] * basis)
    total = shares.sum(axis=0)
    meat = basis @ (total @ across @ covariance @ across @ total) @ basis.T
    description.update(
        method="moving-block-jackknife",
        group_blocks=length,
        groups=len(projected) - length + 1,
        t_widening=float(widening.max()),
    )
    return loewner_max(meat, independent, basis), description, freedom


def projected_shares(informations, basis) -> np.ndarray:
    """B^T A_k B for each of the (K, p, p) `informations`, with two matrix products. (K, q, q)"""
    blocks = np.asarray(informations, dtype=float)
    count, p, q = blocks.shape[0], basis.shape[0], basis.shape[1]
    right = (blocks.reshape(count * p, p) @ basis).reshape(count, p, q)  # A_k B
    left = right.transpose(0, 2, 1).reshape(count * q, p) @ basis  # (A_k B)^T B = B^T A_k B
    return left.reshape(count, q, q)


def least_squares_uncertainty(jacobian, residuals, dof: int) -> tuple:
    """(Uncertainty, score_dependence): standard errors of a least-squares fit from its
    per-sample residuals r_i (N,) and their Jacobian J (N, p) in the parameters' units: the
    sandwich A^-1 Omega A^-1, A = J^T J, Omega from the scores r_i J_i (`dependence_meat`: s^2 A
    when they show no dependence on their neighbours, s^2 = sum r^2 / dof)."""
    jacobian = np.asarray(jacobian, dtype=float)
    residuals = np.asarray(residuals, dtype=float)
    information = jacobian.T @ jacobian
    series, shares, rows = block_sums(
        jacobian * residuals[:, None], np.einsum("ni,nj->nij", jacobian, jacobian)
    )
    independent = float(residuals @ residuals) / max(dof, 1) * information
    meat, description, freedom = dependence_meat(series, shares, independent, dof)
    description["block_samples"] = rows
    description["degrees_of_freedom"] = [float(v) for v in freedom]
    return estimate(information, meat=meat, dof=dof), description


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
    (result,) = estimates(
        information,
        [meat],
        residual_variance=residual_variance,
        scale=scale,
        basis=basis,
        autocorrelation=autocorrelation,
        dof=dof,
    )
    return result


def estimates(
    information,
    meats: list,
    *,
    residual_variance: float = 1.0,
    scale=None,
    basis=None,
    autocorrelation: float = 0.0,
    dof: int = 1,
) -> list:
    """`estimate` with each of `meats` (None: s^2 A^-1), from one eigen-decomposition and one
    inverse of the information. [as `estimate`]"""
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
    weakest = sorted(involved(0)) if values.size else []
    inflation = standard_error_inflation(autocorrelation)
    determined = not weak and dof > 0 and np.isfinite(residual_variance)
    inverse = b @ np.linalg.inv(reduced) @ b.T if determined else None
    covariances = [
        _covariance(inverse, meat, d, float(residual_variance), inflation) for meat in meats
    ]
    return [
        Uncertainty(
            covariance=covariance,
            standard_errors=errors,
            eigenvalues=values,
            weak=list(weak),
            weakest=list(weakest),
            autocorrelation=float(autocorrelation),
            inflation=inflation,
        )
        for covariance, errors in covariances
    ]


def _covariance(inverse, meat, d, residual_variance: float, inflation: float) -> tuple:
    """(covariance, standard errors) in the parameters' units of `estimates`: s^2 A^-1 (`meat`
    None) or A^-1 B A^-1 from `inverse` = A^-1 in the scaled variables; (None, None) without
    it."""
    if inverse is None:
        return None, None
    if meat is None:
        cov_scaled = inverse * (residual_variance * inflation**2)
    else:
        meat_scaled = d[:, None] * np.asarray(meat, dtype=float) * d[None, :]
        cov_scaled = inverse @ meat_scaled @ inverse * inflation**2
    covariance = d[:, None] * cov_scaled * d[None, :]
    return covariance, np.sqrt(np.clip(np.diag(covariance), 0, None))


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
