"""The data of one nine-parameter calibration, its Table 1 rows, and the reweighting of a robust
loss.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from ..models.zhou2010 import Zhou2010Parameters, estimated_parameters
from ..moments import Moments, accumulate
from ..nlp.blocks import (
    OPTIONS,
    Variables,
    evaluate,
    summary_function,
    value_function,
    variables,
)
from ..nlp.solver import IpoptOptions
from ..passes import reduce
from ..results import TableRow
from ..robust import MAD_SAMPLES, Loss, median
from ..statistics import (
    MagnitudeStats,
    StatisticsBlock,
    corrected_magnitude,
    correction,
    field_statistics,
    reference_chunk,
    statistics_block,
    statistics_result,
)
from .result import Reference

#: A loss scale estimated from the residuals is re-estimated at every reweighting until it
#: changes by less than this fraction, then kept, so that the last steps minimise one objective.
SCALE_SETTLED = 1e-3
#: A cycle's row comes from the moments only while the relative spread of |B1|^2 about its mean
#: is below this: the truncation error of its mean is then of the order of 1e-8 and of its std
#: 1e-5, relative (`nlp.objective.centred_expansion`). [1]
MOMENT_ROW_SPREAD = 0.05
#: Rows of the chunks `Problem.residuals` computes |B1| in (8 192 rows of a few buffers: 0.3 MB).
CHUNK_ROWS = 8192


@dataclass
class Problem:
    """The data of one calibration: samples, reference, their moments and the loss.

    samples : (N, 3) raw sensor output B_M. [field unit]
    reference : None, a number or (N,) values F_i. [field unit]
    moments : `nlpcal.moments.Moments` of the samples and the reference; with a robust loss,
        weighted by the loss at the latest estimate (`reweight`).
    loss : the loss (`nlpcal.robust.Loss`); its scale is set by the first `reweight` when not
        given.
    centre : without a reference, the centre of |B1| the residuals are taken from (the weighted
        mean of the latest pass). [field unit]
    ipopt : the IPOPT settings of every solve (print_level > 0 shows IPOPT's log).
    model : the form of Eq. 4 estimated (`nlpcal.models.zhou2010.MODELS`); the parameters it
        does not estimate stay at zero.
    """

    samples: np.ndarray
    reference: float | np.ndarray | None
    moments: Moments
    loss: Loss = field(default_factory=Loss)
    centre: float | None = None
    scale_given: bool = False
    reweights: int = 0
    weighted_at: np.ndarray | None = None  # the estimate the current weights were taken at
    frozen: bool = False  # the weights stay as they are (a comparison of solvers on them)
    ipopt: IpoptOptions = OPTIONS
    model: str = "full"
    #: Table 1 rows whose statistics the pass after the solve gathers: (row, theta, series,
    #: the `nlpcal.statistics.StatisticsBlock` of the loss and weights of their time).
    deferred: list = field(default_factory=list)

    def __post_init__(self):
        self.scale_given = self.loss.scale is not None

    def measured_row(self) -> TableRow:
        """The Table 1 row of the raw |B_M|, gathered with the moments."""
        return TableRow("measured", **self.moments.measured, iterations=0, wall_s=0.0)

    def statistics(self, theta) -> dict:
        """Table 1 statistics of |B1| at theta, with the loss's sums when it is robust and its
        residuals are defined: a scale, and a reference or the centre of a first reweighting
        (a scale given by the user is known before the first cycle, the centre is not)."""
        loss = self.row_loss()
        centre = self.centre if loss is not None else None
        return field_statistics(self.samples, theta, self.reference, loss=loss, centre=centre)

    def row_loss(self) -> Loss | None:
        """The loss whose sums a Table 1 row gathers now (`statistics`), or None."""
        centred = self.reference is not None or self.centre is not None
        robust = self.loss.robust and self.loss.scale is not None and centred
        return self.loss if robust else None

    def row_work(self, theta) -> StatisticsBlock:
        """The work of a Table 1 row at theta in the pass after the solve: `statistics` and,
        after a reweighting, the sums of the exact objective its weights expand
        (`_weighted_objective`)."""
        loss = self.row_loss()
        weights = None
        if loss is not None and self.weighted_at is not None:
            weights = self.weight_function(self.weighted_at, self.loss.weight)
        centre = self.centre if loss is not None else None
        return statistics_block(self.samples, theta, loss=loss, centre=centre, weights=weights)

    def row(self, label, theta, series: float | None = None, *, iterations, wall_s) -> TableRow:
        """A Table 1 row of |B1| for `theta`, with the relative gap between the moment objective
        (`series`, evaluated here when not given) and the exact per-sample one (one pass)."""
        row = TableRow(label)
        row.parameters = Zhou2010Parameters.from_theta(theta).to_dict()
        row.iterations, row.wall_s = int(iterations), float(wall_s)
        self.fill_row(row, theta, series, self.statistics(theta))
        return row

    def deferred_row(
        self, label, theta, series: float | None = None, *, iterations, wall_s
    ) -> TableRow:
        """`row`, its statistics gathered by the pass after the solve (`deferred`) with the
        loss, centre and weights of now (`row_work`): for rows no step of the solve reads."""
        row = TableRow(label)
        row.parameters = Zhou2010Parameters.from_theta(theta).to_dict()
        row.iterations, row.wall_s = int(iterations), float(wall_s)
        self.deferred.append((row, np.array(theta, dtype=float), series, self.row_work(theta)))
        return row

    def fill_deferred(self, entry: tuple, stats: MagnitudeStats, sums: np.ndarray) -> None:
        """Set the statistics of a `deferred` row from the sums of the pass after the solve."""
        row, theta, series, work = entry
        result = statistics_result(stats, sums, work.loss)
        exact = result["objective"]
        if work.weights is not None:
            exact = work.weighted_objective(sums, self.reference is not None)
        self.fill_row(row, theta, series, result, exact)

    def fill_row(self, row: TableRow, theta, series, stats: dict, exact=None) -> None:
        """Set a row's statistics of |B1| at theta (`statistics`) and the relative gap between
        the moment objective `series` (evaluated here when None) and the `exact` one (the
        objective the moments expand: `_weighted_objective` after a reweighting, evaluated here
        when None). [field unit^2]"""
        row.update(stats)
        if series is None or self.loss.robust:
            (series,) = evaluate(value_function, self.moments, theta)
        if exact is None:
            exact = stats["objective"] if not self.loss.robust else self._weighted_objective(theta)
        row.series_rel_error = abs(series - exact) / exact if exact > 0 else 0.0

    def moment_row(self, label, theta, *, iterations, wall_s) -> TableRow | None:
        """A Table 1 row from the moments alone: mean and std of |B1| and the objective, without
        max, min and range (they need a pass over the data); None where the expansion behind it
        does not hold (the spread of |B1| above MOMENT_ROW_SPREAD of its mean, as in the first
        cycles of a log whose offsets exceed the field)."""
        f, mean, variance, spread = evaluate(summary_function, self.moments, theta)
        if not spread <= MOMENT_ROW_SPREAD:
            return None
        return TableRow(
            label,
            mean=mean,
            std=float(np.sqrt(max(variance, 0.0))),
            objective=f,
            from_moments=True,
            parameters=Zhou2010Parameters.from_theta(theta).to_dict(),
            iterations=int(iterations),
            wall_s=float(wall_s),
        )

    @property
    def free(self) -> Variables:
        """The directions of theta the model estimates (`nlpcal.nlp.blocks.variables`)."""
        return variables("joint", self.moments.reference, self.model)

    @property
    def estimated(self) -> list:
        """The names of the parameters the model estimates, in PARAMETER_NAMES order."""
        return estimated_parameters(self.model, self.moments.reference != "none")

    @property
    def rows_from_moments(self) -> bool:
        """Whether cycle rows can come from the moments: least squares without a reference
        series (a robust loss and a series weight the samples in ways the mean cannot show)."""
        return not self.loss.robust and self.moments.reference in ("none", "constant")

    def reference_document(self) -> Reference:
        """The reference of a result: the mode and the field (or its mean)."""
        mode = self.moments.reference
        if mode == "constant":
            return Reference(mode, field=float(self.reference))  # type: ignore[arg-type]
        if mode == "series":
            return Reference(mode, field_mean=float(self.reference.mean()))  # type: ignore[union-attr]
        return Reference(mode)

    # --- robust losses: iteratively reweighted moments ----------------------------------------

    def residuals(self, theta, centre: float | None = None) -> np.ndarray:
        """Residuals |B1_i| - F_i (or - centre) on an even stride of at most MAD_SAMPLES samples.
        [field unit]"""
        step = max(1, self.samples.shape[0] // MAD_SAMPLES)
        strided, rows = self.samples[::step], CHUNK_ROWS  # in chunks: a few buffers of memory
        magnitude = np.concatenate(
            [
                corrected_magnitude(np.asarray(strided[i : i + rows]), *correction(theta))
                for i in range(0, strided.shape[0], rows)
            ]
        )
        if self.reference is None:
            return magnitude - (median(magnitude) if centre is None else centre)
        if np.ndim(self.reference) == 0:
            return magnitude - float(self.reference)
        series: Any = self.reference  # an array in memory or LazySamples
        return magnitude - series[::step]

    def reference_series(self) -> np.ndarray | None:
        """A reference series on the stride of `residuals`, or None (a constant or none).
        [field unit]"""
        if self.reference is None or np.ndim(self.reference) == 0:
            return None
        series: Any = self.reference
        return np.asarray(series[:: max(1, self.samples.shape[0] // MAD_SAMPLES)], dtype=float)

    def weight_function(self, theta, weight):
        """(raw chunk, its reference) -> weight(r) of the chunk's residuals at theta."""
        return partial(
            residual_weights, correction=correction(theta), centre=self.centre, weight=weight
        )

    def weighted_moments(self, theta, weight) -> Moments:
        """The moments with per-sample weights weight(r_i) at theta, in the frame of the first
        pass."""
        return accumulate(
            self.samples,
            self.reference,
            frame=self.moments.frame,
            weight=self.weight_function(theta, weight),
        )

    def reweight(self, theta) -> bool:
        """IRLS: the scale (unless given or settled), the centre and the weights at theta.

        Returns whether the loss scale changed (the objective being minimised then changed).
        """
        if self.frozen:
            return False
        if self.centre is None and self.reference is None:
            self.centre = median(self.residuals(theta, 0.0))
        changed = False
        if not self.scale_given:
            previous = self.loss.scale
            estimated = Loss(self.loss.kind).with_scale_from(self.residuals(theta, self.centre))
            scale = float(estimated.scale or 0.0)
            if previous is None or abs(scale / previous - 1.0) > SCALE_SETTLED:
                self.loss, changed = estimated, True
        if self.reference is None:
            self.centre = self.statistics(theta)["weighted_centre"]
        self.moments = self.weighted_moments(theta, self.loss.weight)
        self.weighted_at = np.array(theta, dtype=float)
        self.reweights += 1
        return changed

    def _weighted_objective(self, theta, chunk_rows: int = 65536) -> float:
        """The exact objective the weighted moments expand at theta: sum w r^2 / sum w with the
        weights of the latest reweighting (r about F_i, or about the weighted mean of |B1|)."""
        if self.weighted_at is None:
            return field_statistics(self.samples, theta, self.reference)["objective"]
        work = WeightedSums(
            self.weight_function(self.weighted_at, self.loss.weight),
            correction(theta),
            self.centre,
            chunk_rows,
        )
        sums = reduce(self.samples, self.reference, work, np.add, chunk_rows)
        if self.reference is None:  # the weighted variance of |B1|
            return float(sums[2] / sums[0] - (sums[1] / sums[0]) ** 2)
        return float(sums[2] / sums[0])


def residual_weights(raw, reference, *, correction, centre, weight) -> np.ndarray:
    """weight(r) of the residuals r = |B1| - F (or - centre) of a chunk of raw samples at the
    correction (offset, M) of Eq. 4. [1]"""
    return weight(
        corrected_magnitude(raw, *correction) - (reference if reference is not None else centre)
    )


@dataclass(frozen=True)
class WeightedSums:
    """The work of one block of `Problem._weighted_objective`: the sums of w, w r and w r^2 with
    r = |B1| - F at a correction (offset, M) (or - centre) and the weights of `weights`."""

    weights: Callable
    correction: tuple
    centre: float | None
    chunk_rows: int

    def __call__(self, samples, reference) -> np.ndarray:
        samples = np.asarray(samples, dtype=float)
        sums = np.zeros(3)
        for start in range(0, samples.shape[0], self.chunk_rows):
            stop = min(start + self.chunk_rows, samples.shape[0])
            raw, ref = samples[start:stop], reference_chunk(reference, start, stop)
            w = self.weights(raw, ref)
            r = corrected_magnitude(raw, *self.correction)
            r = r - (ref if ref is not None else self.centre)  # no cancellation
            sums += (w.sum(), w @ r, w @ (r * r))
        return sums
