"""Table 1 of [1]: statistics of the total field |B1| over the samples.

A row holds max, min, mean, std and range (max - min) of |B1|. The std is the population standard
deviation (ddof = 0, the 1/N of Eq. 8), so that std^2 equals the Eq. 8 objective. Each row also
carries the exact per-sample objective of the run (Eq. 8 or its reference variant), which is how
the moment expansion of `nlpcal.nlp.objective` is checked on every run.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .models.zhou2010 import Zhou2010Parameters, correct, correction_matrix_entries
from .passes import SURVEY_HEAD, as_rows, reduce, reference_chunk

#: Delta degrees of freedom of the reported std.
STD_DDOF = 0
STAT_KEYS = ("max", "min", "mean", "std", "range")


class MagnitudeStats:
    """Table 1 statistics of |B1| and the exact objective, accumulated chunk by chunk.

    Sums are taken of deviations from the first chunk's mean, so that the variance of a
    50 000 nT field with a 1 nT spread does not cancel. Products of neighbouring residuals give
    their lag-1 autocorrelation (a log is a time series: slow disturbances make neighbours alike).
    """

    def __init__(self, shift: float | None = None):
        self.n = 0
        self.shift = shift
        self.total = self.total_sq = self.ref_sq = self.ref_total = 0.0
        self.lag = self.ref_lag = 0.0  # sums of products of neighbouring deviations, residuals
        # (deviation, residual) at the ends, to join neighbours across chunks
        self.first: tuple[float, float] = (0.0, 0.0)
        self.last: tuple[float, float] | None = None
        self.high, self.low = -np.inf, np.inf
        self.u_high = self.u_low = 0.0
        self.has_reference = False

    def add(self, magnitude: np.ndarray, reference=None, residual=None) -> None:
        """Add the magnitudes of one chunk [field unit] and their reference (None, a float or
        an array of the same length) [field unit]; `residual` : magnitude - reference, when
        already at hand. [field unit]"""
        if magnitude.size == 0:
            return
        if self.shift is None:
            self.shift = float(magnitude.mean())
        deviation = magnitude - self.shift
        self.n += magnitude.size
        self.total += float(deviation.sum())
        self.total_sq += float(deviation @ deviation)
        self.lag += float(deviation[:-1] @ deviation[1:])
        high, low = float(magnitude.max()), float(magnitude.min())
        self.high, self.low = max(self.high, high), min(self.low, low)
        if reference is None:
            residual = deviation
        else:
            self.has_reference = True
            residual = magnitude - reference if residual is None else residual
            self.ref_total += float(residual.sum())
            self.ref_sq += float(residual @ residual)
            self.ref_lag += float(residual[:-1] @ residual[1:])
            if np.ndim(reference) == 0:  # (x / F)^2 - 1 rises with x: its ends are the ends'
                ratio = np.array([high, low]) / reference
            else:
                ratio = magnitude / reference
            ratio = ratio * ratio - 1.0
            self.u_high = max(self.u_high, float(ratio.max()))
            self.u_low = min(self.u_low, float(ratio.min()))
        self._join(float(deviation[0]), float(residual[0]))
        self.last = (float(deviation[-1]), float(residual[-1]))

    def _join(self, deviation: float, residual: float) -> None:
        """Count the pair across the boundary with the chunk or part that came before."""
        if self.last is None:
            self.first = (deviation, residual)
            return
        self.lag += self.last[0] * deviation
        self.ref_lag += self.last[1] * residual

    def merge(self, other: MagnitudeStats) -> MagnitudeStats:
        """Add the sums of `other`, gathered with the same shift, to these."""
        if other.n == 0:
            return self
        if self.n == 0:
            return other
        if other.shift != self.shift:
            raise ValueError("MagnitudeStats gathered with different shifts")
        self._join(*other.first)  # `other` covers the samples right after these
        self.last = other.last
        self.n += other.n
        self.total += other.total
        self.total_sq += other.total_sq
        self.lag += other.lag
        self.ref_sq += other.ref_sq
        self.ref_total += other.ref_total
        self.ref_lag += other.ref_lag
        self.high, self.low = max(self.high, other.high), min(self.low, other.low)
        self.u_high, self.u_low = max(self.u_high, other.u_high), min(self.u_low, other.u_low)
        self.has_reference = self.has_reference or other.has_reference
        return self

    def result(self) -> dict:
        """max, min, mean, std, range [field unit], objective [field^2] and max_abs_u [1]: the
        largest |(|B1| / F)^2 - 1| (F the reference, or the mean without one)."""
        n = self.n
        mean_dev = self.total / n
        variance = max(self.total_sq / n - mean_dev**2, 0.0)
        mean = (self.shift or 0.0) + mean_dev
        pairs = max(n - 1, 1)
        if self.has_reference:
            objective, u_high, u_low = self.ref_sq / n, self.u_high, self.u_low
            mean_res = self.ref_total / n
            spread = self.ref_sq / n - mean_res**2
            lag = self.ref_lag / pairs - mean_res**2
        else:
            objective = variance
            u_high, u_low = (self.high / mean) ** 2 - 1.0, (self.low / mean) ** 2 - 1.0
            spread, lag = variance, self.lag / pairs - mean_dev**2
        return {
            "max": self.high,
            "min": self.low,
            "mean": float(mean),
            "std": float(np.sqrt(variance * n / (n - STD_DDOF))),
            "range": self.high - self.low,
            "objective": float(objective),
            "max_abs_u": float(max(abs(u_high), abs(u_low))),
            "residual_lag1_autocorrelation": float(lag / spread) if spread > 0 else 0.0,
        }


def correction(theta):
    """(offset, M) of Eq. 4 for internal parameters theta (None: no correction)."""
    if theta is None:
        return np.zeros(3), np.eye(3)
    theta = np.asarray(theta, dtype=float)
    matrix = correction_matrix_entries(theta[6], theta[7], theta[8], theta[3], theta[4], theta[5])
    return theta[0:3], np.array(matrix, dtype=float)


def shifted_correction(samples, theta) -> tuple:
    """(offset, M, shift): the correction of Eq. 4 for theta (`correction`), and the shift of
    the sums of `MagnitudeStats`, the mean |B1| of the first SURVEY_HEAD samples (which a Dask
    log's survey keeps). [field unit]"""
    offset, matrix = correction(theta)
    head = samples[: min(SURVEY_HEAD, samples.shape[0])]
    return offset, matrix, float(corrected_magnitude(head, offset, matrix).mean())


def corrected_magnitude(chunk, offset, matrix) -> np.ndarray:
    """|B1| = |M (B_M - Z_p)| (Eq. 4) of a chunk of raw samples, M upper triangular. [field unit]"""
    (m00, m01, m02), (_, m11, m12), (_, _, m22) = matrix
    x, y, z = chunk[:, 0] - offset[0], chunk[:, 1] - offset[1], chunk[:, 2] - offset[2]
    b1x = m00 * x + m01 * y + m02 * z
    b1y = m11 * y + m12 * z
    b1z = m22 * z
    return np.sqrt(b1x * b1x + b1y * b1y + b1z * b1z)


@dataclass(frozen=True)
class StatisticsBlock:
    """The work of a Table 1 pass on one block of rows: the `MagnitudeStats` of its |B1| and,
    with a robust loss, the sums of rho, of the samples beyond its scale, of the weights w and
    of w |B1|.

    offset, matrix : the correction of Eq. 4 (`correction`). shift : the shift of the sums.
    loss, centre : a robust `nlpcal.robust.Loss` with its scale, and the centre of |B1| the
        residuals are taken from without a reference. [field unit]
    weights : (raw chunk, its reference) -> given weights v of its samples (a robust fit's
        latest reweighting): the sums of v, v r and v r^2 follow, r the residuals about the
        reference or `centre`, whose weighted mean square the weighted moments expand.
    """

    offset: np.ndarray
    matrix: np.ndarray
    shift: float
    chunk_rows: int = 16384
    loss: Any = None
    centre: float | None = None
    weights: Callable | None = None

    def __call__(self, samples, reference) -> tuple:
        samples = np.asarray(samples, dtype=float)
        stats, sums = self.start()
        for start in range(0, samples.shape[0], self.chunk_rows):
            stop = min(start + self.chunk_rows, samples.shape[0])
            self.add(stats, sums, samples[start:stop], reference_chunk(reference, start, stop))
        return stats, sums

    def start(self) -> tuple:
        """The sums of no rows: `MagnitudeStats`, and rho, outliers, w, w |B1| (then v, v r,
        v r^2 with `weights`)."""
        return MagnitudeStats(self.shift), np.zeros(4 if self.weights is None else 7)

    def of(self, raw) -> np.ndarray:
        """|B1| of a chunk of raw samples. [field unit]"""
        return corrected_magnitude(raw, self.offset, self.matrix)

    def add(
        self, stats: MagnitudeStats, sums: np.ndarray, raw, reference, values=None, residual=None
    ) -> None:
        """Add a chunk of raw samples and its reference to `stats` and `sums`; `values` : their
        |B1| when already at hand, and with a reference `residual`, |B1| - F. [field unit]"""
        values = self.of(raw) if values is None else values
        stats.add(values, reference, residual)
        if self.loss is None:
            return
        loss = self.loss
        r = (
            residual
            if residual is not None
            else values - (reference if reference is not None else self.centre)
        )
        w = loss.weight(r)
        sums[0:4] += (loss.rho(r).sum(), loss.outliers(r).sum(), w.sum(), w @ values)
        if self.weights is not None:
            v = self.weights(raw, reference)
            sums[4:7] += (v.sum(), v @ r, v @ (r * r))

    def weighted_objective(self, sums: np.ndarray, reference: bool) -> float:
        """The weighted mean square of the residuals with the given weights, from a pass's
        `sums` (about their weighted mean without a `reference`). [field unit^2]"""
        total, first, second = sums[4:7]
        return float(second / total - (0.0 if reference else (first / total) ** 2))


def statistics_block(
    samples, theta, chunk_rows: int = 16384, loss=None, centre=None, weights=None
) -> StatisticsBlock:
    """The `StatisticsBlock` of a Table 1 row at theta (None: the measured |B_M|)."""
    offset, matrix, shift = shifted_correction(samples, theta)
    return StatisticsBlock(offset, matrix, shift, chunk_rows, loss, centre, weights)


def statistics_result(total: MagnitudeStats, sums: np.ndarray, loss=None) -> dict:
    """The Table 1 statistics of a pass (`MagnitudeStats.result`), with a robust loss's."""
    result = total.result()
    if loss is not None:
        result.update(
            robust_objective=float(sums[0] / total.n),
            downweighted=int(sums[1]),
            weighted_centre=float(sums[3] / sums[2]) if sums[2] > 0 else result["mean"],
        )
    return result


def _merge_statistics(first: tuple, second: tuple) -> tuple:
    return first[0].merge(second[0]), first[1] + second[1]


def field_statistics(
    samples, theta=None, reference=None, chunk_rows: int = 16384, loss=None, centre=None
) -> dict:
    """One chunked pass: Table 1 statistics of |B1| and the exact objective (`MagnitudeStats`).

    samples : (N, 3) raw output B_M, in memory or a Dask log (`nlpcal.passes`). [field unit]
    theta : internal parameters (z [field], s [1], angles [rad]); None gives the measured row |B_M|.
    reference : None, a float or an (N,) series F_i. [field unit]
    loss, centre : with a robust `nlpcal.robust.Loss` (its scale set), the pass also sums the
        loss of the residuals r_i = |B1_i| - F_i (or - centre without a reference) [field unit]:
        "robust_objective" (mean rho [field^2]), "downweighted" (samples beyond the loss scale) and
        "weighted_centre" (sum w |B1| / sum w with the IRLS weights w [field unit]).
    """
    samples = as_rows(samples)
    work = statistics_block(samples, theta, chunk_rows, loss, centre)
    total, sums = reduce(samples, reference, work, _merge_statistics, chunk_rows)
    return statistics_result(total, sums, loss)


@dataclass(frozen=True)
class ObjectivesBlock:
    """The work of one pass that evaluates the exact objective under several corrections: the
    `MagnitudeStats` of |B1| for each (offset, matrix, shift) of `corrections`, and with a robust
    `loss` the sums of rho, psi and psi' of the residuals (about `centre` without a reference)."""

    corrections: tuple
    chunk_rows: int = 16384
    loss: Any = None
    centre: float | None = None

    def __call__(self, samples, reference) -> list:
        samples = np.asarray(samples, dtype=float)
        stats = self.start()
        for start in range(0, samples.shape[0], self.chunk_rows):
            stop = min(start + self.chunk_rows, samples.shape[0])
            self.add(stats, samples[start:stop], reference_chunk(reference, start, stop))
        return stats

    def start(self) -> list:
        """The sums of no rows, one (MagnitudeStats, rho psi psi' sums) per correction."""
        return [(MagnitudeStats(shift), np.zeros(3)) for _, _, shift in self.corrections]

    def add(self, stats: list, chunk, reference) -> None:
        """Add a chunk of raw samples and its reference to the sums of every correction."""
        for (offset, matrix, _), (total, sums) in zip(self.corrections, stats):
            magnitude = corrected_magnitude(chunk, offset, matrix)
            total.add(magnitude, reference)
            if self.loss is not None:
                r = magnitude - (reference if reference is not None else self.centre)
                loss = self.loss
                sums += (loss.rho(r).sum(), (loss.weight(r) * r).sum(), loss.slope(r).sum())

    def values(self, totals: list, reference: bool) -> np.ndarray:
        """The objectives of a pass's `totals` (see `exact_objectives`). [field^2]"""
        if self.loss is None:
            return np.array([total.result()["objective"] for total, _ in totals])
        values = []
        for total, (rho, psi, slope) in totals:
            profiled = 0.0 if reference or not slope > 0 else psi * psi / (2.0 * slope)
            values.append(2.0 * (rho - profiled) / total.n)
        return np.array(values)


def merge_each(first: list, second: list) -> list:
    return [(a.merge(b), x + y) for (a, x), (b, y) in zip(first, second)]


def exact_objectives(
    samples, thetas, reference=None, chunk_rows: int = 16384, loss=None, centre=None
) -> np.ndarray:
    """The exact objective (Eq. 8, or its reference variant) at each parameter vector of
    `thetas`, in one pass over the samples (one task per block on a Dask log). [field^2]

    loss, centre : with a robust `nlpcal.robust.Loss` (its scale set), the objective is
        (2/N) sum rho(r_i) of the residuals r_i = |B1_i| - F_i, which is the mean square for
        least squares; without a reference r_i = |B1_i| - c, with c one Newton step from `centre`
        towards the c that minimises it: (2/N) (sum rho - (sum psi)^2 / (2 sum psi')), which for
        least squares is the variance of |B1| (Eq. 8) exactly.
    """
    samples = as_rows(samples)
    work = objectives_block(samples, thetas, chunk_rows, loss, centre)
    totals = reduce(samples, reference, work, merge_each, chunk_rows)
    return work.values(totals, reference is not None)


def objectives_block(samples, thetas, chunk_rows: int = 16384, loss=None, centre=None):
    """The `ObjectivesBlock` of `exact_objectives`."""
    corrections = tuple(shifted_correction(samples, theta) for theta in thetas)
    robust = loss is not None and loss.robust
    return ObjectivesBlock(corrections, chunk_rows, loss if robust else None, centre)


def shown_rows(count: int, most: int | None) -> list:
    """Which of `count` rows a summary of at most `most` rows shows (all when `most` is None):
    the first three, the last two and, between them, a few evenly spaced."""
    if most is None or count <= most:
        return list(range(count))
    head, tail = 3, 2
    between = np.linspace(head, count - tail - 1, max(most - head - tail, 0) + 2)[1:-1]
    chosen = {*range(head), *np.round(between).astype(int).tolist(), *range(count - tail, count)}
    return sorted(chosen)


def format_table(rows, unit: str = "nT", extra=(), most: int | None = None) -> str:
    """Rows in the layout of Table 1 of [1], as text for a terminal; with `most`, at most about
    that many of them (`shown_rows`), a line saying how many rows each gap leaves out."""
    columns = ["max", "min", "mean", "std", "range", *extra]
    width = max([len("row")] + [len(str(r["label"])) for r in rows])
    header = f"{'row':<{width}}  " + "  ".join(f"{c:>12}" for c in columns)
    lines = [
        f"total field [{unit}] (measured: |B_M|; other rows: |B1| corrected by Eq. 4), std "
        f"with ddof={STD_DDOF}",
        header,
        "-" * len(header),
    ]
    # Two decimals for fields of 100 and more (nT, counts); more for small numbers (a log in
    # gauss or uT), so that a spread of 0.003 G does not print as 0.00.
    scale = max([abs(float(r[c])) for r in rows for c in STAT_KEYS if r.get(c)] or [1.0])
    decimals = 2 if scale >= 100 else min(8, 4 - int(np.floor(np.log10(scale))))
    shown = shown_rows(len(rows), most)
    for k, index in enumerate(shown):
        row = rows[index]
        gap = index - (shown[k - 1] if k else -1) - 1
        if gap:
            lines.append(f"{'...':<{width}}  ({gap} row{'s' if gap > 1 else ''} not shown)")
        cells = []
        for c in columns:
            value = row.get(c)
            if isinstance(value, (int, np.integer)):
                cells.append(f"{value:>12d}")
            elif value is None:
                cells.append(f"{'':>12}")
            elif c in STAT_KEYS:
                cells.append(f"{value:>12.{decimals}f}")
            elif abs(value) >= 1:
                cells.append(f"{value:>12.2f}")
            else:
                cells.append(f"{value:>12.4g}")
        lines.append(f"{row['label']!s:<{width}}  " + "  ".join(cells))
    return "\n".join(lines)


def direct_objective(samples, theta, reference=None) -> float:
    """Eq. 8 in [1] (reference None) or mean (|B1_i| - F_i)^2, evaluated sample by sample: the
    definition the moment objective of `nlpcal.nlp.objective` is checked against. [field^2]

    theta : internal parameters (z [field], s [1], angles [rad]).
    """
    magnitude = np.linalg.norm(correct(samples, Zhou2010Parameters.from_theta(theta)), axis=1)
    if reference is None:
        return float(np.mean((magnitude - magnitude.mean()) ** 2))
    return float(np.mean((magnitude - reference) ** 2))
