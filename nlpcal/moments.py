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

The pass gathers the distinct moments, not G. With v_i = (gamma_i, a_i, x_i, y_i, z_i) (d_i =
(x_i, y_i, z_i)), omega_i a robust loss's weight (1 without one) and W = sum_i omega_i,

    m_e = (1/W) sum_i omega_i w_i v_i^e,        G_pq = m_(e_p + e_q)                  (M1)

where e_p is feature p's exponent tuple (`feature_exponents`): every Gram entry is one moment,
and the fixed map from the moments to G a selection (`gram_index`). a is kept as a variable of
its own, not expanded into |d|^2 - 1 (M2): near the solution a_i is of the order of the noise
over the field, and a^4 expanded into moments of d of degree 8 would be the difference of sums
of order one; kept, the a^k entries are sums of small terms, exact to the last digits as in the
Gram matrix of the features. (A calibrated sensor, 0.05 nT of noise in 50 000 nT, N = 1e6,
against sums in long double: mean a^4 is off by 4e-13 of itself kept, by 5e7 times itself
expanded, while both Gram matrices meet ||dG|| / ||G|| <= 1e-12.) The set needed
(`gram_moments`): 2k + |m| <= 8 in a^k d^m, 295 moments, with gamma constant; j + k <= 4
and |m| <= 2j in gamma^j a^k d^m, 483 (and the ten unweighted cubic moments of (M3)), for a
series. They are gathered as the entries of one staircase of matrix products per chunk
(`nlpcal.monomials`).

The sphere of the frame, the algebraic fit |b|^2 = 2 c.b + k, is a least-squares problem whose
normal equations in d (b = c0 + L d) read the unweighted moments of degree <= 3:

    [4 E(d d^T)  2 E(d)] [c_d]   [2 E(|d|^2 d)]
    [2 E(d)^T    1     ] [k_d] = [E(|d|^2)    ],   c = c0 + L c_d, R^2 = L^2 (k_d + |c_d|^2)  (M3)

(`sphere_from_moments`). The moments in another frame (centre c', length L') follow from those
in the first by the binomial algebra of the change of variables (`recentred`): with
s = L / L' and delta = (c' - c) / L',

    d' = s d - delta,   gamma' = gamma / s^2,   w' = s^2 w,
    a' = a - gamma (2 delta . d / s - |delta|^2 / s^2)               (a reference series)
    a' = s^2 a + s^2 - 1 + |delta|^2 - 2 s delta . d                 (none: gamma = 1)     (M4)

so each moment of the new frame is a fixed combination of moments of the old one of no higher
order, a linear map of the moment vector (`recentring_map`). It is exact in exact arithmetic;
in float64 the small entries of the new frame (the a^k ones near the solution) inherit the
rounding of the larger old ones they are combined from, relative |delta| + |a_old| per power
of a: a frame off the data by delta costs the precision of a frame that far, as in a pass
gathered in it. (On the log above, a centre 5, 50 and 500 nT off: mean a^2 off by 1e-12, 1e-10
and 1e-8 of itself after the change, mean a^4 by 9e-9, 3e-4 and 0.3.)

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

import numpy as np

from . import compiled
from .errors import InputError
from .monomials import MomentSet, moment_set, monomials
from .monomials import parents as _parents
from .passes import SAMPLE_POINTS, as_rows, mean_square, reduce, reference_chunk, sample_stride
from .statistics import MagnitudeStats

#: Rows per chunk of the data pass. Each chunk costs a few numpy calls besides the kernel's
#: (centring, |d|^2, the Table 1 sums), each holding the interpreter lock between two threads:
#: 32 768 rows (a buffer of 1.3 MB) keep them few; the kernels themselves work through the
#: chunk in steps that stay in a core's cache.
CHUNK_ROWS = 32768

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


MONOMIALS, _RECIPE = monomials(4)  # 35 monomials of degree <= 4
#: The variables of the moments, in the order of their exponent tuples.
VARIABLES = ("gamma", "a", "x", "y", "z")


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


def feature_exponents(lay: Layout) -> np.ndarray:
    """(size, 5) each feature's exponents over VARIABLES (gamma, a, x, y, z)."""
    return np.array([(g, k, *exps) for g, k, exps in lay.keys], dtype=int)


def pair_moments(lay: Layout, extra=()) -> tuple:
    """The distinct moments the Gram matrix of the features of `lay` needs (M1), with the
    exponent tuples `extra`; and the (size, size) position of each Gram entry among them."""
    exps = feature_exponents(lay)
    pairs = exps[:, None, :] + exps[None, :, :]
    moments = moment_set([*map(tuple, pairs.reshape(-1, exps.shape[1])), *extra])
    return moments, moments.indices(pairs)


@cache
def _gram_pairs(varying_gamma: bool) -> tuple:
    # With the unweighted moments of degree <= 3 the sphere fit reads (`sphere_from_moments`).
    unweighted = [(int(varying_gamma), 0, *e) for e in monomials(3)[0]]
    return pair_moments(layout(varying_gamma), unweighted)


def gram_moments(varying_gamma: bool) -> MomentSet:
    """The distinct moments of `layout(varying_gamma)`'s Gram matrix and the sphere fit."""
    return _gram_pairs(varying_gamma)[0]


def gram_index(varying_gamma: bool) -> np.ndarray:
    """(size, size) the position among `gram_moments` of each entry of the Gram matrix (M1)."""
    return _gram_pairs(varying_gamma)[1]


@dataclass(frozen=True)
class Frame:
    """A sphere fitted to the raw samples.

    centre : (3,) its centre. [field unit]
    radius : its radius. [field unit]
    """

    centre: np.ndarray
    radius: float


def sphere_frame(samples: np.ndarray, max_points: int = SAMPLE_POINTS) -> Frame:
    """Algebraic sphere fit |b|^2 = 2 c.b + k to an evenly strided subsample (`sample_stride`);
    on samples in one plane (`planar`), whose sphere the fit cannot determine, their mean and
    rms distance."""
    step = sample_stride(samples.shape[0], max_points)
    sub = samples[::step]
    scale = float(np.sqrt(np.mean(np.einsum("ij,ij->i", sub, sub)))) or 1.0
    unit = sub / scale  # fit in scaled units so that the normal equations are well conditioned
    design = np.column_stack([2.0 * unit, np.ones(unit.shape[0])])
    solution, *_ = np.linalg.lstsq(design, np.einsum("ij,ij->i", unit, unit), rcond=None)
    centre = solution[:3] * scale
    radius_sq = (solution[3] + solution[:3] @ solution[:3]) * scale**2
    mean = sub.mean(axis=0)
    spread = (sub - mean).T @ (sub - mean) / sub.shape[0]
    if _degenerate(centre, radius_sq, spread):
        centre = mean
        radius_sq = float(np.trace(spread))
    radius = float(np.sqrt(radius_sq)) if radius_sq > 0 else 1.0
    return Frame(centre=np.asarray(centre, dtype=float), radius=radius)


#: Samples whose spread across their flattest direction is below this fraction of the spread
#: along the widest lie in one plane: a circle, through which every sphere of a family passes,
#: so that the sphere fit is fixed by the noise alone (and may lie far from the samples). [1]
PLANAR_SPREAD = 1e-3


def _degenerate(centre, radius_sq, spread) -> bool:
    """Whether the sphere fit gives no frame: not finite, not positive, or the samples (their
    covariance `spread` [field unit^2]) in one plane (PLANAR_SPREAD)."""
    if not np.isfinite(radius_sq) or radius_sq <= 0 or not np.isfinite(centre).all():
        return True
    extremes = np.linalg.eigvalsh(spread)[[0, -1]]
    return bool(extremes[0] < PLANAR_SPREAD**2 * extremes[1])


@dataclass
class Moments:
    """Sufficient statistics of a log for the |B1| objectives.

    gram : weighted mean of f f^T over the distinct features of `layout(reference == "series")`,
        assembled from `distinct` (M1).
    frame : the sphere fitted to the samples (the centre of d, and a start for the solvers).
    length : L, the scale of d and of u: the sphere radius (no reference), the reference field,
        or the rms of the reference series. [field unit]
    n : number of samples.
    reference : "none", "constant" or "series".
    measured : Table 1 statistics of the raw |B_M| (`nlpcal.statistics.MagnitudeStats`),
        gathered in the same pass.
    weight_sum : the sum of the per-sample weights the moments are normalised by (N without
        weights).
    distinct : the distinct moments of `moment_set`, normalised like `gram`.
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
    distinct: np.ndarray | None = None
    cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def layout(self) -> Layout:
        return layout(self.reference == "series")

    @property
    def moment_set(self) -> MomentSet:
        return gram_moments(self.reference == "series")


def moments_from(
    distinct, frame: Frame, length: float, n: int, reference: str, measured: dict, weight_sum: float
) -> Moments:
    """`Moments` from the normalised distinct moments, the Gram matrix assembled (M1)."""
    gram = distinct[gram_index(reference == "series")]  # (M1)
    return Moments(gram, frame, length, n, reference, measured, weight_sum, distinct)


@dataclass(frozen=True)
class MomentBlock:
    """The work of the data pass on one block of rows: the sums of its distinct moments (not yet
    means), the Table 1 sums of its raw |B_M| and the sum of its weights.

    centre, length : the frame of d = (b - centre) / length. [field unit]
    series : whether the reference is a series (gamma varies). shift : the shift of the
    `MagnitudeStats` sums. [field unit]
    weight : None, or a function (raw chunk, its reference) -> the chunk's weights. [1]
    fast : whether the compiled kernel sums the moments (`nlpcal.compiled.use`).
    """

    centre: np.ndarray
    length: float
    series: bool
    shift: float
    chunk_rows: int = CHUNK_ROWS
    weight: Callable | None = None
    fast: bool = False

    def __call__(self, samples, reference) -> tuple:
        """(moment sums, measured, weight total) of the rows `samples` and their `reference`
        (None, a number or an array of the same rows). [field unit]"""
        samples = np.asarray(samples, dtype=float)
        rows = samples.shape[0]
        moments = gram_moments(self.series)
        sums = moments.empty()
        variables = np.empty((len(VARIABLES), max(1, min(self.chunk_rows, rows))))
        measured = MagnitudeStats(self.shift)
        total = 0.0
        for start in range(0, rows, self.chunk_rows):
            stop = min(start + self.chunk_rows, rows)
            raw = samples[start:stop]
            ref = reference_chunk(reference, start, stop)
            measured.add(np.sqrt(np.einsum("ij,ij->i", raw, raw)), ref)
            chunk = variables[:, : stop - start]
            gamma, a, d = chunk[0], chunk[1], chunk[2:]
            np.subtract(raw.T, self.centre[:, None], out=d)
            d *= 1.0 / self.length
            np.einsum("ij,ij->j", d, d, out=a)
            weight = None
            if self.series:
                np.divide(self.length, ref, out=gamma)
                gamma *= gamma
                a *= gamma
                weight = 1.0 / gamma  # w_i = F_i^2 / L^2
            a -= 1.0
            if self.weight is not None:
                omega = np.asarray(self.weight(raw, ref), dtype=float)
                total += float(omega.sum())
                weight = omega if weight is None else weight * omega
            moments.add(sums, chunk, weight, self.fast)
        return moments.values(sums), measured, total


def sphere_from_moments(moments: Moments) -> Frame:
    """The algebraic sphere fit |b|^2 = 2 c.b + k of `sphere_frame`, from the moments (M3).

    It reads the unweighted moments of d of degree <= 3 (for a series, those of w gamma = 1;
    with a robust loss's weights, the fit is weighted by them): the same least-squares problem
    as `sphere_frame` on the rows the moments were gathered from, so the same sphere up to
    rounding when `sphere_frame` reads every row (at most its `max_points`).
    """
    unit = int(moments.reference == "series")
    pick = moments.moment_set.indices
    basis = [(unit, 0, *e) for e in monomials(3)[0]]  # 1, d (3), d d (6), d d d (10)
    m = np.asarray(moments.distinct)[pick(basis)]
    total, mean = m[0], m[1:4]
    second = np.empty((3, 3))
    second[np.triu_indices(3)] = m[4:10]
    second = np.triu(second) + np.triu(second, 1).T
    third = dict(zip(basis[10:], m[10:]))

    def cubic(v):  # mean |d|^2 d_v
        return sum(
            third[(unit, 0, *np.add(np.eye(3, dtype=int)[v], 2 * np.eye(3, dtype=int)[w]))]
            for w in range(3)
        )

    normal = np.block([[4.0 * second, 2.0 * mean[:, None]], [2.0 * mean[None, :], total]])
    radius_mean = float(np.trace(second))
    right = np.append([2.0 * cubic(v) for v in range(3)], radius_mean)
    solution, *_ = np.linalg.lstsq(normal, right, rcond=None)  # (M3)
    length, origin = moments.length, moments.frame.centre
    centre = origin + length * solution[:3]
    radius_sq = (solution[3] + solution[:3] @ solution[:3]) * length**2
    spread = (second / total - np.outer(mean, mean) / total**2) * length**2
    if _degenerate(centre, radius_sq, spread):  # as in sphere_frame
        centre = origin + length * mean / total
        radius_sq = float(np.trace(spread))
    radius = float(np.sqrt(radius_sq)) if radius_sq > 0 else 1.0
    return Frame(centre=np.asarray(centre, dtype=float), radius=radius)


def recentred(moments: Moments, frame: Frame, length: float | None = None) -> Moments:
    """The moments in another frame: centre `frame.centre`, scale `length` (M4), exactly in
    exact arithmetic; a linear map of the distinct moments.

    length : L' [field unit]; None: the sphere radius (no reference), F (a constant reference,
    whose length cannot change) or the length of `moments` (a series).
    """
    kind = moments.reference
    if length is None:
        length = frame.radius if kind == "none" else moments.length
    if kind == "constant" and length != moments.length:
        raise ValueError("the length of moments with a constant reference is the reference F")
    shrink = moments.length / length  # s
    shift = (np.asarray(frame.centre, dtype=float) - moments.frame.centre) / length  # delta
    mapped = recentring_map(kind == "series", shrink, shift) @ moments.distinct  # (M4)
    return moments_from(
        mapped, frame, float(length), moments.n, kind, moments.measured, moments.weight_sum
    )


def recentring_map(varying_gamma: bool, s: float, delta) -> np.ndarray:
    """The matrix of (M4) on `gram_moments(varying_gamma)`: row e the monomial w' v'^e of the
    new frame as a combination of the old moments."""
    moments = gram_moments(varying_gamma)
    keys = moments.keys
    where = {k: i for i, k in enumerate(keys)}
    unit = np.eye(len(VARIABLES), dtype=int)
    gamma, a, d = unit[0], unit[1], unit[2:]
    zero = (0,) * len(VARIABLES)
    delta = np.asarray(delta, dtype=float)
    near = float(delta @ delta)
    # Each new variable as a polynomial in the old ones: {exponents: coefficient}.
    if varying_gamma:
        a_new = {tuple(a): 1.0, tuple(gamma): near / s**2}
        a_new.update({tuple(gamma + d[v]): -2.0 * delta[v] / s for v in range(3)})
    else:
        a_new = {tuple(a): s**2, zero: s**2 - 1.0 + near}
        a_new.update({tuple(d[v]): -2.0 * s * delta[v] for v in range(3)})
    new = [{tuple(gamma): s**-2.0}, a_new, *({tuple(d[v]): s, zero: -delta[v]} for v in range(3))]
    targets = {}
    for poly in new:
        for term in poly:
            if term not in targets:
                targets[term] = np.array(
                    [where.get(tuple(np.add(k, term)), -1) for k in keys], dtype=np.intp
                )
    order = sorted(range(len(keys)), key=lambda i: sum(keys[i]))
    recipe = dict(zip(order, _parents([keys[i] for i in order])))
    matrix = np.zeros((len(keys), len(keys)))
    for i in order:
        parent, variable = recipe[i]
        if parent == -1:  # the constant
            matrix[i, i] = 1.0
            continue
        if parent < 0:
            raise ValueError("the moment set is not closed under a change of frame")
        row, source = matrix[i], matrix[order[parent]]
        for term, coefficient in new[variable].items():
            target = targets[term]
            nonzero = source != 0
            if (target[nonzero] < 0).any():
                raise ValueError("the moment set is not closed under a change of frame")
            row[target[nonzero]] += coefficient * source[nonzero]
    return matrix * (s**2 if varying_gamma else 1.0)  # w' = s^2 w


def merge_moments(first: tuple, second: tuple) -> tuple:
    """The partial results of `MomentBlock` of two neighbouring blocks, `second` after `first`."""
    return first[0] + second[0], first[1].merge(second[1]), first[2] + second[2]


def accumulate(
    samples,
    reference=None,
    frame: Frame | None = None,
    chunk_rows: int = CHUNK_ROWS,
    weight=None,
    length: float | None = None,
) -> Moments:
    """One pass over the samples that gathers the distinct moments, chunk by chunk, and the
    Gram matrix of the features they make (M1).

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
    fast = compiled.use(n)
    work = MomentBlock(frame.centre, length, kind == "series", shift, chunk_rows, weight, fast)
    sums, measured, total = reduce(samples, reference, work, merge_moments, chunk_rows)
    n = measured.n  # the rows read: a Dask log's first pass may find fewer than declared
    if weight is not None and not total > 0:
        raise InputError(
            "every sample has weight zero: the loss scale is too small for the residuals of "
            "these data (raise --loss-scale, or leave it out to estimate it)"
        )
    total = total if weight is not None else float(n)
    return moments_from(sums / total, frame, length, n, kind, measured.result(), total)
