"""The compiled columns of the pass after the solve, for `nlpcal.compiled` (numba): imported only
where they run."""

import math

import numba

# numpy's error model: a sample at Z_p gives |B1| = 0 and inf, as the numpy columns do, not a
# ZeroDivisionError
_compile = numba.njit(nogil=True, cache=True, fastmath={"reassoc", "contract"}, error_model="numpy")


@_compile
def columns(raw, offset, matrix, y, work, magnitude):
    """`nlpcal.calibration.scores.ScoreTerms.columns` for the n samples of raw (3, n), one loop
    over them: per sample c = B_M - Z_p, B1 = M c (Eq. 4), u = B1 / |B1| and g = M^T u; fills
    y[0:9, :n] with f = (u, u_j c_k for j <= k), work[11, :n] with 1 / |B1|, work[13, :n] with
    |g|^2 and magnitude[:n] with |B1|. [field unit]

    raw : (3, n) C-contiguous. offset : (3,) Z_p. matrix : (3, 3) M. y : (10, rows) and work
    (14, rows), rows >= n, C-contiguous.
    """
    n = raw.shape[1]
    for i in range(n):
        c0 = raw[0, i] - offset[0]
        c1 = raw[1, i] - offset[1]
        c2 = raw[2, i] - offset[2]
        u0 = matrix[0, 0] * c0 + matrix[0, 1] * c1 + matrix[0, 2] * c2
        u1 = matrix[1, 0] * c0 + matrix[1, 1] * c1 + matrix[1, 2] * c2
        u2 = matrix[2, 0] * c0 + matrix[2, 1] * c1 + matrix[2, 2] * c2
        length = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
        inverse = 1.0 / length
        u0 *= inverse
        u1 *= inverse
        u2 *= inverse
        y[0, i] = u0
        y[1, i] = u1
        y[2, i] = u2
        y[3, i] = u0 * c0  # the entries (j, k) of `scores.ENTRIES`
        y[4, i] = u0 * c1
        y[5, i] = u0 * c2
        y[6, i] = u1 * c1
        y[7, i] = u1 * c2
        y[8, i] = u2 * c2
        g0 = matrix[0, 0] * u0 + matrix[1, 0] * u1 + matrix[2, 0] * u2
        g1 = matrix[0, 1] * u0 + matrix[1, 1] * u1 + matrix[2, 1] * u2
        g2 = matrix[0, 2] * u0 + matrix[1, 2] * u1 + matrix[2, 2] * u2
        work[11, i] = inverse
        work[13, i] = g0 * g0 + g1 * g1 + g2 * g2
        magnitude[i] = length
