"""What the |B1| objectives need from the data, gathered in one chunked pass.

The objectives of Eq. 8 in [1] and its reference variants are means over the N samples of a
function of |B1_i|. For the nine-parameter model, |B1_i|^2 is a quadratic form in the sample
(`nlpcal.models.zhou2010`). With the reference value F_i of sample i, a length L (the reference
field, or the radius of a sphere fitted to the data without one), d_i = (b_i - c) / L the centred,
scaled sample and gamma_i = (L / F_i)^2,

    u_i = |B1_i|^2 / F_i^2 - 1 = a_i + e(theta) . psi'_i                        (*)

where psi'_i = gamma_i psi(d_i) holds the ten quadratic monomials of d_i (x^2, y^2, z^2, xy, xz,
yz, x, y, z, 1), a_i = gamma_i |d_i|^2 - 1 is the value of u_i for the sphere of the frame, and
e(theta) are ten coefficients that depend on the nine parameters only (`nlpcal.nlp.objective`).
Every power u^k with k <= 4 is a linear function of the products

    h_i = [1, psi'_i, psi'_i psi'_i^T (upper triangle), a_i, a_i psi'_i, a_i^2]

and those products are monomials of d_i times powers of a_i and gamma_i. The features kept are
the distinct ones, gamma^j a^k d^m: 46 when gamma is constant (no reference, or a constant one,
then gamma = 1), 58 for a reference series. Their weighted Gram matrix

    G = (1/N) sum_i w_i f_i f_i^T,        w_i = F_i^2 / mean(F^2)

carries everything the objectives need. It is additive over chunks: memory is O(chunk) and the
symbolic problem has the same size for every N.

Optional groups of moments sit beside G and share its features and frame: the lag of a
reference series adds one vector and one number, (1/N) sum_i w_i x_i f_i and
(1/N) sum_i w_i x_i^2 with x_i = D_i / F_i the reference's time derivative over its value
(`nlpcal.lag`), gathered by a pass of its own.

Floating-point cancellation is kept away by the frame: centred on a sphere fitted to the samples
and scaled by the field, a_i and e are small near the solution, so the small objective is never
the difference of large sums.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from itertools import combinations_with_replacement

import numpy as np

from .errors import InputError
from .passes import as_rows, mean_square, reduce, reference_chunk
from .statistics import MagnitudeStats

#: Rows per chunk of the data pass: large enough for BLAS, small enough for the cache.
CHUNK_ROWS = 8192

#: Exponents of psi = (x^2, y^2, z^2, xy, xz, yz, x, y, z, 1).
PSI_EXPONENTS = (
    (2, 0, 0),
    (0, 2, 0),
    (0, 0, 2),
    (1, 1, 0),
    (1, 0, 1),
    (0, 1, 1),
    (1, 0, 0),
    (0, 1, 0),
    (0, 0, 1),
    (0, 0, 0),
)
N_PSI = len(PSI_EXPONENTS)
#: (k, l) with k <= l: the products psi_k psi_l that (e . psi)^2 needs.
PAIR_INDICES = tuple((k, l) for k in range(N_PSI) for l in range(k, N_PSI))


def monomials(max_degree: int, variables: int = 3):
    """Exponent tuples of `variables` variables of degree <= max_degree, by degree, and how to
    build each one: (parent index, variable), the monomial being its parent times the variable."""
    exps: list[tuple[int, ...]] = [(0,) * variables]
    recipe = [(-1, -1)]  # (parent index, variable): monomial = parent * d[:, variable]
    for degree in range(1, max_degree + 1):
        for combo in combinations_with_replacement(range(variables), degree):
            e = [0] * variables
            for v in combo:
                e[v] += 1
            parent = list(e)
            parent[combo[-1]] -= 1
            exps.append(tuple(e))
            recipe.append((exps.index(tuple(parent)), combo[-1]))
    return tuple(exps), tuple(recipe)


MONOMIALS, _RECIPE = monomials(4)  # 35 monomials of degree <= 4


def _add(a, b):
    return tuple(x + y for x, y in zip(a, b))


@dataclass(frozen=True, eq=False)
class Layout:
    """Which distinct feature each entry of h is, for one kind of reference.

    keys : the distinct features as (power of gamma, power of a, exponents of d).
    one, a, a2 : indices of the features 1, a, a^2.
    psi[k], pair[(k, l)], apsi[k] : indices of psi'_k, psi'_k psi'_l and a psi'_k.
    """

    varying_gamma: bool
    keys: tuple
    one: int
    a: int
    a2: int
    psi: tuple
    pair: dict
    apsi: tuple

    @property
    def size(self) -> int:
        return len(self.keys)


@cache
def layout(varying_gamma: bool) -> Layout:
    """The feature layout: with gamma constant, powers of gamma fold into the data."""
    keys: list = []

    def key(gamma_power, a_power, exps):
        k = (gamma_power if varying_gamma else 0, a_power, exps)
        if k not in keys:
            keys.append(k)
        return keys.index(k)

    zero = (0, 0, 0)
    # Plain monomials first (every one of degree <= 4 occurs), so the Gram's leading block is
    # the moment matrix of d.
    if not varying_gamma:
        for exps in MONOMIALS:
            key(0, 0, exps)
    one = key(0, 0, zero)
    psi = tuple(key(1, 0, e) for e in PSI_EXPONENTS)
    pair = {(k, l): key(2, 0, _add(PSI_EXPONENTS[k], PSI_EXPONENTS[l])) for k, l in PAIR_INDICES}
    a = key(0, 1, zero)
    apsi = tuple(key(1, 1, e) for e in PSI_EXPONENTS)
    a2 = key(0, 2, zero)
    return Layout(varying_gamma, tuple(keys), one, a, a2, psi, pair, apsi)


@dataclass(frozen=True)
class Frame:
    """A sphere fitted to the raw samples.

    centre : (3,) its centre. [field unit]
    radius : its radius. [field unit]
    """

    centre: np.ndarray
    radius: float


def sphere_frame(samples: np.ndarray, max_points: int = 20000) -> Frame:
    """Algebraic sphere fit |b|^2 = 2 c.b + k to an evenly strided subsample."""
    step = max(1, samples.shape[0] // max_points)
    sub = samples[::step]
    scale = float(np.sqrt(np.mean(np.einsum("ij,ij->i", sub, sub)))) or 1.0
    unit = sub / scale  # fit in scaled units so that the normal equations are well conditioned
    design = np.column_stack([2.0 * unit, np.ones(unit.shape[0])])
    solution, *_ = np.linalg.lstsq(design, np.einsum("ij,ij->i", unit, unit), rcond=None)
    centre = solution[:3] * scale
    radius_sq = (solution[3] + solution[:3] @ solution[:3]) * scale**2
    if not np.isfinite(radius_sq) or radius_sq <= 0 or not np.isfinite(centre).all():
        # Degenerate coverage (all samples on a plane through the origin, say): fall back to the
        # mean and the rms distance from it.
        centre = sub.mean(axis=0)
        radius_sq = float(np.mean(np.sum((sub - centre) ** 2, axis=1)))
    radius = float(np.sqrt(radius_sq)) if radius_sq > 0 else 1.0
    return Frame(centre=np.asarray(centre, dtype=float), radius=radius)


@dataclass
class Moments:
    """Sufficient statistics of a log for the |B1| objectives.

    gram : weighted mean of f f^T over the distinct features of `layout(reference == "series")`.
    frame : the sphere fitted to the samples (the centre of d, and a start for the solvers).
    length : L, the scale of d and of u: the sphere radius (no reference), the reference field,
        or the rms of the reference series. [field unit]
    n : number of samples.
    reference : "none", "constant" or "series".
    measured : Table 1 statistics of the raw |B_M| (`nlpcal.statistics.MagnitudeStats`),
        gathered in the same pass.
    weight_sum : the sum of the per-sample weights the Gram matrix is normalised by (N without
        weights).
    cache : values derived from these moments by the layers that use them (the problems'
        parameter vector), built once.
    """

    gram: np.ndarray
    frame: Frame
    length: float
    n: int
    reference: str
    measured: dict
    weight_sum: float = 0.0
    cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def layout(self) -> Layout:
        return layout(self.reference == "series")


@cache
def _groups(varying_gamma: bool):
    """Feature columns grouped by their powers of gamma and a, with their monomial columns."""
    column = {exps: i for i, exps in enumerate(MONOMIALS)}
    groups: dict = {}
    for j, (g_pow, a_pow, exps) in enumerate(layout(varying_gamma).keys):
        cols, monos = groups.setdefault((g_pow, a_pow), ([], []))
        cols.append(j)
        monos.append(column[exps])
    return tuple((g, p, np.array(c), np.array(m)) for (g, p), (c, m) in groups.items())


def fill_features(d, a, gamma, lay: Layout, out, recipe=_RECIPE, groups=None) -> None:
    """Fill `out` (lay.size x rows) with the distinct features gamma^j a^k d^m of one chunk.

    Features are rows, samples are columns: every operation runs along contiguous memory. With
    gamma constant the first rows of the layout are the monomials themselves, built in place.
    `recipe` and `groups` (default: those of d's three coordinates) build the monomials of
    other variables, the rows of `d` (the channels' feature group, `nlpcal.auxiliary.moments`).
    """
    in_place = not lay.varying_gamma
    mono = out[: len(recipe)] if in_place else np.empty((len(recipe), d.shape[1]))
    mono[0] = 1.0
    for index in range(1, len(recipe)):
        parent, variable = recipe[index]
        np.multiply(mono[parent], d[variable], out=mono[index])
    for g_pow, a_pow, rows, monos in groups or _groups(lay.varying_gamma):
        if in_place and not (g_pow or a_pow):
            continue
        block = mono[monos]
        if a_pow:
            block *= a**a_pow
        if g_pow:
            block *= gamma**g_pow
        out[rows] = block


@dataclass(frozen=True)
class GramBlock:
    """The work of the data pass on one block of rows: its partial Gram matrix (a sum, not yet
    a mean), the Table 1 sums of its raw |B_M| and the sum of its weights.

    centre, length : the frame of d = (b - centre) / length. [field unit]
    lay : the feature layout. shift : the shift of the `MagnitudeStats` sums. [field unit]
    weight : None, or a function (raw chunk, its reference) -> the chunk's weights. [1]
    """

    centre: np.ndarray
    length: float
    lay: Layout
    shift: float
    chunk_rows: int = CHUNK_ROWS
    weight: Callable | None = None

    def __call__(self, samples, reference) -> tuple:
        """(gram, measured, weight total) of the rows `samples` and their `reference` (None, a
        number or an array of the same rows). [field unit]"""
        samples = np.asarray(samples, dtype=float)
        rows = samples.shape[0]
        size = self.lay.size
        gram = np.zeros((size, size))
        buffer = np.empty((size, max(1, min(self.chunk_rows, rows))))
        measured = MagnitudeStats(self.shift)
        total = 0.0
        series = reference is not None and np.ndim(reference) > 0
        for start in range(0, rows, self.chunk_rows):
            stop = min(start + self.chunk_rows, rows)
            raw = samples[start:stop]
            ref = reference_chunk(reference, start, stop)
            measured.add(np.sqrt(np.einsum("ij,ij->i", raw, raw)), ref)
            d = (raw - self.centre).T / self.length  # 3 x rows
            radius_sq = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
            if not series:
                gamma, a = None, radius_sq - 1.0
            else:
                gamma = (self.length / ref) ** 2
                a = gamma * radius_sq - 1.0
            chunk = buffer[:, : stop - start]
            fill_features(d, a, gamma, self.lay, chunk)
            root = ref / self.length if series else None  # sqrt of w_i
            if self.weight is not None:
                omega = np.asarray(self.weight(raw, ref), dtype=float)
                total += float(omega.sum())
                root = np.sqrt(omega) if root is None else root * np.sqrt(omega)
            if root is not None:
                chunk *= root
            gram += chunk @ chunk.T
        return gram, measured, total


def merge_gram(first: tuple, second: tuple) -> tuple:
    """The partial results of `GramBlock` of two neighbouring blocks, `second` after `first`."""
    return first[0] + second[0], first[1].merge(second[1]), first[2] + second[2]


def accumulate(
    samples,
    reference=None,
    frame: Frame | None = None,
    chunk_rows: int = CHUNK_ROWS,
    weight=None,
    length: float | None = None,
) -> Moments:
    """One pass over the samples that builds the Gram matrix of the features, chunk by chunk.

    samples : (N, 3) raw sensor output B_M, in memory or a Dask log (`nlpcal.passes`). [field
        unit]
    reference : None (Eq. 8), a float F or an (N,) series F_i. [field unit]
    weight : None, or a function (raw chunk, its reference) -> the chunk's weights omega_i >= 0,
        so that the objectives become weighted means, sum omega_i r_i^2 / sum omega_i (the
        reweighting passes of a robust loss). [1]
    length : L of a reference series, when not the rms of the series (a Dask log's first
        pass, before its survey has that rms). [field unit]
    """
    samples = as_rows(samples)
    n = samples.shape[0]
    frame = frame or sphere_frame(samples)
    if reference is None:
        kind, length = "none", frame.radius
    elif np.ndim(reference) == 0:
        kind, length = "constant", float(reference)
    else:
        kind = "series"
        reference = as_rows(reference)
        length = length or float(np.sqrt(mean_square(reference)))
    first = samples[: min(1024, n)]
    shift = float(np.sqrt(np.einsum("ij,ij->i", first, first)).mean())
    work = GramBlock(frame.centre, length, layout(kind == "series"), shift, chunk_rows, weight)
    gram, measured, total = reduce(samples, reference, work, merge_gram, chunk_rows)
    n = measured.n  # the rows read: a Dask log's first pass may find fewer than declared
    if weight is not None and not total > 0:
        raise InputError(
            "every sample has weight zero: the loss scale is too small for the residuals of "
            "these data (raise --loss-scale, or leave it out to estimate it)"
        )
    total = total if weight is not None else float(n)
    gram /= total
    return Moments(
        gram=gram,
        frame=frame,
        length=length,
        n=n,
        reference=kind,
        measured=measured.result(),
        weight_sum=total,
    )
