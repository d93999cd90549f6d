"""The Gram matrix of the features as nlpcal gathered it before the distinct moments: one chunk
of features f (rows) per step, G += f f^T. Kept here only as the reference the moment pass and
its linear map are checked against (tests/test_moments.py)."""

import numpy as np

from nlpcal.moments import MONOMIALS, layout
from nlpcal.monomials import monomials

_RECIPE = monomials(4)[1]


def _groups(lay, monomial_exps=MONOMIALS):
    column = {exps: i for i, exps in enumerate(monomial_exps)}
    groups: dict = {}
    for j, (g_pow, a_pow, exps) in enumerate(lay.keys):
        cols, monos = groups.setdefault((g_pow, a_pow), ([], []))
        cols.append(j)
        monos.append(column[exps])
    return tuple((g, p, np.array(c), np.array(m)) for (g, p), (c, m) in groups.items())


def fill_features(d, a, gamma, lay, out, recipe=_RECIPE, groups=None):
    """The distinct features gamma^j a^k d^m of one chunk, features as rows."""
    mono = np.empty((len(recipe), d.shape[1]))
    mono[0] = 1.0
    for index in range(1, len(recipe)):
        parent, variable = recipe[index]
        np.multiply(mono[parent], d[variable], out=mono[index])
    for g_pow, a_pow, rows, monos in groups or _groups(lay):
        block = mono[monos]
        if a_pow:
            block *= a**a_pow
        if g_pow:
            block *= gamma**g_pow
        out[rows] = block


def reference_gram(samples, reference, centre, length, weights=None, chunk_rows=8192):
    """(1/total) sum_i w_i omega_i f_i f_i^T over the features of `layout`, chunk by chunk."""
    samples = np.asarray(samples, dtype=float)
    series = reference is not None and np.ndim(reference) > 0
    lay = layout(series)
    gram = np.zeros((lay.size, lay.size))
    for start in range(0, samples.shape[0], chunk_rows):
        stop = min(start + chunk_rows, samples.shape[0])
        d = (samples[start:stop] - centre).T / length
        radius_sq = np.einsum("ij,ij->j", d, d)
        if series:
            ref = np.asarray(reference, dtype=float)[start:stop]
            gamma = (length / ref) ** 2
            a = gamma * radius_sq - 1.0
        else:
            gamma, a = None, radius_sq - 1.0
        chunk = np.empty((lay.size, stop - start))
        fill_features(d, a, gamma, lay, chunk)
        root = ref / length if series else np.ones(stop - start)
        if weights is not None:
            root = root * np.sqrt(weights[start:stop])
        chunk *= root
        gram += chunk @ chunk.T
    total = samples.shape[0] if weights is None else float(np.sum(weights))
    return gram / total
