"""Ridge regression from a Gram matrix, its parameter chosen by generalised cross-validation.

The fit is linear least squares, y = X beta + e, on the band-passed columns, so it is solved in
closed form from the sums the pass gathered: X'X, X'y and y'y (`nlpcal.platform.bandpass`). The
Tolles-Lawson terms are nearly collinear, so the solve is regularised (Hoerl and Kennard [1]):
on the columns scaled to unit norm (R = D^-1 X'X D^-1, D = diag(X'X)^1/2, the correlation form,
so that one parameter penalises every term alike whatever its unit),

    beta_s(lambda) = (R + lambda I)^-1 r,     r = D^-1 X'y,     beta = D^-1 beta_s

and lambda minimises the generalised cross-validation score of Golub, Heath and Wahba [2],

    GCV(lambda) = n RSS(lambda) / (n - tr H(lambda))^2,    tr H = sum_k d_k / (d_k + lambda)
    RSS(lambda) = y'y - sum_k a_k^2 (d_k + 2 lambda) / (d_k + lambda)^2,    a = V' r

with R = V diag(d) V' (Eq. 1.4 and 2.3 of [2]): one eigendecomposition of the small matrix R
gives the score at every lambda. The same decomposition gives the condition number of the scaled
design, (d_max / d_min)^1/2, and the variance inflation factors, the diagonal of R^-1 (Marquardt
[3]): how much collinearity inflates the variance of each coefficient. The rows of band-passed
data are correlated, which GCV does not know: it takes n rows for n independent ones and may
choose too little regularisation; the compensation, which is what is judged, is not sensitive
to it.

References
----------
[1] Hoerl A. E., Kennard R. W. (1970), Ridge regression: biased estimation for nonorthogonal
    problems, Technometrics 12(1), 55-67. doi:10.1080/00401706.1970.10488634
[2] Golub G. H., Heath M., Wahba G. (1979), Generalized cross-validation as a method for
    choosing a good ridge parameter, Technometrics 21(2), 215-223.
    doi:10.1080/00401706.1979.10489751
[3] Marquardt D. W. (1970), Generalized inverses, ridge regression, biased linear estimation,
    and nonlinear estimation, Technometrics 12(3), 591-612. doi:10.1080/00401706.1970.10488699
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Eigenvalues of R below this fraction of the largest count as zero (the design's rank lost to
#: rounding): they bound the condition number and the variance inflation, which stay finite.
EIGENVALUE_FLOOR = 1e-15
#: The search of lambda: a grid from LAMBDA_RANGE[0] to LAMBDA_RANGE[1] times the largest
#: eigenvalue of R, GRID points per decade, then a bounded search about the grid's best. [1]
LAMBDA_RANGE = (1e-14, 1e2)
GRID = 8


@dataclass
class Ridge:
    """The ridge solution of the sums of a least-squares problem.

    coefficients : beta, in the columns' units. (p,)
    parameter : lambda, for the columns scaled to unit norm. [1]
    residual_sum : RSS(lambda), the sum of the squared residuals. [y unit^2]
    effective_terms : tr H(lambda), the degrees of freedom the fit uses. [1]
    condition_number : (d_max / d_min)^1/2 of the scaled design. [1]
    variance_inflation : the diagonal of R^-1, per column. [1]
    """

    coefficients: np.ndarray
    parameter: float
    residual_sum: float
    effective_terms: float
    condition_number: float
    variance_inflation: np.ndarray


def solve(gram: np.ndarray, cross: np.ndarray, total: float, n: int) -> Ridge:
    """The ridge solution, lambda chosen by GCV, of X'X = `gram` (p, p), X'y = `cross` (p,),
    y'y = `total` over `n` rows (module docstring); every column of X must have a positive
    norm."""
    scale = np.sqrt(np.diag(gram))
    correlation = gram / np.outer(scale, scale)
    d, v = np.linalg.eigh(0.5 * (correlation + correlation.T))
    d = np.maximum(d, EIGENVALUE_FLOOR * d[-1])
    a = v.T @ (cross / scale)

    def residual_sum(lam: float) -> float:  # Eq. 2.3 of [2], through the eigenvalues
        return float(total - np.sum(a**2 * (d + 2.0 * lam) / (d + lam) ** 2))

    def score(log_lam: float) -> float:  # GCV, Eq. 1.4 of [2]
        lam = 10.0**log_lam
        effective = float(np.sum(d / (d + lam)))
        return n * max(residual_sum(lam), 0.0) / max(n - effective, 1.0) ** 2

    lam = 10.0 ** _minimise(score, *np.log10(np.array(LAMBDA_RANGE) * d[-1]))
    beta_scaled = v @ (a / (d + lam))
    return Ridge(
        coefficients=beta_scaled / scale,
        parameter=float(lam),
        residual_sum=max(residual_sum(lam), 0.0),
        effective_terms=float(np.sum(d / (d + lam))),
        condition_number=float(np.sqrt(d[-1] / d[0])),
        variance_inflation=(v**2) @ (1.0 / d),  # diag(R^-1) = sum_k v_jk^2 / d_k [3]
    )


def _minimise(score, low: float, high: float) -> float:
    """The log10 lambda in [low, high] of the lowest score: a grid, then golden-section search
    in the grid's neighbourhood of its best point."""
    grid = np.linspace(low, high, int(round((high - low) * GRID)) + 1)
    values = [score(x) for x in grid]
    best = int(np.argmin(values))
    a, b = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    c, d = b - ratio * (b - a), a + ratio * (b - a)
    fc, fd = score(c), score(d)
    for _ in range(40):  # the bracket shrinks by 0.618 each step: 1e-8 of a decade
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - ratio * (b - a)
            fc = score(c)
        else:
            a, c, fc = c, d, fd
            d = a + ratio * (b - a)
            fd = score(d)
    candidates = [(values[best], grid[best]), (fc, c), (fd, d)]
    return min(candidates)[1]
