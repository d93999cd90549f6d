"""Where the field pointed: the direction bins the corrected field visits, and logs whose samples
lie in one plane (a sensor turned about one axis only), which no nine-parameter fit can use.

All judged on a strided subsample of at most 20 000 rows (the survey's, for a Dask log).
"""

from __future__ import annotations

import numpy as np

from ..models.zhou2010 import PARAMETER_NAMES, Zhou2010Parameters, correct
from ..robust import robust_std

#: The 26 directions of a cube's faces, edges and corners: the bins of `direction_coverage`.
_BIN_DIRECTIONS = np.array(
    [
        (i, j, k)
        for i in (-1, 0, 1)
        for j in (-1, 0, 1)
        for k in (-1, 0, 1)
        if (i, j, k) != (0, 0, 0)
    ],
    dtype=float,
)
_BIN_DIRECTIONS /= np.linalg.norm(_BIN_DIRECTIONS, axis=1, keepdims=True)
#: Fewer bins than this fraction are reported as poor attitude coverage.
COVERAGE_WARN = 0.5
#: Samples whose cloud is thinner than this many noise standard deviations across its flattest
#: direction lie in one plane within the noise: the attitudes were turns about one axis only.
PLANAR_NOISE = 5.0
#: Without a reference field, a cloud thinner than this fraction of its extent along the plane
#: lies nearly in one plane: turns about one axis with tilts of a few degrees (+/-3 deg of tilt
#: give about 0.04). The parameters of the axes along the normal are then so weakly determined
#: that the quadratic standard errors no longer describe them (estimates 4-10 standard errors
#: off at +/-1.5 to 1 deg of tilt, none of it noise), so they count as not determined. A known
#: field magnitude holds them (standard errors that cover the truth down to +/-1.5 deg).
NEARLY_PLANAR = 0.05
#: A cloud at least this thick against its extent is never planar, whatever the noise.
NEVER_PLANAR = 0.2
#: A cloud thinner than this fraction of its extent lies in one plane whatever the noise level
#: it is judged against: the smallest eigenvalue of its second-moment matrix is resolved to about
#: machine epsilon times the largest, so thicknesses below sqrt(eps) = 1.5e-8 of the extent are
#: rounding, whose value depends on the BLAS kernel (0 on one, 1.2e-8 of the extent on another),
#: as does the noise of noise-free samples (1e-11 nT); a hundred times sqrt(eps) leaves a margin.
ROUNDING_THIN = 1e-6
#: Leading rows whose successive differences tell the noise across the plane.
HEAD_ROWS = 1024
#: A sensor axis whose share of the plane's normal exceeds this is one the plane leaves blind.
PLANAR_AXIS_SHARE = 0.2
#: The sensor axes each parameter involves (alpha couples x and z, beta y and z, gamma x and y).
_AXES_OF = dict(zip(PARAMETER_NAMES, ("x", "y", "z", "x", "y", "z", "xz", "yz", "xy")))
#: Most rows of the strided subsample the coverage and the flatness are judged on.
MAX_POINTS = 20000


def subsample(samples, max_points: int = MAX_POINTS) -> np.ndarray:
    """Every k-th row, at most about `max_points` of them. [field unit]"""
    return np.asarray(samples[:: max(1, samples.shape[0] // max_points)], dtype=float)


def coverage_centre(samples, frame) -> np.ndarray:
    """Where to judge the field directions of samples whose parameters are not determined: the
    centre of the sphere fitted to them, unless that sphere is degenerate (a radius over three
    times their spread: samples in a plane), then their mean. [field unit]"""
    sub = subsample(samples)
    mean = sub.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum((sub - mean) ** 2, axis=1))))
    return np.asarray(frame.centre) if frame.radius <= 3.0 * spread else mean


def bin_hits(vectors) -> np.ndarray:
    """(26,) how many of the vectors (N, 3) fall in each direction bin (`direction_bins`): the
    bin of a vector is the direction nearest to it (largest cosine); a zero vector, or one not
    finite, has no direction and falls in none.

    Found without the 26 cosines: a direction with m non-zero components (i, j, k in {-1, 0, 1})
    has the cosine sum_c i_c v_c / (|v| sqrt m) with v, greatest, for a given m, with the signs
    of v on its m largest components |v_c|. So the nearest direction is the best of three
    candidates, the largest component, the two largest, all three: the m whose sum of the m
    largest |v_c| over sqrt m is largest (a sample on the boundary of two bins falls in one of
    them). A dozen whole-array operations where the cosines' argmax over 26 columns takes
    several times as long (0.1 ms for 2 000 vectors).
    """
    v = np.ascontiguousarray(np.asarray(vectors, dtype=float).reshape(-1, 3).T)  # (3, N)
    a = np.abs(v)
    largest, smallest = np.max(a, axis=0), np.min(a, axis=0)
    total = np.sum(a, axis=0)
    with np.errstate(invalid="ignore"):  # inf - inf for an infinite vector: in no bin below
        two, three = (total - smallest) / np.sqrt(2.0), total / np.sqrt(3.0)
    one_best = (largest >= two) & (largest >= three)
    two_best = ~one_best & (two >= three)
    three_best = ~one_best & ~two_best
    index = np.zeros(v.shape[1])  # (i+1, j+1, k+1) in base 3
    for c, weight in enumerate((9.0, 3.0, 1.0)):
        # on the largest component; on all but the smallest; or on all three
        on = (one_best & (a[c] == largest)) | (two_best & (a[c] > smallest)) | three_best
        index += weight * (np.sign(v[c]) * on + 1.0)
    index -= index > 13  # no bin for (0, 0, 0)
    directed = (largest > 0) & np.isfinite(total)  # not a zero vector, nor NaN or infinite
    return np.bincount(index[directed].astype(np.intp), minlength=26)


def direction_bins() -> tuple:
    """(names, (26, 3) unit vectors) of the 26 direction bins, in `bin_hits` order. [1]"""
    return list(_BIN_NAMES), _BIN_DIRECTIONS.copy()


def direction_coverage(samples, theta) -> dict:
    """How many of 26 direction bins the corrected field B1 visits."""
    b1 = correct(subsample(samples), Zhou2010Parameters.from_theta(theta))
    hits = bin_hits(b1)
    covered = int(np.count_nonzero(hits))
    missing = [_BIN_NAMES[k] for k in range(26) if not hits[k]]
    missing.sort(key=_bin_order)  # +x, -x, +y, -y, +z, -z, then edges and corners
    return {
        "direction_bins": 26,
        "covered": covered,
        "fraction": covered / 26,
        "missing": missing,
    }


def flatness(samples, noise: float, reference: bool = False) -> dict:
    """How thin the cloud of measured samples is across its flattest direction.

    Turns about one axis put the field on one circle, and an affine image of a circle is a planar
    ellipse: a whole family of ellipsoids passes through it, so the offset, scale and angles of the
    axes along the plane's normal are not determined, whatever the solver returns (the spread of
    |B1| even shrinks as the blind axis is scaled towards zero). The cloud lies in one plane when
    its thickness is within PLANAR_NOISE noise levels (and below NEVER_PLANAR of its extent) or
    below ROUNDING_THIN of its extent (where thickness and noise are both rounding), and,
    without a `reference` field, nearly in one when it is below NEARLY_PLANAR of its extent. The
    noise level is the smaller of `noise` (the residual standard deviation of the fit, which model
    misfit inflates) [field unit] and the noise of successive samples across the plane (1.4826
    MAD of their differences / sqrt 2: a log in time order).

    Returns the out-of-plane and in-plane standard deviations and the noise level judged against
    [field unit] (the successive samples' only when the residuals' would call the cloud planar),
    the unit normal in sensor axes, whether the samples are planar (or nearly), and the
    parameters the plane leaves blind.
    """
    sub = subsample(samples)
    centred = sub - sub.mean(axis=0)
    values, vectors = np.linalg.eigh(centred.T @ centred / max(sub.shape[0], 1))
    thickness, extent = np.sqrt(np.clip(values[[0, 2]], 0.0, None))
    normal = vectors[:, 0] * (1.0 if vectors[np.argmax(np.abs(vectors[:, 0])), 0] > 0 else -1.0)
    level = noise
    if thickness <= PLANAR_NOISE * noise:  # within the residuals: is it within the sensor noise?
        across = np.diff(np.asarray(samples[:HEAD_ROWS], dtype=float) @ normal)
        level = min(noise, robust_std(across) / np.sqrt(2.0) if across.size > 8 else np.inf)
    within_noise = bool(
        (thickness <= PLANAR_NOISE * level and thickness < NEVER_PLANAR * extent)
        or thickness <= ROUNDING_THIN * extent
    )
    planar = within_noise or (not reference and bool(thickness < NEARLY_PLANAR * extent))
    blind_axes = {axis for axis, share in zip("xyz", np.abs(normal)) if share > PLANAR_AXIS_SHARE}
    return {
        "planar": planar,
        "within_noise": within_noise,
        "out_of_plane_std": float(thickness),
        "in_plane_std": float(extent),
        "noise_std": float(level),
        "normal": [float(v) for v in normal],
        "parameters": [n for n in PARAMETER_NAMES if blind_axes & set(_AXES_OF[n])]
        if planar
        else [],
    }


def planar_message(flat: dict, unit: str) -> str:
    """Why a planar log cannot be calibrated, and what would help: one sentence."""
    normal = ", ".join(f"{v:+.2f}" for v in flat["normal"])
    thickness, extent = flat["out_of_plane_std"], flat["in_plane_std"]
    if flat.get("within_noise", True):
        how = "lie in one plane"
        why = (
            "the sensor was turned about one axis only, and a whole family of ellipsoids "
            "passes through one circle of directions"
        )
    else:
        how = "lie nearly in one plane"
        why = (
            "the sensor was turned about one axis with a few degrees of tilt at most, and a "
            "whole family of ellipsoids fits so thin a band of directions almost equally well"
        )
    return (
        f"the samples {how} (their spread across it is {thickness:.3g} {unit}, "
        f"{100 * thickness / extent:.2g} % of that along it; normal ({normal}) in sensor axes): "
        f"{why}, "
        f"so the data do not determine {', '.join(flat['parameters'])}; rotate the sensor "
        f"through more attitudes, tilting it out of that plane"
    )


def _bin_name(direction) -> str:
    """ "+x", "-x+y", "+x-y-z": the signs of a bin direction's non-zero components."""
    return "".join(
        f"{'+' if v > 0 else '-'}{axis}" for v, axis in zip(direction, "xyz") if abs(v) > 1e-9
    )


_BIN_NAMES = [_bin_name(d) for d in _BIN_DIRECTIONS]


def _bin_order(name: str) -> tuple:
    return (len(name), ["xyz".index(axis) for axis in name[1::2]], name[0::2])
