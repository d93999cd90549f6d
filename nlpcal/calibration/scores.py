"""The scores of a calibration: per sample, its loss's psi(r_i) times the sensitivity J_i of its
residual to the nine parameters, summed over consecutive blocks of samples, in the one pass
over the data after the solve that also gathers the Table 1 rows (`after_solve`).

The residual of sample i is r_i = |B1_i| - F_i (a reference) or |B1_i| - c (none: c the mean of
|B1|, or the robust loss's centre), |B1_i| = |M (B_M,i - Z_p)| (Eq. 4 in [1]). With c_i =
B_M,i - Z_p and u_i = B1_i / |B1_i|, its sensitivity in the scaled variables y = theta / D of
the problems (`nlpcal.nlp.blocks.variable_scale`) is linear in f_i = (u_i, the entries u_j c_k
of u_i c_i^T on and above the diagonal, j <= k):

    d|B1| / dZ_p = -M^T u,    d|B1| / dM_jk = u_j c_k,    J_i = f_i L,

L (9, 9) fixed by theta (M's six entries follow the scale errors and angles by
`correction_matrix_entries`, their derivatives by a complex step, exact to rounding). Without a
reference the centre c is estimated with theta; the score of theta with c profiled out is
psi(r_i) (J_i - Jbar), Jbar the psi'-weighted mean of J (the mean for least squares), so each
block sum is sum psi J - Jbar sum psi.

Per chunk the work is a few products of whole arrays: the rows x_i = (psi' f_i, psi', psi) and
y_i = (f_i, 1), and per block of `block_rows` consecutive samples (counted from the log's first
row, so that the sums do not depend on how a pass splits the rows: threads, `--low-memory` or
Dask) the product X_k^T Y_k (11, 10), one batched matrix product for the blocks of a chunk. It
holds the block's sums of psi f, psi, psi' f, psi' and psi' f f^T, which L turns into those of
the scores psi J, psi' J and psi' J J^T after the pass (sums of products are linear in L): the
series `nlpcal.inference.dependence_meat` turns into the meat of the sandwich covariance. The
noise terms of the bias (`noise_sums`) and, on request, sum psi(r_i)^2 J_i J_i^T (the meat of
independent samples) are sums over every sample, products of the chunk's arrays with y as well.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import compiled
from ..inference import MAX_BLOCKS
from ..models.zhou2010 import correction_matrix_entries
from ..nlp.blocks import variable_scale
from ..passes import as_rows, reduce, reference_chunk
from ..statistics import correction, merge_each

#: Complex step for the derivatives of M's entries. [rad or 1]
COMPLEX_STEP = 1e-30
#: Rows of the chunks of the pass after the solve, rounded to whole score blocks: its work is a
#: dozen whole-array numpy calls per chunk, each holding the interpreter lock between two
#: threads, so large chunks (a work array of 14 rows: 3.7 MB) beat chunks within a core's L2
#: cache. With these and the data pass's 32 768 rows, against 8 192 each, a warm joint fit of
#: 10^6 samples on 2 cores took 56 ms instead of 75 (compiled kernel) and 128 instead of 160
#: (numpy kernel) in one run; 65 536 each saved 3 % more and took the peak memory from 14 to
#: 25 MiB.
SCORE_CHUNK_ROWS = 32768
#: The upper-triangular entries of M, as (row, column).
ENTRIES = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
#: Columns of f_i: u (3), then u_j c_k for (j, k) in ENTRIES (6).
F_WIDTH = 9
#: Rows of a chunk's work array: x_i = (psi' f (9), psi', psi), then the noise weights
#: a = psi' / |B1|, b = a s and s = |g|^2; y_i is (f, 1).
PSI_SLOPE, PSI, NOISE = 9, 10, slice(11, 14)
#: Sums over every sample: (a, b, s) times y. (3, 10)
NOISE_WIDTH = 30
#: The indices of ENTRIES.
UPPER = tuple(np.array(index) for index in zip(*ENTRIES))


def entry_derivatives(theta) -> np.ndarray:
    """(6, 6): d(M's upper entries, ENTRIES order) / d(s_x, s_y, s_z, alpha, beta, gamma). [1]

    One complex step per parameter, the six evaluated together: column k of `steps` is theta
    with parameter 3 + k moved by i COMPLEX_STEP."""
    steps = np.repeat(np.asarray(theta, dtype=complex)[:, None], 6, axis=1)
    steps[3:9][np.diag_indices(6)] += 1j * COMPLEX_STEP
    matrix = correction_matrix_entries(steps[6], steps[7], steps[8], steps[3], steps[4], steps[5])
    return np.array([np.imag(matrix[j][c]) / COMPLEX_STEP for j, c in ENTRIES])


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
    """L (9, 9): J = f L for f = (u, u_j c_k for the entries (j, k) of ENTRIES), in the scaled
    variables."""
    _, matrix = correction(theta)
    linear = np.zeros((F_WIDTH, 9))
    linear[0:3, 0:3] = -matrix  # d|B1|/dZ = -M^T u, as a row: -u M
    linear[3:9, 3:9] = entry_derivatives(theta)
    return linear * variable_scale(radius)[None, :]


def block_products(x: np.ndarray, y: np.ndarray, first_row: int, rows: int) -> tuple:
    """(index of the first block, X_k^T Y_k per block (k, w, 10)) of the columns of a chunk
    (x (w, n), y (10, n): one column per sample) that starts at row `first_row` of the log,
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
    (`products`, (k, 11, 10)) or, for blocks of one sample, x_i and f_i themselves (`rows`,
    (x (11, k), f (9, k)), one column per sample), and the sums over every row (`totals`: the
    noise sums, then sum psi^2 y y^T when asked)."""

    first: int
    products: np.ndarray | None
    rows: tuple | None
    totals: np.ndarray

    def merge(self, later: ScorePart) -> ScorePart:
        """These rows' sums joined with those of the rows right after them."""
        totals = self.totals + later.totals
        if self.rows is not None and later.rows is not None:
            rows = tuple(np.concatenate([a, b], axis=1) for a, b in zip(self.rows, later.rows))
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
        x, f = self.rows  # type: ignore[misc]
        y = np.concatenate([f, np.ones((1, f.shape[1]))])
        return x.T[:, :, None] * y.T[:, None, :]


@dataclass(frozen=True)
class ScoreTerms:
    """The score sums at one theta: what a chunk of the pass after the solve adds.

    offset, matrix : the correction of Eq. 4 at theta. linear : L of `sensitivity_map`.
    block_rows : samples per block. loss : a robust `nlpcal.robust.Loss` with its scale, or None
    (least squares: psi(r) = r, psi' = 1). centre : without a reference, the centre of |B1| the
    residuals are taken from [field unit]. meat : also sum psi^2 y y^T over every sample.
    fast : the compiled kernel fills the columns (`nlpcal.compiled.score_columns`, the pass's
    choice by `nlpcal.compiled.use`).
    """

    offset: np.ndarray
    matrix: np.ndarray
    linear: np.ndarray
    block_rows: int
    loss: Any
    centre: float | None
    meat: bool
    fast: bool = False

    def empty(self, first_row: int, n: int) -> ScorePart:
        """The sums of no rows yet, for the n rows from `first_row` on."""
        first = first_row // self.block_rows
        width = NOISE_WIDTH + (100 if self.meat else 0)
        if self.block_rows == 1:
            return ScorePart(first, None, (np.empty((11, n)), np.empty((9, n))), np.zeros(width))
        count = (first_row + n - 1) // self.block_rows - first + 1 if n else 0
        return ScorePart(first, np.zeros((count, 11, 10)), None, np.zeros(width))

    def workspace(self, rows: int) -> tuple:
        """The arrays of a chunk of at most `rows` samples, one column per sample, reused from
        chunk to chunk (they stay in the core's cache): the work array (14, rows) whose rows
        are x, then a, b, s; y (10, rows), the first ten rows of the work array for least
        squares (psi' = 1); c = B_M - Z_p (3, rows) and g (3, rows)."""
        work = np.empty((14, rows))
        y = work[0:10] if self.loss is None else np.empty((10, rows))
        y[F_WIDTH] = 1.0
        return work, y, np.empty((3, rows)), np.empty((3, rows))

    def add(self, part: ScorePart, space: tuple, raw: np.ndarray, ref, first_row: int, begin: int):
        """Add a chunk of raw samples (rows begin: of `part`, `first_row` of the log) and its
        reference to `part`, computed in the arrays of `workspace`; returns (|B1|, r) of the
        chunk. [field unit]"""
        n = raw.shape[0]
        magnitude = None
        if self.fast:  # fills the whole arrays' first n columns, as `columns` fills the views
            whole_work, whole_y = space[0], space[1]
            magnitude = compiled.score_columns(raw, self.offset, self.matrix, whole_y, whole_work)
        work, y, centred, g = (array[:, :n] for array in space)
        f, r = y[0:F_WIDTH], work[PSI]
        if magnitude is None:
            magnitude = self.columns(raw, f, work[NOISE], centred, g)
        np.subtract(magnitude, ref if ref is not None else self.centre, out=r)  # type: ignore[arg-type]
        if self.loss is not None:
            r = self.weigh(work, f, r)
        np.multiply(work[11], work[13], out=work[12])  # b = a s
        x = work[0:11]
        if part.rows is not None:
            part.rows[0][:, begin : begin + n] = x
            part.rows[1][:, begin : begin + n] = f
            part.totals[:NOISE_WIDTH] += (work[NOISE] @ y.T).ravel()
        else:  # the noise rows in the same batched product: one call, summed over the blocks
            first, products = block_products(work, y, first_row, self.block_rows)
            start = first - part.first
            part.products[start : start + len(products)] += products[:, 0:11]  # type: ignore[index]
            part.totals[:NOISE_WIDTH] += products[:, NOISE].sum(axis=0).ravel()
        if self.meat:
            weighted = y * x[PSI]
            part.totals[NOISE_WIDTH:] += (weighted @ weighted.T).ravel()
        return magnitude, r

    def columns(self, raw, f, noise, centred, g) -> np.ndarray:
        """Fill f (9, n) and the noise rows (a, -, s) of a chunk of raw samples (n, 3) as for
        least squares (a = 1 / |B1|, s = |g|^2, g = M^T u); returns |B1|. [field unit]"""
        u = f[0:3]
        np.subtract(raw.T, self.offset[:, None], out=centred)
        np.matmul(self.matrix, centred, out=u)  # B1 = M c (Eq. 4)
        magnitude = np.sqrt(np.einsum("in,in->n", u, u))
        inverse = np.divide(1.0, magnitude, out=noise[0])
        u *= inverse
        np.multiply(u[0], centred, out=f[3:6])  # u_j c_k for (j, k) in ENTRIES
        np.multiply(u[1], centred[1:3], out=f[6:8])
        np.multiply(u[2], centred[2], out=f[8])
        np.matmul(self.matrix.T, u, out=g)
        np.einsum("in,in->n", g, g, out=noise[2])
        return magnitude

    def weigh(self, work, f, r) -> np.ndarray:
        """The rows of x for the robust loss from the residuals r (the row psi of `work`, which
        this sets): psi' f, psi', psi = w r, and a = psi' / |B1|; returns r. [field unit]"""
        r = r.copy()
        slope = self.loss.slope(r)
        np.multiply(f, slope, out=work[0:F_WIDTH])
        work[PSI_SLOPE] = slope
        work[11] *= slope
        np.multiply(self.loss.weight(r), r, out=work[PSI])
        return r


def noise_sums(totals: np.ndarray, matrix: np.ndarray, linear: np.ndarray) -> tuple:
    """(along, traced, trace, squares) of the noise terms of the bias (`noise_bias`), from the
    sums over every sample of (a, b, s) times y (`NOISE_WIDTH`), weighted by psi' (Stein's
    lemma: the noise moves psi(r) by psi' times it; 1 for least squares): `along`, sum psi' J's
    derivative along g = M^T u (9,); `traced`, sum psi' tr(d2|B1|/db2) J (9,); `trace`,
    sum psi' tr(d2|B1|/db2); `squares`, sum s, s = |g|^2.

    f's derivative along g is df = (du, du c^T + u g^T), du = (M g - u s) / |B1|, and
    tr(d2|B1|/db2) = (|M|_F^2 - s) / |B1|. With a = psi' / |B1|, b = a s and u u^T =
    u c^T M^T / |B1|: sum psi' du = M M^T sum a u - sum b u, sum psi' du c^T = M M^T sum a u c^T
    - sum b u c^T, sum psi' u g^T = (sum a u c^T) M^T M and sum psi' tr f = |M|_F^2 sum a f -
    sum b f. Only the upper entries of u c^T are columns of f: sum a u c^T = M C with
    C = sum a c c^T / |B1| symmetric, which they determine (`full_outer`)."""
    (a, b), (total_a, total_b), squares = totals[0:2, 0:9], totals[0:2, 9], totals[2, 9]
    gram, frobenius = matrix @ matrix.T, float(np.sum(matrix * matrix))
    moved = np.empty(9)
    moved[0:3] = gram @ a[0:3]
    outer = full_outer(a[3:9], matrix)
    moved[3:9] = (gram @ outer + outer @ matrix.T @ matrix)[UPPER]
    along, traced = np.stack([moved - b, frobenius * a - b]) @ linear
    return along, traced, frobenius * total_a - total_b, squares


def full_outer(upper: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """The (3, 3) sum w u c^T over samples (any weights w, u = M c / |B1|) from its entries at
    ENTRIES (6,): it is M C, C = sum w c c^T / |B1| symmetric, whose six entries the six given
    determine, by back substitution (M upper triangular with a nonzero diagonal)."""
    (u00, u01, u02, u11, u12, u22), m = upper.tolist(), matrix.tolist()
    (m00, m01, m02), (_, m11, m12), (_, _, m22) = m
    c22 = u22 / m22
    c12 = (u12 - m12 * c22) / m11
    c11 = (u11 - m12 * c12) / m11
    c02 = (u02 - m01 * c12 - m02 * c22) / m00
    c01 = (u01 - m01 * c11 - m02 * c12) / m00
    c00 = (u00 - m01 * c01 - m02 * c02) / m00
    return matrix @ np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]])


def block_rows(n: int) -> int:
    """Samples per block of the score series of `n` samples (at most MAX_BLOCKS blocks)."""
    return max(1, -(-int(n) // MAX_BLOCKS))


def score_terms(theta, radius: float, n: int, loss, centre: float | None, meat: bool) -> ScoreTerms:
    """The `ScoreTerms` of a log of n samples at theta (internal units) in the scaled variables
    of a sphere frame of `radius` [field unit]; `loss` None or not robust is least squares."""
    offset, matrix = correction(theta)
    robust = loss if loss is not None and loss.robust else None
    linear = sensitivity_map(theta, radius)
    fast = compiled.use(n)
    return ScoreTerms(offset, matrix, linear, block_rows(n), robust, centre, meat, fast)


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
        part = space = None
        if self.scores is not None:
            part = self.scores.empty(start, n)
            space = self.scores.workspace(min(n, self.chunk_rows))
        objectives = None if self.objectives is None else self.objectives.start()
        begin = 0
        while begin < n:  # chunks aligned to multiples of chunk_rows rows of the log
            stop = min(n, ((start + begin) // self.chunk_rows + 1) * self.chunk_rows - start)
            raw, ref = samples[begin:stop], reference_chunk(reference, begin, stop)
            shared = (None, None)  # |B1| at the scores' theta, and |B1| - F with a reference
            if self.scores is not None:
                shared = self.scores.add(part, space, raw, ref, start + begin, begin)  # type: ignore[arg-type]
                shared = (shared[0], shared[1] if ref is not None else None)
            for k, (row, (total, sums)) in enumerate(zip(self.rows, stats)):
                at_theta = k < len(self.shared) and self.shared[k]
                row.add(total, sums, raw, ref, *(shared if at_theta else ()))
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
    |g|^2); `meat` (9, 9) sum psi(r_i)^2 J_i J_i^T over the samples or None (not asked).
    The `part`'s sums are of f_i, J_i = f_i L (`linear`, `sensitivity_map`)."""

    series: np.ndarray
    part: ScorePart
    linear: np.ndarray
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
            x, f = self.part.rows
            total = x[0:F_WIDTH] @ f.T
            weighted, slopes = x[0:F_WIDTH].sum(axis=1), x[PSI_SLOPE].sum()
        else:
            products = self.part.products_all().sum(axis=0)
            total, weighted, slopes = products[0:9, 0:9], products[0:9, 9], products[PSI_SLOPE, 9]
        total, weighted = self.linear.T @ total @ self.linear, weighted @ self.linear
        if self.mean is not None:
            cross = np.outer(weighted, self.mean)
            total = total - cross - cross.T + slopes * np.outer(self.mean, self.mean)
        return 0.5 * (total + total.T)

    def informations(self) -> np.ndarray:
        products = self.part.products_all()
        information = self.linear.T @ products[:, 0:9, 0:9] @ self.linear
        if self.mean is None:
            return information
        weighted, slopes = products[:, 0:9, 9] @ self.linear, products[:, PSI_SLOPE, 9]
        cross = weighted[:, :, None] * self.mean[None, None, :]
        outer = np.outer(self.mean, self.mean)
        return information - cross - cross.transpose(0, 2, 1) + slopes[:, None, None] * outer


def finished(part: ScorePart, terms: ScoreTerms, n: int, profiled: bool, shift: float = 0.0):
    """The `ScoreSums` of the `ScorePart` of a whole log of n samples; `profiled` without a
    reference. shift : for least squares, how far the centre the residuals were taken from lies
    below the one they are to be taken from (the mean of |B1|, known after the pass): psi = r is
    then lower by shift, psi' = 1 unchanged. [field unit]"""
    linear = terms.linear
    if part.rows is not None:
        x, f = part.rows
        if shift:
            x[PSI] -= shift * x[PSI_SLOPE]
        scores, psi = (linear.T @ (f * x[PSI])).T, x[PSI]
        weighted, slopes = x[0:F_WIDTH].T, x[PSI_SLOPE]
    else:
        products = part.products_all()
        if shift:
            products[:, PSI] -= shift * products[:, PSI_SLOPE]
        scores, psi = products[:, PSI, 0:F_WIDTH] @ linear, products[:, PSI, F_WIDTH]
        weighted, slopes = products[:, 0:F_WIDTH, F_WIDTH], products[:, PSI_SLOPE, F_WIDTH]
    noise = part.totals[:NOISE_WIDTH].reshape(3, 10)
    along, traced, trace, squares = noise_sums(noise, terms.matrix, linear)
    meat = None
    if terms.meat:  # sum psi^2 y y^T, y = (J, 1)
        widened = np.eye(10)
        widened[0:9, 0:9] = linear
        meat = widened.T @ part.totals[NOISE_WIDTH:].reshape(10, 10) @ widened
    mean = None
    if profiled:  # the centre profiled out: J_i - Jbar, Jbar the psi'-weighted mean
        mean = weighted.sum(axis=0) @ linear / slopes.sum()
        scores = scores - np.outer(psi, mean)
        traced = traced - mean * trace
        if meat is not None:
            squared, square = meat[9, 0:9], meat[9, 9]
            cross = np.outer(squared, mean)
            meat = meat[0:9, 0:9] - cross - cross.T + square * np.outer(mean, mean)
    elif meat is not None:
        meat = meat[0:9, 0:9]
    bias = {"gradient": along + 0.5 * traced, "mean_square_g": squares / n}
    return ScoreSums(scores, part, linear, mean, terms.block_rows, bias, meat)


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
    terms = score_terms(theta, radius, n, loss, centre, meat=True)
    rows = terms.block_rows
    chunk = max(1, min(chunk_rows, SCORE_CHUNK_ROWS) // rows) * rows
    work = AfterSolve((), terms, chunk)
    _, part, _ = reduce(samples, reference, work, _merge_after, chunk, indexed=True)
    sums = finished(part, terms, n, reference is None)
    return sums.series, sums.informations(), rows, sums.bias, sums.meat
