"""The standard errors of the joint solve with auxiliary channels: the sandwich covariance of
its scores, over the nine parameters of Eq. 4 in [1] and the stray fields v_k of
`nlpcal.auxiliary.model`.

The residual of sample i is r_i = |B1_i| - F_i (or - c without a reference, c the mean |B1|,
profiled out with the mean of J), B1 = O_p S_p (B_M - Z_p - sum_k v_k c_k). Its sensitivities
to the scaled parameters y (`nlpcal.nlp.channels`) are those of `nlpcal.calibration.scores`
(`sensitivities`, taken at B_M - sum v_k c_k) for the nine, and for v_k

    d|B1| / dv_k = -c_k M^T B1 / |B1| = c_k d|B1| / dZ_p.

One pass sums, per block of consecutive samples (counted from the log's first row, so that the
sums do not depend on how the pass splits the rows), the scores r_i J_i and the information
J_i J_i^T, and over the log the meat of independent samples, r_i^2 J_i J_i^T. The covariance is
the sandwich A^-1 Omega A^-1 (A = sum J J^T) with the meat of `nlpcal.inference.dependence_meat`,
as the nine-parameter calibration's: that of independent samples widened by Student's t, or,
when neighbouring blocks are alike (a smooth trajectory, a current that varies slowly), the
moving-block jackknife's, never narrower than the independent one.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import inference
from ..auxiliary.moments import stacked, subsample
from ..models.zhou2010 import PARAMETER_NAMES
from ..passes import reduce
from .scores import _merge, entry_derivatives, sensitivities

#: Rows per chunk of the scores pass (512 rows of up to 15 + 225 sums: 1 MB).
CHUNK_ROWS = 512
#: A covariance whose information matrix has a larger condition number is not stated. [1]
CONDITION_LIMIT = 1e14


def jacobian(raw, channels, theta, v, derivatives, scale) -> tuple:
    """(|B1|, J): |B1| of raw samples less their stray field (n,) [field unit] and its
    sensitivities to the scaled nine parameters and v (n, 9 + 3K) [field unit]."""
    compensated = raw - channels @ v
    magnitude, nine, g = sensitivities(compensated, theta, derivatives, scale[:9])
    stray = -(channels[:, :, None] * g[:, None, :]).reshape(len(raw), -1) * scale[9:]
    return magnitude, np.concatenate([nine, stray], axis=1)


@dataclass(frozen=True)
class ChannelScores:
    """The work of the scores pass on the rows from `start`: (index of its first block, per block
    the sums of r J and of J J^T (k, w + w^2), the sum of r^2 J J^T (w^2,)), w = 9 + 3K.

    centre, mean_j : without a reference, the mean |B1| [field unit] and the mean J; constant :
    a constant reference F [field unit] (a series comes as the last column of `extra`)."""

    theta: np.ndarray
    v: np.ndarray
    scale: np.ndarray
    channels: int
    block_rows: int
    constant: float | None = None
    centre: float | None = None
    mean_j: np.ndarray | None = None

    def __call__(self, samples, extra, start: int) -> tuple:
        samples, extra = np.asarray(samples, dtype=float), np.asarray(extra, dtype=float)
        n, k, width = samples.shape[0], self.channels, 9 + 3 * self.channels
        first = start // self.block_rows
        count = (start + n - 1) // self.block_rows - first + 1 if n else 0
        sums = np.zeros((count, width + width * width))
        meat = np.zeros((width, width))
        derivatives = entry_derivatives(self.theta)
        for begin in range(0, n, CHUNK_ROWS):
            stop = min(begin + CHUNK_ROWS, n)
            c = extra[begin:stop, :k]
            magnitude, j = jacobian(
                samples[begin:stop], c, self.theta, self.v, derivatives, self.scale
            )
            if self.constant is not None:
                r = magnitude - self.constant
            elif extra.shape[1] > k:
                r = magnitude - extra[begin:stop, k]
            else:
                r, j = magnitude - self.centre, j - self.mean_j
            values = np.concatenate(
                [j * r[:, None], (j[:, :, None] * j[:, None, :]).reshape(len(r), -1)], axis=1
            )
            index = (start + np.arange(begin, stop)) // self.block_rows - first
            edges = np.flatnonzero(np.diff(index, prepend=-1))  # the rows that open a block
            sums[index[edges]] += np.add.reduceat(values, edges, axis=0)
            meat += (j * (r * r)[:, None]).T @ j
        return first, sums, meat.ravel()


def joint_covariance(fit, samples, reference, kind: str, scale, q) -> dict:
    """Set `fit.v_errors` (K, 3) [field per channel unit] and `fit.inflation` (each of the nine
    parameters' standard error with v estimated over the one with v fixed, [1]) from the
    covariance of the scores (the module docstring); returns how it was estimated.

    q : (9 + 3K, p) orthonormal directions of the scaled parameters the fit moves along (those
    of the stray fields held at zero left out). kind : "none", "constant" or "series".
    scale : (9 + 3K,) the variable scales. [internal units]
    """
    k, n = fit.channels.count, samples.shape[0]
    extra = stacked(fit.channels.values, reference) if kind == "series" else fit.channels.values
    work = ChannelScores(fit.theta, fit.v, scale, k, inference.block_rows(n))
    if kind == "constant":
        work = ChannelScores(**{**work.__dict__, "constant": float(reference)})
    elif kind == "none":  # the mean |B1| and the mean J profiled out, from an even stride
        magnitude, j = jacobian(
            subsample(samples),
            subsample(fit.channels.values),
            fit.theta,
            fit.v,
            entry_derivatives(fit.theta),
            scale,
        )
        work = ChannelScores(
            **{**work.__dict__, "centre": float(magnitude.mean()), "mean_j": j.mean(axis=0)}
        )
    _, sums, totals = reduce(samples, extra, work, _merge, CHUNK_ROWS, indexed=True)
    width = 9 + 3 * k
    series, blocks = sums[:, :width], sums[:, width:].reshape(-1, width, width)
    meat = totals.reshape(width, width)
    dof = n - q.shape[1] - (kind == "none")
    marginal, how = _covariance(q, series, blocks, meat, dof)
    nine = q[:, ~np.any(q[9:], axis=0)]  # the directions that leave v where it is
    conditional, _ = _covariance(nine, series, blocks, meat, dof)
    if marginal is None or conditional is None:
        return {"method": "singular"}
    errors = np.sqrt(np.maximum(np.diag(marginal)[9:], 0.0)) * scale[9:]
    fit.v_errors = errors.reshape(k, 3)
    fit.inflation = {
        PARAMETER_NAMES[i]: float(np.sqrt(max(marginal[i, i], 0.0) / conditional[i, i]))
        for i in range(9)
        if conditional[i, i] > 0
    }
    return how


def _covariance(q, series, blocks, meat, dof: int) -> tuple:
    """(covariance of the scaled parameters within the directions q, how), or (None, ...) when
    the information along q is singular: the sandwich A^-1 Omega A^-1 with the meat Omega of
    `nlpcal.inference.dependence_meat` (the meat of independent samples `meat`, or the
    moving-block jackknife's when the block sums of the scores are dependent)."""
    information = q.T @ blocks.sum(axis=0) @ q
    if not np.linalg.cond(information) < CONDITION_LIMIT:
        return None, {"method": "singular"}
    inverse = np.linalg.inv(information)
    omega, how, _ = inference.dependence_meat(series, blocks, meat, dof, q)
    covariance = q @ inverse @ (q.T @ omega @ q) @ inverse @ q.T
    return covariance, {k: v for k, v in how.items() if k != "degrees_of_freedom"}
