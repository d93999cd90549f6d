"""The scores of a calibration: per sample, its loss's psi(r_i) times the sensitivity J_i of its
residual to the nine parameters, summed over consecutive blocks of samples in one pass.

The residual of sample i is r_i = |B1_i| - F_i (a reference) or |B1_i| - c (none: c the mean of
|B1|, or the robust loss's centre), |B1_i| = |M (B_M,i - Z_p)| (Eq. 4 in [1]). Its sensitivity in
the scaled variables y = theta / D of the problems (`nlpcal.nlp.blocks.variable_scale`):

    d|B1| / dZ_p = -M^T u,    d|B1| / dM_jk = u_j (B_M - Z_p)_k,    u = B1 / |B1|,

M's six entries following the scale errors and angles by `correction_matrix_entries` (their
derivatives by a complex step, exact to rounding). Without a reference the centre c is estimated
with theta; the score of theta with c profiled out is psi(r_i) (J_i - Jbar), Jbar the psi'-weighted
mean of J (the mean for least squares), so each block sum is sum psi J - Jbar sum psi.

The block sums (blocks of `block_rows` consecutive samples, counted from the log's first row, so
that the sums do not depend on how a pass splits the rows: threads, `--low-memory` or Dask) are
the series `nlpcal.inference.dependence_meat` turns into the meat of the sandwich covariance;
the same pass sums psi(r_i)^2 J_i J_i^T over every sample, the meat of independent samples.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..inference import MAX_BLOCKS
from ..models.zhou2010 import correction_matrix_entries
from ..nlp.blocks import variable_scale
from ..passes import as_rows, reduce, reference_chunk
from ..statistics import correction

#: Complex step for the derivatives of M's entries. [rad or 1]
COMPLEX_STEP = 1e-30
#: Rows of the chunks of a block of the scores pass (512 rows of WIDTH sums are 0.3 MB).
SCORE_CHUNK_ROWS = 512
#: The entries of psi' J J^T a block sums: its upper triangle (row <= column).
UPPER = np.triu_indices(9)
#: Columns of a block's sums: psi J (9), psi, psi' J (9), psi', the upper triangle of
#: psi' J J^T (45), the noise terms: dJ/db g (9), tr J (9), tr, |g|^2, then the terms of the
#: meat of independent samples: psi^2 J (9), psi^2, the upper triangle of psi^2 J J^T (45).
WIDTH = 20 + len(UPPER[0]) + 20 + 10 + len(UPPER[0])
#: The columns summed per block; the rest (the noise and meat terms) only over the whole log.
BLOCK_WIDTH = 20 + len(UPPER[0])
#: The first column of the meat's terms.
MEAT = 40 + len(UPPER[0])
#: The step of the derivative of J along g, relative to the sphere's radius. [1]
NOISE_STEP = 1e-5
#: The upper-triangular entries of M, as (row, column).
ENTRIES = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def entry_derivatives(theta) -> np.ndarray:
    """(6, 6): d(M's upper entries, ENTRIES order) / d(s_x, s_y, s_z, alpha, beta, gamma). [1]"""
    theta = np.asarray(theta, dtype=float)
    columns = []
    for k in range(3, 9):
        step = theta.astype(complex)
        step[k] += 1j * COMPLEX_STEP
        matrix = correction_matrix_entries(step[6], step[7], step[8], step[3], step[4], step[5])
        columns.append([complex(matrix[j][c]).imag / COMPLEX_STEP for j, c in ENTRIES])
    return np.array(columns).T


def sensitivities(raw, theta, derivatives, scale) -> tuple:
    """(|B1|, J, g): |B1| of a chunk of raw samples (n,) [field unit], the sensitivities of it to
    the scaled variables (n, 9) [field unit] and to the raw sample, g = M^T u (n, 3). [1]"""
    offset, matrix = correction(theta)
    centred = raw - offset
    field = centred @ matrix.T
    magnitude = np.sqrt(np.einsum("ij,ij->i", field, field))
    u = field / magnitude[:, None]
    jacobian = np.empty((raw.shape[0], 9))
    jacobian[:, 0:3] = -(u @ matrix)
    products = np.stack([u[:, j] * centred[:, c] for j, c in ENTRIES], axis=1)
    jacobian[:, 3:9] = products @ derivatives
    return magnitude, jacobian * scale, -jacobian[:, 0:3]


@dataclass(frozen=True)
class ScoreBlock:
    """The work of the scores pass on one block of rows starting at row `start` of the log:
    (index of its first score block, the sums of the first BLOCK_WIDTH columns per score block
    (k, BLOCK_WIDTH), the sums of the others over the rows (WIDTH - BLOCK_WIDTH,))."""

    theta: np.ndarray
    derivatives: np.ndarray
    scale: np.ndarray
    block_rows: int
    loss: Any
    centre: float | None
    step: float  # of the derivative along g [field unit]
    frobenius: float  # |M|_F^2 [1]
    chunk_rows: int = SCORE_CHUNK_ROWS

    def __call__(self, samples, reference, start: int) -> tuple:
        samples = np.asarray(samples, dtype=float)
        n = samples.shape[0]
        first = start // self.block_rows
        count = (start + n - 1) // self.block_rows - first + 1 if n else 0
        sums = np.zeros((count, BLOCK_WIDTH))
        totals = np.zeros(WIDTH - BLOCK_WIDTH)
        for begin in range(0, n, self.chunk_rows):
            stop = min(begin + self.chunk_rows, n)
            raw = samples[begin:stop]
            magnitude, jacobian, gradient = sensitivities(
                raw, self.theta, self.derivatives, self.scale
            )
            ref = reference_chunk(reference, begin, stop)
            r = magnitude - (ref if ref is not None else self.centre)
            psi, slope = self.loss.weight(r) * r, self.loss.slope(r)
            weighted = jacobian * slope[:, None]
            # the noise terms of the bias (`noise_bias`), weighted by psi' (Stein's lemma: the
            # noise moves psi(r) by psi' times it; 1 for least squares): J's derivative along g,
            # and
            # tr(d2|B1|/db2) = (|M|_F^2 - |g|^2) / |B1|
            h = self.step
            ahead = sensitivities(raw + h * gradient, self.theta, self.derivatives, self.scale)
            behind = sensitivities(raw - h * gradient, self.theta, self.derivatives, self.scale)
            along = (ahead[1] - behind[1]) / (2 * h)
            squares = np.einsum("ij,ij->i", gradient, gradient)
            trace = (self.frobenius - squares) / magnitude
            values = np.column_stack(
                [
                    jacobian * psi[:, None],
                    psi,
                    weighted,
                    slope,
                    weighted[:, UPPER[0]] * jacobian[:, UPPER[1]],
                    along * slope[:, None],
                    weighted * trace[:, None],
                    trace * slope,
                    squares,
                    jacobian * (psi**2)[:, None],
                    psi**2,
                    jacobian[:, UPPER[0]] * jacobian[:, UPPER[1]] * (psi**2)[:, None],
                ]
            )
            index = (start + np.arange(begin, stop)) // self.block_rows - first
            edges = np.flatnonzero(np.diff(index, prepend=-1))  # the rows that open a block
            sums[index[edges]] += np.add.reduceat(values[:, :BLOCK_WIDTH], edges, axis=0)
            totals += values[:, BLOCK_WIDTH:].sum(axis=0)
        return first, sums, totals


def _merge(earlier: tuple, later: tuple) -> tuple:
    """Two partial results of neighbouring rows: their block sums joined, a block split between
    them added; their totals added."""
    (first, sums, totals), (second, more, others) = earlier, later
    if not len(sums):
        return second, more, totals + others
    if not len(more):
        return first, sums, totals + others
    overlap = first + len(sums) - second  # 1 when a block straddles the boundary, else 0
    joined = np.concatenate([sums, more[overlap:]])
    if overlap:
        joined[len(sums) - 1] += more[0]
    return first, joined, totals + others


def score_block_sums(
    samples, theta, reference, loss, centre: float | None, radius: float, chunk_rows: int = 16384
) -> tuple:
    """(S, A, block_rows, bias, B): per block of `block_rows` consecutive samples, the sum S_k
    (K, 9) of the scores psi(r_i) J_i at theta and the sum A_k (K, 9, 9) of psi'(r_i) J_i J_i^T (the
    block's share of the information), in the scaled variables and, without a reference, with
    the centre profiled out (J_i - Jbar); one pass over the samples.

    samples : (N, 3) raw output, in memory or a Dask log. [field unit]
    reference : None, a float or an (N,) series. centre : without a reference the centre of
        |B1| the residuals are taken from (the mean for least squares). [field unit]
    radius : the sphere frame's radius, for the scaled variables. [field unit]

    bias : the terms of the estimate's bias to second order in the sensor noise
    (`nlpcal.calibration.diagnostics.noise_bias`): "gradient", E[sum psi(r_i) J_i] / sigma^2 =
    sum psi'(r_i) (dJ_i/db g_i + tr(d2|B1_i|/db2) J_i / 2) (profiled without a reference), and
    "mean_square_g", the mean of |g|^2 (the noise of |B1| is sigma |g|).

    B : (9, 9) sum psi(r_i)^2 J_i J_i^T over the samples (profiled without a reference), the
    meat of the sandwich for independent samples: the sum of S_k S_k^T over blocks of several
    samples would add their dependence within each block.
    """
    samples = as_rows(samples)
    n = samples.shape[0]
    block_rows = max(1, -(-n // MAX_BLOCKS))
    theta = np.asarray(theta, dtype=float)
    offset, matrix = correction(theta)
    work = ScoreBlock(
        theta,
        entry_derivatives(theta),
        variable_scale(radius),
        block_rows,
        loss,
        centre,
        NOISE_STEP * radius,
        float(np.sum(matrix * matrix)),
        min(chunk_rows, SCORE_CHUNK_ROWS),
    )
    _, sums, totals = reduce(samples, reference, work, _merge, chunk_rows, indexed=True)
    scores, psi = sums[:, 0:9], sums[:, 9]
    weighted, slopes = sums[:, 10:19], sums[:, 19]
    upper = sums[:, 20 : 20 + len(UPPER[0])]
    information = np.zeros((len(sums), 9, 9))
    information[:, UPPER[0], UPPER[1]] = upper
    information[:, UPPER[1], UPPER[0]] = upper
    noise, terms = totals[: MEAT - BLOCK_WIDTH], totals[MEAT - BLOCK_WIDTH :]
    squared, square = terms[0:9], terms[9]
    meat = np.zeros((9, 9))
    meat[UPPER[0], UPPER[1]] = terms[10:]
    meat[UPPER[1], UPPER[0]] = terms[10:]
    along, traced, trace, squares = noise[0:9], noise[9:18], noise[18], noise[19]
    mean = weighted.sum(axis=0) / slopes.sum()
    if reference is None:  # the centre profiled out: J_i - Jbar, Jbar the psi'-weighted mean
        scores = scores - np.outer(psi, mean)
        cross = np.einsum("ki,j->kij", weighted, mean)
        information = (
            information
            - cross
            - cross.transpose(0, 2, 1)
            + slopes[:, None, None] * np.outer(mean, mean)
        )
        traced = traced - mean * trace
        outer = np.outer(squared, mean)
        meat = meat - outer - outer.T + square * np.outer(mean, mean)
    bias = {"gradient": along + 0.5 * traced, "mean_square_g": squares / n}
    return scores, information, block_rows, bias, meat
