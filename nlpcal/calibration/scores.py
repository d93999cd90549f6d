"""The scores of a calibration: per sample, its loss's psi(r_i) times the sensitivity J_i of its
residual to the nine parameters, summed over consecutive blocks of samples, in the one pass
over the data after the solve that also gathers the Table 1 rows (`after_solve`).

The residual of sample i is r_i = |B1_i| - F_i (a reference) or |B1_i| - c (none: c the mean of
|B1|, or the robust loss's centre), |B1_i| = |M (B_M,i - Z_p)| (Eq. 4 in [1]). With c_i =
B_M,i - Z_p and u_i = B1_i / |B1_i|, its sensitivity in the scaled variables y = theta / D of
the problems (`nlpcal.nlp.blocks.variable_scale`) is linear in f_i = (u_i, u_i c_i^T):

    d|B1| / dZ_p = -M^T u,    d|B1| / dM_jk = u_j c_k,    J_i = f_i L,

L (12, 9) fixed by theta (M's six entries follow the scale errors and angles by
`correction_matrix_entries`, their derivatives by a complex step, exact to rounding). Without a
reference the centre c is estimated with theta; the score of theta with c profiled out is
psi(r_i) (J_i - Jbar), Jbar the psi'-weighted mean of J (the mean for least squares), so each
block sum is sum psi J - Jbar sum psi.

Per chunk the work is a few products of whole arrays: the rows x_i = (psi' J_i, psi', psi) and
y_i = (J_i, 1), and per block of `block_rows` consecutive samples (counted from the log's first
row, so that the sums do not depend on how a pass splits the rows: threads, `--low-memory` or
Dask) the product X_k^T Y_k (11, 10), one batched matrix product for the blocks of a chunk. It
holds the block's sums of the scores psi J, of psi, psi' J, psi' and psi' J J^T: the series
`nlpcal.inference.dependence_meat` turns into the meat of the sandwich covariance. The noise
terms of the bias and, on request, sum psi(r_i)^2 J_i J_i^T (the meat of independent samples)
are sums over every sample, products of the chunk's arrays as well.

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
from ..statistics import correction, merge_each

#: Complex step for the derivatives of M's entries. [rad or 1]
COMPLEX_STEP = 1e-30
#: Rows of the chunks of the pass after the solve (a few arrays of 12 columns: 0.8 MB), rounded
#: to whole score blocks.
SCORE_CHUNK_ROWS = 8192
#: The upper-triangular entries of M, as (row, column).
ENTRIES = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
#: Columns of x_i: psi' J (9), psi', psi; y_i is (J, 1).
PSI_SLOPE, PSI = 9, 10
#: Sums over every sample: psi' df along g (12), psi' tr f (12), psi' tr, |g|^2.
NOISE_WIDTH = 26


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
    the scaled variables (n, 9) [field unit] and to the raw sample, g = M^T u (n, 3), each
    sample's own (the channels' scores pass of `channel_errors` adds columns to them). [1]"""
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


def _merge(earlier: tuple, later: tuple) -> tuple:
    """Two partial results (index of the first block, block sums (k, w), totals) of neighbouring
    rows: their block sums joined, a block split between them added; their totals added."""
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


def sensitivity_map(theta, radius: float) -> np.ndarray:
    """L (12, 9): J = f L for f = (u, u c^T flattened by rows), in the scaled variables."""
    _, matrix = correction(theta)
    derivatives = entry_derivatives(theta)
    linear = np.zeros((12, 9))
    linear[0:3, 0:3] = -matrix  # d|B1|/dZ = -M^T u, as a row: -u M
    for e, (j, c) in enumerate(ENTRIES):
        linear[3 + 3 * j + c, 3:9] = derivatives[e]
    return linear * variable_scale(radius)[None, :]


def block_products(x: np.ndarray, y: np.ndarray, first_row: int, rows: int) -> tuple:
    """(index of the first block, X_k^T Y_k per block (k, 11, 10)) of the columns of a chunk
    (x (11, n), y (10, n): one column per sample) that starts at row `first_row` of the log,
    blocks of `rows` samples counted from the log's first."""
    n = x.shape[1]
    head = min(n, (-first_row) % rows)
    full = (n - head) // rows
    tail = n - head - full * rows
    parts = [(x[:, :head] @ y[:, :head].T)[None]] if head else []
    if full:
        body = slice(head, head + full * rows)
        xs = x[:, body].reshape(x.shape[0], full, rows).transpose(1, 0, 2)
        ys = y[:, body].reshape(y.shape[0], full, rows).transpose(1, 2, 0)
        parts.append(np.matmul(xs, ys))
    if tail:
        parts.append((x[:, n - tail :] @ y[:, n - tail :].T)[None])
    return first_row // rows, np.concatenate(parts) if len(parts) > 1 else parts[0]


@dataclass
class ScorePart:
    """The score sums of consecutive rows: from block `first` on, X_k^T Y_k per block
    (`products`, (k, 11, 10)) or, for blocks of one sample, x_i and J_i themselves (`rows`,
    (x (k, 11), J (k, 9))), and the sums over every row (`totals`: the noise terms, then
    sum psi^2 y y^T when asked)."""

    first: int
    products: np.ndarray | None
    rows: tuple | None
    totals: np.ndarray

    def merge(self, later: ScorePart) -> ScorePart:
        """These rows' sums joined with those of the rows right after them."""
        totals = self.totals + later.totals
        if self.rows is not None and later.rows is not None:
            rows = tuple(np.concatenate([a, b]) for a, b in zip(self.rows, later.rows))
            return ScorePart(self.first, None, rows, totals)
        mine, theirs = self.products, later.products
        if mine is None or not len(mine):
            return ScorePart(later.first, theirs, None, totals)
        if theirs is None or not len(theirs):
            return ScorePart(self.first, mine, None, totals)
        overlap = self.first + len(mine) - later.first  # 1 when a block straddles, else 0
        joined = np.concatenate([mine, theirs[overlap:]])
        if overlap:
            joined[len(mine) - 1] += theirs[0]
        return ScorePart(self.first, joined, None, totals)

    def products_all(self) -> np.ndarray:
        """X_k^T Y_k per block (k, 11, 10)."""
        if self.products is not None:
            return self.products
        x, jacobian = self.rows  # type: ignore[misc]
        y = np.concatenate([jacobian, np.ones((len(jacobian), 1))], axis=1)
        return x[:, :, None] * y[:, None, :]


@dataclass(frozen=True)
class ScoreTerms:
    """The score sums at one theta: what a chunk of the pass after the solve adds.

    offset, matrix : the correction of Eq. 4 at theta. linear : L of `sensitivity_map`.
    block_rows : samples per block. loss : a robust `nlpcal.robust.Loss` with its scale, or None
    (least squares: psi(r) = r, psi' = 1). centre : without a reference, the centre of |B1| the
    residuals are taken from [field unit]. meat : also sum psi^2 y y^T over every sample.
    """

    offset: np.ndarray
    matrix: np.ndarray
    linear: np.ndarray
    block_rows: int
    loss: Any
    centre: float | None
    meat: bool

    def empty(self, first_row: int, n: int) -> ScorePart:
        """The sums of no rows yet, for the n rows from `first_row` on."""
        first = first_row // self.block_rows
        width = NOISE_WIDTH + (100 if self.meat else 0)
        if self.block_rows == 1:
            return ScorePart(first, None, (np.empty((n, 11)), np.empty((n, 9))), np.zeros(width))
        count = (first_row + n - 1) // self.block_rows - first + 1 if n else 0
        return ScorePart(first, np.zeros((count, 11, 10)), None, np.zeros(width))

    def add(self, part: ScorePart, raw: np.ndarray, ref, first_row: int, begin: int):
        """Add a chunk of raw samples (rows begin: of `part`, `first_row` of the log) and its
        reference to `part`; returns |B1| of the chunk. [field unit]

        One column per sample (c, u: (3, n), f: (12, n), x: (11, n)), so that every operation
        runs along the samples."""
        n = raw.shape[0]
        centred = np.subtract(raw.T, self.offset[:, None], out=np.empty((3, n)))
        field = self.matrix @ centred
        magnitude = np.sqrt(np.einsum("in,in->n", field, field))
        inverse = 1.0 / magnitude
        f = np.empty((12, n))  # u, then u c^T by rows
        u = np.multiply(field, inverse, out=f[0:3])
        np.multiply(u[:, None, :], centred[None, :, :], out=f[3:12].reshape(3, 3, n))
        x = np.empty((11, n))
        np.matmul(self.linear.T, f, out=x[0:9])
        r = x[PSI]
        r[:] = magnitude - (ref if ref is not None else self.centre)
        slope = None if self.loss is None else self.loss.slope(r)
        y = x[0:10]
        if slope is None:  # least squares: x = (J, 1, r), y = (J, 1)
            x[PSI_SLOPE] = 1.0
        else:
            y = np.concatenate([x[0:9], np.ones((1, n))])
            x[0:9] *= slope
            x[PSI_SLOPE], x[PSI] = slope, self.loss.weight(r) * r
        if part.rows is not None:
            part.rows[0][begin : begin + n] = x.T
            part.rows[1][begin : begin + n] = y[0:9].T
        else:
            first, products = block_products(x, y, first_row, self.block_rows)
            start = first - part.first
            part.products[start : start + len(products)] += products  # type: ignore[index]
        part.totals[:NOISE_WIDTH] += self.noise_terms(f, inverse, slope)
        if self.meat:
            weighted = y * x[PSI]
            part.totals[NOISE_WIDTH:] += (weighted @ weighted.T).ravel()
        return magnitude

    def noise_terms(self, f, inverse, slope) -> np.ndarray:
        """The sums of the noise terms of the bias (`noise_bias`), weighted by psi' (Stein's
        lemma: the noise moves psi(r) by psi' times it; 1 for least squares): f's derivative
        along g = M^T u, df = (du, du c^T + u g^T) with du = (M g - u s) / |B1|, s = |g|^2,
        and tr(d2|B1|/db2) = (|M|_F^2 - s) / |B1|; then sum s. (NOISE_WIDTH,)

        All from the sums of a f and b f, a = psi' / |B1| and b = a s (one matrix product),
        since u u^T = u c^T M^T / |B1|: sum psi' du = M M^T sum a u - sum b u, sum psi' du c^T
        = M M^T sum a u c^T - sum b u c^T, sum psi' u g^T = (sum a u c^T) M^T M, and
        sum psi' tr f = |M|_F^2 sum a f - sum b f."""
        matrix = self.matrix
        g = matrix.T @ f[0:3]
        squares = np.einsum("in,in->n", g, g)
        weights = np.empty((2, f.shape[1]))
        if slope is None:
            weights[0] = inverse
        else:
            np.multiply(inverse, slope, out=weights[0])
        np.multiply(squares, weights[0], out=weights[1])
        (a, b), (total_a, total_b) = (f @ weights.T).T, weights.sum(axis=1)
        gram, frobenius = matrix @ matrix.T, float(np.sum(matrix * matrix))
        a_outer, b_outer = a[3:12].reshape(3, 3), b[3:12].reshape(3, 3)
        terms = np.empty(NOISE_WIDTH)
        terms[0:3] = gram @ a[0:3] - b[0:3]
        terms[3:12] = (gram @ a_outer - b_outer + a_outer @ matrix.T @ matrix).ravel()
        terms[12:24] = frobenius * a - b
        terms[24], terms[25] = frobenius * total_a - total_b, squares.sum()
        return terms


def block_rows(n: int) -> int:
    """Samples per block of the score series of `n` samples (at most MAX_BLOCKS blocks)."""
    return max(1, -(-int(n) // MAX_BLOCKS))


def score_terms(
    theta, radius: float, block_rows: int, loss, centre: float | None, meat: bool
) -> ScoreTerms:
    """The `ScoreTerms` at theta (internal units) in the scaled variables of a sphere frame of
    `radius` [field unit]; `loss` None or not robust is least squares."""
    offset, matrix = correction(theta)
    robust = loss if loss is not None and loss.robust else None
    return ScoreTerms(
        offset, matrix, sensitivity_map(theta, radius), block_rows, robust, centre, meat
    )


@dataclass(frozen=True)
class AfterSolve:
    """The work of the pass after the solve on one block of rows starting at row `start` of the
    log: the Table 1 sums of each of `rows` (`nlpcal.statistics.StatisticsBlock`; the first at
    the scores' theta when there are `scores`, sharing their |B1|) and the score sums."""

    rows: tuple
    scores: ScoreTerms | None
    chunk_rows: int
    shared: tuple = ()  # whether each row is at the scores' theta
    objectives: Any = None  # a `nlpcal.statistics.ObjectivesBlock`, or None

    def __call__(self, samples, reference, start: int) -> tuple:
        samples = np.asarray(samples, dtype=float)
        n = samples.shape[0]
        stats = [row.start() for row in self.rows]
        part = None if self.scores is None else self.scores.empty(start, n)
        objectives = None if self.objectives is None else self.objectives.start()
        begin = 0
        while begin < n:  # chunks aligned to multiples of chunk_rows rows of the log
            stop = min(n, ((start + begin) // self.chunk_rows + 1) * self.chunk_rows - start)
            raw, ref = samples[begin:stop], reference_chunk(reference, begin, stop)
            shared = None
            if self.scores is not None:
                shared = self.scores.add(part, raw, ref, start + begin, begin)  # type: ignore[arg-type]
            for k, (row, (total, sums)) in enumerate(zip(self.rows, stats)):
                at_theta = shared is not None and k < len(self.shared) and self.shared[k]
                row.add(total, sums, raw, ref, shared if at_theta else None)
            if objectives is not None:
                self.objectives.add(objectives, raw, ref)
            begin = stop
        return stats, part, objectives


def _merge_after(earlier: tuple, later: tuple) -> tuple:
    """Two partial results of the pass after the solve on neighbouring rows, merged."""
    stats = merge_each(earlier[0], later[0])
    part = None if earlier[1] is None else earlier[1].merge(later[1])
    objectives = None if earlier[2] is None else merge_each(earlier[2], later[2])
    return stats, part, objectives


def chunk_rows_for(block_rows: int) -> int:
    """Rows of the chunks of a pass with score blocks of `block_rows` rows: whole blocks, about
    SCORE_CHUNK_ROWS."""
    return max(1, SCORE_CHUNK_ROWS // block_rows) * block_rows


def after_solve(
    samples, reference, rows: list, scores: ScoreTerms | None = None, shared=(), objectives=None
) -> tuple:
    """One pass over the samples: the Table 1 sums of each `nlpcal.statistics.StatisticsBlock`
    of `rows` (those `shared` at the scores' theta take their |B1|), the `ScorePart` of the
    whole log (None without `scores`) and the totals of an `ObjectivesBlock` (or None).
    Returns ([(MagnitudeStats, sums)], part, totals)."""
    samples = as_rows(samples)
    chunk = chunk_rows_for(scores.block_rows) if scores is not None else SCORE_CHUNK_ROWS
    work = AfterSolve(tuple(rows), scores, chunk, tuple(shared), objectives)
    return reduce(samples, reference, work, _merge_after, chunk, indexed=True)


@dataclass
class ScoreSums:
    """The score sums of a log at theta, in the scaled variables (profiled without a
    reference): `series` (K, 9) the block sums S_k of psi(r_i) J_i; `informations()` the blocks'
    (K, 9, 9) shares A_k = sum psi'(r_i) J_i J_i^T of the information (formed when asked: a
    jackknife needs them, independent scores do not); `block_rows`; `bias` the noise terms of
    `nlpcal.calibration.diagnostics.noise_bias` ("gradient", E[sum psi(r_i) J_i] / sigma^2 =
    sum psi'(r_i) (dJ_i/db g_i + tr(d2|B1_i|/db2) J_i / 2), and "mean_square_g", the mean of
    |g|^2); `meat` (9, 9) sum psi(r_i)^2 J_i J_i^T over the samples or None (not asked)."""

    series: np.ndarray
    part: ScorePart
    mean: np.ndarray | None  # Jbar, when profiled
    block_rows: int
    bias: dict
    meat: np.ndarray | None
    #: The exact objectives of the exact-optimum check, when gathered in the same pass.
    exact_objectives: np.ndarray | None = None

    def information(self) -> np.ndarray:
        """A = sum psi'(r_i) J_i J_i^T over the samples (profiled without a reference): the
        bread of the sandwich of an M-estimate. (9, 9)"""
        if self.part.rows is not None:
            x, jacobian = self.part.rows
            total = x[:, 0:9].T @ jacobian
            weighted, slopes = x[:, 0:9].sum(axis=0), x[:, PSI_SLOPE].sum()
        else:
            products = self.part.products_all().sum(axis=0)
            total, weighted, slopes = products[0:9, 0:9], products[0:9, 9], products[PSI_SLOPE, 9]
        if self.mean is not None:
            cross = np.outer(weighted, self.mean)
            total = total - cross - cross.T + slopes * np.outer(self.mean, self.mean)
        return 0.5 * (total + total.T)

    def informations(self) -> np.ndarray:
        products = self.part.products_all()
        information = products[:, 0:9, 0:9]
        if self.mean is None:
            return np.array(information)
        weighted, slopes = products[:, 0:9, 9], products[:, PSI_SLOPE, 9]
        cross = weighted[:, :, None] * self.mean[None, None, :]
        outer = np.outer(self.mean, self.mean)
        return information - cross - cross.transpose(0, 2, 1) + slopes[:, None, None] * outer


def finished(part: ScorePart, terms: ScoreTerms, n: int, profiled: bool, shift: float = 0.0):
    """The `ScoreSums` of the `ScorePart` of a whole log of n samples; `profiled` without a
    reference. shift : for least squares, how far the centre the residuals were taken from lies
    below the one they are to be taken from (the mean of |B1|, known after the pass): psi = r is
    then lower by shift, psi' = 1 unchanged. [field unit]"""
    if part.rows is not None:
        x, jacobian = part.rows
        if shift:
            x[:, PSI] -= shift * x[:, PSI_SLOPE]
        scores, psi = x[:, PSI, None] * jacobian, x[:, PSI]
        weighted, slopes = x[:, 0:9], x[:, PSI_SLOPE]
    else:
        products = part.products_all()
        if shift:
            products[:, PSI] -= shift * products[:, PSI_SLOPE]
        scores, psi = products[:, PSI, 0:9], products[:, PSI, 9]
        weighted, slopes = products[:, 0:9, 9], products[:, PSI_SLOPE, 9]
    totals, linear = part.totals, terms.linear
    along, traced = totals[0:12] @ linear, totals[12:24] @ linear
    trace, squares = totals[24], totals[25]
    meat = totals[NOISE_WIDTH:].reshape(10, 10) if terms.meat else None
    mean = None
    if profiled:  # the centre profiled out: J_i - Jbar, Jbar the psi'-weighted mean
        mean = weighted.sum(axis=0) / slopes.sum()
        scores = scores - np.outer(psi, mean)
        traced = traced - mean * trace
        if meat is not None:
            squared, square = meat[9, 0:9], meat[9, 9]
            cross = np.outer(squared, mean)
            meat = meat[0:9, 0:9] - cross - cross.T + square * np.outer(mean, mean)
    elif meat is not None:
        meat = meat[0:9, 0:9]
    bias = {"gradient": along + 0.5 * traced, "mean_square_g": squares / n}
    return ScoreSums(scores, part, mean, terms.block_rows, bias, meat)


def score_block_sums(
    samples, theta, reference, loss, centre: float | None, radius: float, chunk_rows: int = 16384
) -> tuple:
    """(S, A, block_rows, bias, B) of the scores at theta (`ScoreSums`), in a pass of their own:
    S (K, 9) the block sums of the scores, A (K, 9, 9) the blocks' shares of the information,
    B (9, 9) sum psi(r_i)^2 J_i J_i^T.

    samples : (N, 3) raw output, in memory or a Dask log. [field unit]
    reference : None, a float or an (N,) series. centre : without a reference the centre of |B1|
        the residuals are taken from (the mean for least squares). [field unit]
    radius : the sphere frame's radius, for the scaled variables. [field unit]
    chunk_rows : the rows of the chunks (rounded to whole blocks).
    """
    samples = as_rows(samples)
    n = samples.shape[0]
    rows = block_rows(n)
    terms = score_terms(theta, radius, rows, loss, centre, meat=True)
    chunk = max(1, min(chunk_rows, SCORE_CHUNK_ROWS) // rows) * rows
    work = AfterSolve((), terms, chunk)
    _, part, _ = reduce(samples, reference, work, _merge_after, chunk, indexed=True)
    sums = finished(part, terms, n, reference is None)
    return sums.series, sums.informations(), rows, sums.bias, sums.meat
