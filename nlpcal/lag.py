"""The lag of a scalar reference series, estimated with the nine parameters of Eq. 4 in [1].

A scalar magnetometer recorded by another instrument carries its own clock. Its value on the row
of time t is the field at t - tau (tau > 0: the reference is late), R(t) = F(t - tau), so the
field at the row's time is, to first order,

    F(t) = R(t + tau) = R(t) + tau R'(t)                                          (L1)

and the residual of sample i becomes r_i = |B1_i| - R_i - tau D_i, D_i an estimate of R'(t_i).
Its mean square is a quadratic in tau,

    f(theta, tau) = f_0(theta) - 2 tau mean D_i (|B1_i| - R_i) + tau^2 mean D_i^2     (L2)

f_0 the reference objective of `nlpcal.nlp.objective`. With the notation of `nlpcal.moments`
(u_i, the weights w_i = R_i^2 / L^2 and the features f_i), |B1_i| - R_i = R_i (sqrt(1 + u_i) - 1)
= R_i (u_i / 2 - u_i^2 / 8 + ...), so with x_i = D_i / R_i [1/s]

    mean D_i (|B1_i| - R_i) = L^2 (U . g / 2 - P . g / 8),   g = (1/N) sum_i w_i x_i f_i
    mean D_i^2 = L^2 c,                                      c = (1/N) sum_i w_i x_i^2     (L3)

(U and P give u and u^2 on the features, `nlpcal.nlp.objective.feature_coefficients`; the term
u^3 / 16 dropped is of relative size u^2, below 1e-6 near any solution). g and c are the lag's
own group of moments, one more vector and one number beside the Gram matrix, gathered by one
pass block by block (`LagBlock`) as the distinct moments w x f_p and w x^2 over the variables
(gamma, a, d, x) (`lag_moment_set`, `nlpcal.monomials`): f keeps its size for every N.

The derivative is the central difference D_i = (R_{i+1} - R_{i-1}) / (t_{i+1} - t_{i-1}); a block
reads one row beyond each of its ends (two ahead for the noise estimate below), so the pass runs
in threads, on a memory map (`--low-memory`) and on Dask (`dask.array.map_overlap`) alike.

Errors in variables. Reference noise of variance sigma^2 puts noise of variance
v_i = sigma^2 q_i, q_i = 2 / (t_{i+1} - t_{i-1})^2, into D_i; mean D_i^2 then overstates the
signal's and shrinks tau by the factor mean D^2 / (mean D^2 + mean v) [F87, Sec. 1.1]. The
estimate corrects the moment, c -> c - sigma^2 mean q / L^2 (the method-of-moments estimator
[F87, Eq. 1.2.3]); the central difference leaves R_i itself out, so its noise is independent of
the residual's. sigma^2 is estimated from the third differences of R, whose variance is
20 sigma^2 for white noise and nearly free of a field smooth over four samples. The covariance
is the sandwich A_c^-1 A A_c^-1 (A the Gauss-Newton information with the observed derivative,
A_c the corrected one), widened, when the scores of neighbouring samples are alike, by the
moving-block jackknife of `nlpcal.inference.moving_block_jackknife`.

The correction takes the reference's noise as white on the rows; a filtered or interpolated
reference's is not (its third differences understate the derivative's noise, and tau is
attenuated). `third_autocorrelations` checks it and the estimate says so (`colour_warning`).

When |tau| exceeds half a sample, (L1) is no longer a small correction: the reference is
re-interpolated linearly at t + tau and the lag about it estimated again. The interpolation,
a fraction a of the way between rows, smooths the noise: sigma^2 is estimated once on the
rows as logged and the derivative's noise variance scaled by (1 - a)^2 + a^2
(`interpolated_share`).

The lag is determined when it stands MIN_SIGNIFICANCE standard errors from zero, or when its
standard error is within a tolerance (`--lag-tolerance`, LAG_TOLERANCE_S by default: the
time-stamp accuracy of INTERMAGNET's one-second data, so that a lag known to be near zero is
estimated, not undetermined). Neither test depends on the sample interval: the standard error
falls as 1 / sqrt(rate), and a limit in samples (~ 1 / rate) would tighten faster than it.
Otherwise it is undetermined: dF/dt too small against the noise (a quiet day at an
observatory).

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
[F87] Fuller, W. A. (1987). Measurement Error Models. Wiley. doi:10.1002/9780470316665
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import compiled, inference, passes, validation
from .errors import InputError, SolveError
from .models.zhou2010 import PARAMETER_NAMES, Zhou2010Parameters, correct, model_directions
from .moments import CHUNK_ROWS, VARIABLES, Layout, Moments, accumulate, feature_exponents
from .monomials import MomentSet, moment_set
from .nlp.blocks import variable_scale
from .nlp.objective import coefficient_derivative_functions, objective_derivatives
from .timing import reference_at

#: The statuses of a lag in a parameters file.
STATUSES = ("estimated", "given", "undetermined")
#: Rows a block reads beyond each of its ends: one behind, two ahead (central and third
#: differences).
HALO = 2
#: A lag is determined when it is this many standard errors from zero ... [1]
MIN_SIGNIFICANCE = 3.0
#: ... or when its standard error is within this tolerance (`--lag-tolerance`): the 10 ms
#: time-stamp accuracy INTERMAGNET asks of one-second data. [s]
LAG_TOLERANCE_S = 0.01
#: The autocorrelations at lags 1, 2, 3 of the third differences of white noise, (-15, 6, -1)
#: / 20. A reference averaged over 3 samples keeps -0.75 at lag 1 but gives 0.5 and -0.5 at
#: lags 2 and 3; one averaged over 2 samples gives -0.4 at lag 1. [1]
WHITE_THIRDS = (-0.75, 0.3, -0.05)
#: The noise is taken as coloured when one of them departs by more than this. [1]
COLOUR_TOLERANCE = 0.1
#: Rows of the reference, from its start, that judge the colour of its noise.
COLOUR_PROBE = 1_000_000
#: Re-interpolations of the reference before the lag is given up as not converging.
MAX_REINTERPOLATIONS = 6
#: Newton iterations of one joint solve; it stops when no step exceeds STEP_TOLERANCE standard
#: errors (the resolution of the estimate). [1]
MAX_NEWTON = 30
STEP_TOLERANCE = 0.01
#: Rows per block of the scores, the unit of the jackknife's groups.
SCORE_ROWS = 512
#: Blocks of scores below which the variance of tau is the Hessian's sandwich alone.
MIN_SCORE_BLOCKS = 20


def lag_option(value) -> str | float | None:
    """None, "auto" or a number of seconds, from `lag=` or `--lag`. [s]"""
    if value is None or (isinstance(value, str) and value == "auto"):
        return value
    return validation.number(value, "--lag ('auto', or a lag in seconds)")


def tolerance_option(value) -> float:
    """The tolerance of the standard error of a lag (`--lag-tolerance`), LAG_TOLERANCE_S when
    None. [s]"""
    if value is None:
        return LAG_TOLERANCE_S
    return validation.number(value, "--lag-tolerance (seconds)", minimum=0.0)


def is_determined(seconds: float, error: float, tolerance: float = LAG_TOLERANCE_S) -> bool:
    """Whether a lag [s] with standard error `error` [s] is determined: MIN_SIGNIFICANCE
    standard errors from zero, or an error within `tolerance` [s]; neither depends on the
    sample interval."""
    return bool(error <= tolerance or abs(seconds) >= MIN_SIGNIFICANCE * error)


def third_autocorrelations(reference) -> tuple:
    """The autocorrelations at lags 1, 2, 3 of the third differences of the reference's first
    COLOUR_PROBE rows: a sample of its noise nearly free of a field smooth over four samples,
    to compare with WHITE_THIRDS (the noise correction takes the noise as white). [1]"""
    if isinstance(reference, passes.LazySamples):
        reference = reference.array
    thirds = np.diff(np.asarray(reference[:COLOUR_PROBE], dtype=float), 3)
    thirds = thirds[np.isfinite(thirds)]
    power = float(thirds @ thirds)
    if thirds.size < 100 or not power > 0:
        return WHITE_THIRDS
    return tuple(float(thirds[:-k] @ thirds[k:]) / power for k in (1, 2, 3))


def check_times(times, n: int) -> np.ndarray:
    """Times of the rows as seconds from any origin, increasing strictly. [s]"""
    if times is None:
        raise InputError("a lag needs the time of every sample: give --time-column")
    times = np.asarray(times, dtype=float)
    if times.shape != (n,):
        raise InputError(f"got {times.size} times for {n} samples; expected one time per sample")
    if not np.isfinite(times).all():
        raise InputError("the time column has missing or non-numeric values")
    if n > 1 and not (np.diff(times) > 0).all():
        raise InputError("the times must increase from row to row for a lag")
    return times


def sample_interval(times: np.ndarray) -> float:
    """The median interval between rows. [s]"""
    return float(np.median(np.diff(times))) if times.size > 1 else float("nan")


def check_span(seconds: float, times: np.ndarray) -> float:
    """A lag given (`--lag SECONDS`, or a parameters file's) that leaves rows with a reference:
    shorter than the span of the times, else InputError (`kept_rows` would keep none). [s]"""
    span = float(times[-1] - times[0]) if times.size else 0.0
    if abs(seconds) >= span:
        raise InputError(
            f"a lag of {seconds:g} s moves the reference off the log, which spans {span:g} s: "
            f"no row would keep a reference value"
        )
    return seconds


def kept_rows(times: np.ndarray, tau: float) -> slice:
    """The rows whose time moved by the lag, t + tau, falls within the reference's span
    [t_0, t_end] (the times increase: one stretch). The others, within |tau| of one end, have
    no reference value once the lag is taken out and are dropped (`dropped_note`)."""
    start = int(np.searchsorted(times, times[0] - tau, side="left"))
    stop = int(np.searchsorted(times, times[-1] - tau, side="right"))
    return slice(start, max(start, stop))


def dropped_note(dropped: int, tau: float) -> str:
    """The sentence that tells how many rows a lag [s] left without a reference."""
    return (
        f"{dropped} row(s) within {abs(tau):g} s of the {'end' if tau > 0 else 'start'} of the "
        f"log dropped: once the lag is taken out, the reference has no value for them"
    )


def shifted(reference, times: np.ndarray, tau: float) -> np.ndarray:
    """R(t + tau) on the rows `kept_rows(times, tau)`, by linear interpolation
    (`nlpcal.timing.reference_at`): the reference moved so that a lag tau is taken out (L1).
    Rows in a gap of the reference keep the line of its nearest values (`numpy.interp`).
    [reference unit]"""
    reference = np.asarray(reference, dtype=float)
    if tau == 0.0:
        return reference
    wanted = times[kept_rows(times, tau)] + tau
    moved = reference_at(times, reference, wanted)
    missing = ~np.isfinite(moved)
    moved[missing] = np.interp(wanted[missing], times, reference)
    return moved


def derivative_columns(reference, times, lead: int, rows: int) -> tuple:
    """(D, q, third) for `rows` rows from index `lead` of arrays extended by up to HALO rows:
    the central difference D [unit/s] (0 where a neighbour is missing), its noise factor q
    [1/s^2] (D's noise variance over the reference's; 0 where D is missing), and the squared
    third difference R_{i+2} - 3 R_{i+1} + 3 R_i - R_{i-1} [unit^2] (NaN where it cannot be
    formed)."""
    r = np.asarray(reference, dtype=float)
    t = np.asarray(times, dtype=float)
    index = np.arange(lead, lead + rows)
    D, q = np.zeros(rows), np.zeros(rows)
    inside = (index >= 1) & (index + 1 < r.size)
    i = index[inside]
    span = t[i + 1] - t[i - 1]
    slope = (r[i + 1] - r[i - 1]) / span
    good = np.isfinite(slope) & (span > 0)
    D[inside] = np.where(good, slope, 0.0)
    q[inside] = np.where(good, 2.0 / np.where(span > 0, span, 1.0) ** 2, 0.0)
    third = np.full(rows, np.nan)
    far = (index >= 1) & (index + 2 < r.size)
    j = index[far]
    third[far] = (r[j + 2] - 3 * r[j + 1] + 3 * r[j] - r[j - 1]) ** 2
    return D, q, third


@dataclass(frozen=True)
class Series:
    """A reference series and the times of its rows, in memory or mapped: a block reads its
    HALO rows beyond its ends from them."""

    reference: np.ndarray
    times: np.ndarray

    def columns(self, start: int, rows: int) -> tuple:
        """(R, D, q, third) of the rows start:start + rows (`derivative_columns`)."""
        low, high = max(0, start - HALO), min(self.reference.size, start + rows + HALO)
        around = derivative_columns(
            self.reference[low:high], self.times[low:high], start - low, rows
        )
        return (np.asarray(self.reference[start : start + rows], dtype=float), *around)


def _overlapped_columns(reference, times, block_info=None):
    """(rows, 4) columns R, D, q, third of a Dask block extended by the HALO rows of its
    neighbours (none beyond the ends of the log): the block's own rows only."""
    where = block_info[0]
    index, count = where["chunk-location"][0], where["num-chunks"][0]
    lead = HALO if index > 0 else 0
    rows = reference.size - lead - (HALO if index < count - 1 else 0)
    own = reference[lead : lead + rows]
    return np.column_stack([own, *derivative_columns(reference, times, lead, rows)])


def halo_chunks(sizes) -> tuple:
    """Block sizes with none below HALO rows (`dask.array.map_overlap` reads HALO rows of each
    neighbour): a short block is merged into the one before it (the first into the next), so
    that the blocks declared are the blocks computed."""
    merged: list = []
    for size in sizes:
        if merged and (size < HALO or merged[-1] < HALO):
            merged[-1] += size
        else:
            merged.append(size)
    return tuple(merged)


def lazy_columns(reference, times) -> passes.LazySamples:
    """The columns R, D, q, third of a Dask reference, each block computed with the HALO rows
    of its neighbours (`dask.array.map_overlap`)."""
    import dask.array as da

    array = reference.array if isinstance(reference, passes.LazySamples) else reference
    array = array.rechunk({0: halo_chunks(array.chunks[0])})
    stamps = da.from_array(np.asarray(times, dtype=float), chunks=array.chunks)
    stacked = da.map_overlap(
        _overlapped_columns,
        array,
        stamps,
        depth={0: HALO},
        boundary="none",
        trim=False,
        new_axis=1,
        chunks=(array.chunks[0], (4,)),
        dtype=float,
        meta=np.empty((0, 4)),
    )
    return passes.LazySamples(stacked)


@dataclass
class LagSums:
    """The lag's group of moments of one block (sums, not yet means).

    g : sum_i w_i x_i f_i over the features of the layout. c : sum_i w_i x_i^2. [1/s^2]
    q : sum_i q_i over the rows with a derivative [1/s^2]; counted : those rows.
    third, thirds : the sum of the squared third differences [unit^2] and their number.
    """

    g: np.ndarray
    c: float
    q: float
    counted: int
    third: float
    thirds: int

    def __add__(self, other: LagSums) -> LagSums:
        return LagSums(
            self.g + other.g,
            self.c + other.c,
            self.q + other.q,
            self.counted + other.counted,
            self.third + other.third,
            self.thirds + other.thirds,
        )


def _block_columns(series, reference, start: int) -> tuple:
    """(R, D, q, third) of a block: from its (rows, 4) columns on Dask, else from `series`."""
    if np.ndim(reference) == 2:
        block = np.asarray(reference, dtype=float)
        return block[:, 0], block[:, 1], block[:, 2], block[:, 3]
    return series.columns(start, len(reference))


@dataclass(frozen=True)
class LagBlock:
    """The work of the lag's pass on one block of rows (`nlpcal.passes.reduce`, indexed).

    series : the reference and its times in memory (None on Dask, whose blocks carry their
        columns). centre, length : the frame of the moments [unit]. lay : their layout.
    """

    series: Series | None
    centre: np.ndarray
    length: float
    lay: Layout
    chunk_rows: int = CHUNK_ROWS
    fast: bool = False  # the compiled kernel sums the moments (`nlpcal.compiled.use`)

    def __call__(self, samples, reference, start: int) -> LagSums:
        samples = np.asarray(samples, dtype=float)
        R, D, q, third = _block_columns(self.series, reference, start)
        moments, g_index, c_index = lag_moment_set(self.lay)
        found = np.isfinite(third)
        sums = moments.empty()
        rows = samples.shape[0]
        variables = np.empty((len(VARIABLES) + 1, max(1, min(self.chunk_rows, rows))))
        for begin in range(0, rows, self.chunk_rows):
            end = min(begin + self.chunk_rows, rows)
            ref = R[begin:end]
            chunk = variables[:, : end - begin]
            gamma, a, d, x = chunk[0], chunk[1], chunk[2:5], chunk[5]
            np.divide((samples[begin:end] - self.centre).T, self.length, out=d)
            np.divide(self.length, ref, out=gamma)
            gamma *= gamma
            np.einsum("ij,ij->j", d, d, out=a)
            a *= gamma
            a -= 1.0
            np.divide(D[begin:end], ref, out=x)  # x_i = D_i / R_i
            moments.add(sums, chunk, 1.0 / gamma, self.fast)  # w_i = R_i^2 / L^2
        values = moments.values(sums)
        return LagSums(
            values[g_index],
            float(values[c_index]),
            float(q.sum()),
            int(np.count_nonzero(q)),
            float(third[found].sum()),
            int(found.sum()),
        )


_LAG_SETS: dict = {}


def lag_moment_set(lay: Layout) -> tuple:
    """The distinct moments of the lag's group (L3) over (gamma, a, x, y, z, x_i): w x f_p for
    each feature f_p and w x^2; with the positions of g and of c among them."""
    if lay not in _LAG_SETS:
        features = feature_exponents(lay)
        keys = [(*f, 1) for f in features] + [(0,) * len(VARIABLES) + (2,)]
        moments: MomentSet = moment_set(keys)
        where = moments.indices(keys)
        _LAG_SETS[lay] = (moments, where[:-1], int(where[-1]))
    return _LAG_SETS[lay]


def _add(first, second):
    return first + second


def _pass_inputs(samples, reference, times) -> tuple:
    """(samples, reference, series) for an indexed pass that needs the derivative."""
    samples = passes.as_rows(samples)
    reference = passes.as_rows(reference)
    if isinstance(samples, passes.LazySamples) or isinstance(reference, passes.LazySamples):
        if not isinstance(reference, passes.LazySamples):
            import dask.array as da

            reference = da.from_array(reference, chunks=(samples.array.chunks[0],))
        return samples, lazy_columns(reference, times), None
    return samples, reference, Series(reference, times)


@dataclass(frozen=True)
class LagMoments:
    """The lag's group of moments beside the Gram matrix (L3), as means.

    g : (size,) mean w_i x_i f_i. c_observed : mean w_i x_i^2 with the observed derivative;
    c : the same corrected for the reference's noise. [1/s^2]
    noise : the reference's noise variance estimated from its third differences. [unit^2]
    rms_derivative : the rms of dF/dt, corrected for that noise. [unit/s]
    """

    g: np.ndarray
    c_observed: float
    c: float
    noise: float
    rms_derivative: float


def lag_moments(samples, reference, times, moments: Moments, noise=None) -> LagMoments:
    """One pass over a log for the lag's moments (`LagBlock`), in the frame of `moments`.
    noise : the noise variance that multiplies q in the derivative [unit^2]; None: the
    reference's, from its third differences (white noise on the rows)."""
    samples, ref, series = _pass_inputs(samples, reference, times)
    fast = compiled.use(moments.n)
    work = LagBlock(series, moments.frame.centre, moments.length, moments.layout, fast=fast)
    sums = passes.reduce(samples, ref, work, _add, CHUNK_ROWS, indexed=True)
    n = moments.n
    if noise is None:
        noise = sums.third / (20.0 * sums.thirds) if sums.thirds else 0.0
    c_observed = sums.c / n
    c = c_observed - noise * (sums.q / n) / moments.length**2
    rms = moments.length * float(np.sqrt(max(c, 0.0)))
    return LagMoments(sums.g / n, c_observed, c, noise, rms)


def joint_derivatives(theta, tau: float, moments: Moments, lag: LagMoments, corrected=True):
    """(f, gradient, Hessian) of (L2) in (theta [internal units], tau [s]), from the moments.

    The theta part is `objective_derivatives`; the lag adds -2 tau L^2 b(theta) + tau^2 L^2 c
    with b = U . g / 2 - P . g / 8 (L3), its derivatives from the coefficients' Jacobians and
    curvature. `corrected` : c corrected for the reference's noise (False: the observed c, for
    the sandwich's meat). [unit^2]
    """
    length, centre = moments.length, moments.frame.centre
    f0, g0, h0 = (np.asarray(v, dtype=float) for v in _theta_part(theta, moments))
    jacobians, curvature = coefficient_derivative_functions(True)
    U, P, JU, JP = (np.asarray(v, dtype=float) for v in jacobians(theta, centre, length))
    g = lag.g
    b = float(U.ravel() @ g) / 2 - float(P.ravel() @ g) / 8
    grad_b = JU.T @ g / 2 - JP.T @ g / 8
    hess_b = np.asarray(curvature(theta, centre, length, g / 2, -g / 8), dtype=float)
    c = lag.c if corrected else lag.c_observed
    scale = length**2
    f = float(f0.item()) - 2 * tau * scale * b + tau**2 * scale * c
    gradient = np.append(
        g0.ravel() - 2 * tau * scale * grad_b, -2 * scale * b + 2 * tau * scale * c
    )
    hessian = np.zeros((10, 10))
    hessian[:9, :9] = h0 - 2 * tau * scale * hess_b
    hessian[:9, 9] = hessian[9, :9] = -2 * scale * grad_b
    hessian[9, 9] = 2 * scale * c
    return f, gradient, hessian


def _theta_part(theta, moments: Moments) -> tuple:
    return objective_derivatives(
        np.asarray(theta, dtype=float), moments.gram, moments.frame.centre, moments.length, "series"
    )


@dataclass
class JointSolve:
    """The optimum of (L2) over the free directions of theta and tau.

    theta : internal units. tau : about the reference as given to the solve. [s]
    hessian, observed : (10, 10) Hessians in (theta, tau) with the corrected and the observed c.
    objective : f at the optimum. [unit^2] iterations : Newton steps taken.
    """

    theta: np.ndarray
    tau: float
    objective: float
    hessian: np.ndarray
    observed: np.ndarray
    iterations: int


def solve_joint(theta_start, moments: Moments, lag: LagMoments, directions) -> JointSolve:
    """Newton's method with a halving line search on (L2), in the scaled free variables: the
    columns of `directions` (9, k) scaled by `nlpcal.nlp.blocks.variable_scale`, and tau scaled
    by its own resolution. (L2) is quadratic in tau and smooth in theta, so a few steps reach the
    optimum from the no-lag one; SolveError when they do not."""
    if not lag.c > 0:
        raise SolveError("the reference's time derivative is below its noise: no lag to fit")
    theta = np.asarray(theta_start, dtype=float).copy()
    tau = 0.0
    f, grad, hess = joint_derivatives(theta, tau, moments, lag)
    noise = max(f, 1e-30)
    basis = np.zeros((10, directions.shape[1] + 1))
    basis[:9, :-1] = variable_scale(moments.frame.radius)[:, None] * directions
    basis[9, -1] = np.sqrt(noise / (moments.length**2 * lag.c))
    for iteration in range(1, MAX_NEWTON + 1):
        g, h = basis.T @ grad, basis.T @ hess @ basis
        try:
            step = -np.linalg.solve(h, g)
        except np.linalg.LinAlgError:
            raise SolveError("the joint problem of the lag is singular") from None
        size = 1.0
        while True:
            trial = basis @ (size * step)
            f_new, grad_new, hess_new = joint_derivatives(
                theta + trial[:9], tau + trial[9], moments, lag
            )
            if f_new <= f + 1e-12 * abs(f) or size < 1e-6:
                break
            size /= 2
        theta, tau = theta + trial[:9], tau + float(trial[9])
        f, grad, hess = f_new, grad_new, hess_new
        resolution = np.sqrt(np.clip(np.diag(np.linalg.pinv(h)), 0, None) * 2 * noise / moments.n)
        if np.all(np.abs(size * step) <= STEP_TOLERANCE * np.maximum(resolution, 1e-300) + 1e-12):
            observed = joint_derivatives(theta, tau, moments, lag, corrected=False)[2]
            return JointSolve(theta, tau, f, hess, observed, iteration)
    raise SolveError(f"the joint solve of the lag did not converge in {MAX_NEWTON} Newton steps")


@dataclass(frozen=True)
class LagScores:
    """The work of the scores pass on one block: per SCORE_ROWS rows, the sum of the tau scores
    r_i D_i + tau sigma^2 q_i (zero-mean: the residual's -tau e_i meets the e_i of D_i)
    [unit^2/s] and of their information D_i^2 - sigma^2 q_i [unit^2/s^2], at the estimate
    (`lag_uncertainty`)."""

    series: Series | None
    parameters: Zhou2010Parameters
    tau: float
    noise: float

    def __call__(self, samples, reference, start: int) -> tuple:
        R, D, q, _ = _block_columns(self.series, reference, start)
        magnitude = np.linalg.norm(
            correct(np.asarray(samples, dtype=float), self.parameters), axis=1
        )
        residual = magnitude - R - self.tau * D
        starts = np.arange(0, R.size, SCORE_ROWS)
        if not starts.size:
            return np.zeros(0), np.zeros(0)
        return (
            np.add.reduceat(residual * D + self.tau * self.noise * q, starts),
            np.add.reduceat(D * D - self.noise * q, starts),
        )


def _concatenate(first, second):
    return np.concatenate([first[0], second[0]]), np.concatenate([first[1], second[1]])


def tau_dependence(samples, reference, times, theta, tau: float, noise: float) -> dict:
    """The variance of tau from the scores of its blocks [s^2]: the sandwich of the block sums,
    sum_b S_b^2 / (sum_b A_b)^2, which holds when the residuals' spread follows the field's
    activity or neighbouring samples are alike within a block; the moving-block jackknife
    (`nlpcal.inference.moving_block_jackknife`) when the blocks' scores are alike too, if larger.
    None (and the Hessian's sandwich is kept) below MIN_SCORE_BLOCKS blocks."""
    samples, ref, series = _pass_inputs(samples, reference, times)
    work = LagScores(series, Zhou2010Parameters.from_theta(theta), tau, noise)
    scores, shares = passes.reduce(samples, ref, work, _concatenate, CHUNK_ROWS, indexed=True)
    if scores.size < MIN_SCORE_BLOCKS or not shares.sum() > 0:
        return {"dependent": False, "variance": None}
    variance = float(scores @ scores) / float(shares.sum()) ** 2
    column = scores[:, None]
    if not inference.scores_dependent(column):
        return {"dependent": False, "variance": variance}
    length = inference.group_length(inference.bartlett_bandwidth(column), len(scores))
    jackknife, freedom = inference.moving_block_jackknife(
        column, shares[:, None, None], length, np.eye(1)
    )
    widened = float(jackknife[0, 0]) * inference.t_widening(freedom[0]) ** 2
    return {"dependent": True, "variance": max(variance, widened)}


def _direction_names(directions) -> list:
    """A name per free direction of theta: the parameter, or the tied ones joined by '='."""
    return [
        "=".join(n for n, v in zip(PARAMETER_NAMES, column) if v != 0.0)
        for column in np.asarray(directions).T
    ]


@dataclass
class LagEstimate:
    """A lag estimated with the parameters (L2), and what the data say of it.

    status : "estimated" or "undetermined". seconds : tau [s] (the estimate, also when
    undetermined; None when dF/dt is lost in the derivative's noise). standard_error_s : [s]
    or None. correlations : tau's correlation with each free
    parameter [1]. theta : the parameters of the joint optimum [internal units].
    sample_interval_s : [s]. rms_derivative : rms dF/dt with the noise taken out [unit/s].
    reference_noise : the reference's noise std from its third differences [unit].
    reinterpolations : times the reference was re-interpolated. dependent : whether the
    standard error follows dependent scores (the jackknife). [s]
    """

    status: str
    seconds: float | None
    standard_error_s: float | None
    correlations: dict
    theta: np.ndarray
    sample_interval_s: float
    rms_derivative: float
    reference_noise: float
    reinterpolations: int
    dependent: bool
    objective: float = float("nan")
    tolerance_s: float = LAG_TOLERANCE_S
    noise_autocorrelation: tuple = WHITE_THIRDS
    notes: list = field(default_factory=list)

    @property
    def determined(self) -> bool:
        return self.status == "estimated"

    @property
    def noise_white(self) -> bool:
        """Whether the reference's noise looks white (`third_autocorrelations`)."""
        departure = np.subtract(self.noise_autocorrelation, WHITE_THIRDS)
        return bool(np.all(np.abs(departure) <= COLOUR_TOLERANCE))

    def colour_warning(self) -> str | None:
        """The sentence that says tau may be attenuated by coloured reference noise, if so."""
        if self.noise_white:
            return None
        found = ", ".join(f"{value:.2f}" for value in self.noise_autocorrelation)
        return (
            f"the reference's noise is not white (autocorrelations of its third differences "
            f"{found} at lags 1-3, white noise {', '.join(f'{v:g}' for v in WHITE_THIRDS)}: "
            f"filtered, interpolated, or a field not smooth over four samples); the correction "
            f"for the derivative's noise assumes white noise, so the lag may be attenuated "
            f"towards zero (a low-passed reference) or biased"
        )

    def to_dict(self) -> dict:
        """The "lag" block of a parameters file (the undetermined estimate kept apart)."""
        document = {
            "status": self.status,
            "seconds": self.seconds if self.determined else None,
            "standard_error_s": self.standard_error_s,
            "sample_interval_s": self.sample_interval_s,
            "rms_derivative_per_s": self.rms_derivative,
            "reference_noise": self.reference_noise,
            "reinterpolations": self.reinterpolations,
            "correlations": dict(self.correlations),
            "noise_white": self.noise_white,
            "noise_autocorrelation": list(self.noise_autocorrelation),
        }
        if not self.determined:
            document["estimate_s"] = self.seconds
        return document

    def message(self) -> str:
        """One sentence for the report."""
        if self.seconds is None or self.standard_error_s is None:
            return (
                f"lag undetermined: the field's rate of change does not rise above the noise of "
                f"the reference's derivative (reference noise {self.reference_noise:.3g})"
            )
        if self.determined:
            return (
                f"lag of the reference {self.seconds * 1e3:+.2f} ms +/- "
                f"{self.standard_error_s * 1e3:.2f} ms (positive: the reference is late)"
            )
        return (
            f"lag undetermined: {self.seconds * 1e3:+.3g} ms is within {MIN_SIGNIFICANCE:g} "
            f"standard errors ({self.standard_error_s * 1e3:.3g} ms) of zero and that error "
            f"exceeds the tolerance of {self.tolerance_s * 1e3:g} ms; the field changes too "
            f"slowly (rms dF/dt {self.rms_derivative:.3g} per s) against the noise"
        )


def given_lag(seconds: float) -> dict:
    """The "lag" block of a lag given, not estimated. [s]"""
    return {"status": "given", "seconds": float(seconds), "standard_error_s": None}


def read_lag(reader) -> dict | None:
    """The "lag" block of a parameters file, checked (`nlpcal.results.DocumentReader`), or None."""
    block = reader.reader("lag", None)
    if block is None:
        return None
    status = block.string("status", options=list(STATUSES))
    seconds = block.number("seconds", None)
    if status != "undetermined" and seconds is None:
        raise InputError(f"{reader.source}: lag.seconds is missing for a lag {status}")
    block.number("standard_error_s", None, minimum=0.0)
    return dict(block.document)


def seconds_of(lag_block: dict | None) -> float:
    """The lag a parameters file's "lag" block tells apply and stats to take out: its seconds
    when estimated or given, 0 when undetermined or absent. [s]"""
    if not lag_block or lag_block.get("status") == "undetermined":
        return 0.0
    return float(lag_block["seconds"])


#: The scores' variance left to the Hessian's sandwich (`lag_uncertainty`).
WHITE = {"dependent": False, "variance": None}


def lag_uncertainty(joint: JointSolve, directions, n: int, dependence: dict) -> tuple:
    """(standard error of tau [s], correlations of tau with the free directions [1], whether it
    follows dependent scores): the sandwich s^2 A_c^-1 A A_c^-1 of the module's notes, its tau
    variance replaced by the one of the block scores (`tau_dependence`) when there is one."""
    basis = np.zeros((10, directions.shape[1] + 1))
    basis[:9, :-1] = directions
    basis[9, -1] = 1.0
    p = basis.shape[1]
    corrected = inference.information_from_hessian(basis.T @ joint.hessian @ basis, n)
    observed = inference.information_from_hessian(basis.T @ joint.observed @ basis, n)
    s2 = joint.objective * n / max(n - p, 1)
    inverse = np.linalg.pinv(corrected)
    covariance = s2 * inverse @ observed @ inverse
    variance = float(covariance[-1, -1])
    if dependence["variance"] is not None and variance > 0:
        factor = np.ones(p)
        factor[-1] = np.sqrt(dependence["variance"] / variance)
        covariance = covariance * np.outer(factor, factor)
    correlation = np.asarray(inference.correlation(covariance))
    names = _direction_names(directions)
    return (
        float(np.sqrt(covariance[-1, -1])),
        {name: float(correlation[-1, k]) for k, name in enumerate(names)},
        bool(dependence["dependent"]),
    )


def estimate_lag(
    samples, reference, times, theta_start, directions, tolerance: float = LAG_TOLERANCE_S
) -> LagEstimate:
    """tau with the free directions of theta (L2), re-interpolating the reference while |tau|
    exceeds half a sample.

    samples : (N, 3) raw B_M [unit]; reference : (N,) R [unit]; times : (N,) [s];
    theta_start : the no-lag optimum [internal units]; directions : (9, k) the model's free
    directions (`fixed_directions` for a fixed sensor); tolerance : the standard error that
    determines a lag near zero (`is_determined`). [s]
    """
    times = check_times(times, len(reference))
    interval = sample_interval(times)
    theta, tau, moved = np.asarray(theta_start, dtype=float), 0.0, 0
    rows, ref, stamps = samples, reference, times
    sigma2 = None  # the reference's noise variance, from its own rows [unit^2]
    while True:
        if tau != 0.0:
            kept = kept_rows(times, tau)
            rows, ref, stamps = (
                samples[kept],
                shifted(np.asarray(reference), times, tau),
                times[kept],
            )
        moments = accumulate(rows, ref)
        share = None if sigma2 is None else sigma2 * interpolated_share(tau, interval)
        group = lag_moments(rows, ref, stamps, moments, share)
        sigma2 = group.noise if sigma2 is None else sigma2
        if not group.c > 0:  # dF/dt lost in the reference's noise
            return silent_field(theta, interval, group, moved)
        joint = solve_joint(theta, moments, group, directions)
        theta = joint.theta
        white = lag_uncertainty(joint, directions, moments.n, WHITE)[0]
        # a wandering estimate: nothing to re-interpolate for
        vague = not is_determined(tau + joint.tau, white, tolerance)
        if abs(joint.tau) <= interval / 2 or vague:
            break
        if (
            moved == MAX_REINTERPOLATIONS
            or passes.is_dask(reference)
            or isinstance(reference, passes.LazySamples)
        ):
            raise SolveError(
                f"the lag did not settle within {MAX_REINTERPOLATIONS} re-interpolations of "
                f"the reference (last step {joint.tau:+.4g} s)"
                if moved == MAX_REINTERPOLATIONS
                else "a lag beyond half a sample needs the reference in memory to re-interpolate"
            )
        tau, moved = tau + joint.tau, moved + 1
    dependence = tau_dependence(rows, ref, stamps, theta, joint.tau, group.noise)
    error, correlations, dependent = lag_uncertainty(joint, directions, moments.n, dependence)
    determined = not vague and is_determined(tau + joint.tau, error, tolerance)
    return LagEstimate(
        status="estimated" if determined else "undetermined",
        seconds=tau + joint.tau,
        standard_error_s=error,
        correlations=correlations,
        theta=theta,
        sample_interval_s=interval,
        rms_derivative=group.rms_derivative,
        reference_noise=float(np.sqrt(sigma2)),
        reinterpolations=moved,
        dependent=dependent,
        objective=joint.objective,
        tolerance_s=tolerance,
        noise_autocorrelation=third_autocorrelations(reference),
    )


def interpolated_share(tau: float, interval: float) -> float:
    """The share of the reference's noise variance left in R(t + tau) interpolated linearly a
    fraction a = frac(tau / interval) of the way between its rows, (1 - a)^2 + a^2 [1]: each
    interpolated value weighs two noise terms by 1 - a and a, and so does its central
    difference (whose noise stays uncorrelated with the value's). The third differences of
    the interpolated series would state less, 20 (1 - a)^2 + 20 a^2 - 30 a (1 - a) over 20
    (1/8 at a = 1/2), the smoothing counted twice: sigma^2 is taken from the rows as logged."""
    a = float(np.mod(tau / interval, 1.0))
    return (1.0 - a) ** 2 + a**2


def silent_field(theta, interval: float, group: LagMoments, moved: int) -> LagEstimate:
    """The undetermined lag of a log whose dF/dt does not rise above the derivative's noise:
    no estimate, no standard error."""
    return LagEstimate(
        status="undetermined",
        seconds=None,
        standard_error_s=None,
        correlations={},
        theta=np.asarray(theta, dtype=float),
        sample_interval_s=interval,
        rms_derivative=0.0,
        reference_noise=float(np.sqrt(group.noise)),
        reinterpolations=moved,
        dependent=False,
    )


def fixed_directions() -> np.ndarray:
    """The lag with one common scale (s_x = s_y = s_z), the other parameters held: for a fixed
    sensor, whose attitudes determine none of the nine, the common scale takes up the baseline
    of delta F (a constant |B| - F of 0.02 % is a scale of 2e-4 at a steady |B|)."""
    return model_directions("offset", True)[:, 3:]


__all__ = [
    "LagEstimate",
    "estimate_lag",
    "given_lag",
    "lag_option",
    "model_directions",
    "shifted",
]
