"""The Gram matrices of features as nlpcal gathered them before the distinct moments: one chunk
of features f (rows) per step, G += f f^T (and, for the lag's group, g += f (w x)). Kept only as
the reference the moment passes and their linear maps are checked against
(tests/test_moments.py) and timed beside (benchmarks/bench_calibrate.py --pass-costs)."""

from dataclasses import dataclass

import numpy as np

from nlpcal.auxiliary.moments import channel_layout
from nlpcal.moments import CHUNK_ROWS, MONOMIALS, layout
from nlpcal.monomials import monomials

_RECIPE = monomials(4)[1]


def _groups(lay, monomial_exps=MONOMIALS):
    """Feature rows grouped by their powers of gamma and a, with their monomial rows."""
    column = {exps: i for i, exps in enumerate(monomial_exps)}
    groups: dict = {}
    for j, (g_pow, a_pow, exps) in enumerate(lay.keys):
        cols, monos = groups.setdefault((g_pow, a_pow), ([], []))
        cols.append(j)
        monos.append(column[exps])
    return tuple((g, p, np.array(c), np.array(m)) for (g, p), (c, m) in groups.items())


def fill_features(d, a, gamma, lay, out, recipe=_RECIPE, groups=None):
    """Fill `out` (lay.size x rows) with the distinct features gamma^j a^k d^m of one chunk;
    with gamma constant the first rows are the monomials themselves, built in place."""
    in_place = not lay.varying_gamma
    mono = out[: len(recipe)] if in_place else np.empty((len(recipe), d.shape[1]))
    mono[0] = 1.0
    for index in range(1, len(recipe)):
        parent, variable = recipe[index]
        np.multiply(mono[parent], d[variable], out=mono[index])
    for g_pow, a_pow, rows, monos in groups or _groups(lay):
        if in_place and not (g_pow or a_pow):
            continue
        block = mono[monos]
        if a_pow:
            block *= a**a_pow
        if g_pow:
            block *= gamma**g_pow
        out[rows] = block


@dataclass(frozen=True)
class FeatureGram:
    """The old work of a block: sum_i w_i omega_i f_i f_i^T over the features of `layout`
    (with K auxiliary channels, those of `channel_layout`, their values after the sample's
    coordinates in `extra`), and the lag's sum_i w_i x_i f_i when `derivative` is given."""

    centre: np.ndarray
    length: float
    series: bool
    channels: int = 0
    chunk_rows: int = CHUNK_ROWS

    def __call__(self, samples, reference, weights=None, extra=None, derivative=None):
        samples = np.asarray(samples, dtype=float)
        lay = channel_layout(self.series, self.channels) if self.channels else layout(self.series)
        exps, recipe = monomials(4, 3 + self.channels)
        groups = _groups(lay, exps)
        gram = np.zeros((lay.size, lay.size))
        lag = np.zeros(lay.size)
        buffer = np.empty((lay.size, max(1, min(self.chunk_rows, samples.shape[0]))))
        for start in range(0, samples.shape[0], self.chunk_rows):
            stop = min(start + self.chunk_rows, samples.shape[0])
            d = (samples[start:stop] - self.centre).T / self.length
            if self.channels:
                d = np.vstack([d, extra[start:stop].T])
            radius_sq = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
            if self.series:
                ref = np.asarray(reference, dtype=float)[start:stop]
                gamma = (self.length / ref) ** 2
                a = gamma * radius_sq - 1.0
            else:
                gamma, a = None, radius_sq - 1.0
            chunk = buffer[:, : stop - start]
            fill_features(d, a, gamma, lay, chunk, recipe, groups)
            if derivative is not None:  # the lag's group: a pass of its own before
                lag += chunk @ ((ref / self.length) ** 2 * (derivative[start:stop] / ref))
                continue
            root = ref / self.length if self.series else None
            if weights is not None:
                omega = np.sqrt(weights[start:stop])
                root = omega if root is None else root * omega
            if root is not None:
                chunk *= root
            gram += chunk @ chunk.T
        return lag if derivative is not None else gram


def reference_gram(samples, reference, centre, length, weights=None, chunk_rows=CHUNK_ROWS):
    """(1/total) sum_i w_i omega_i f_i f_i^T over the features of `layout`."""
    series = reference is not None and np.ndim(reference) > 0
    gram = FeatureGram(centre, length, series, chunk_rows=chunk_rows)(samples, reference, weights)
    total = len(samples) if weights is None else float(np.sum(weights))
    return gram / total
