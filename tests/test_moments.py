"""The distinct moments and the Gram matrix assembled from them (`nlpcal.moments`).

The reference is the Gram matrix of the features as nlpcal gathered it before
(`gram_reference.reference_gram`, chunk by chunk f f^T): the moments and their fixed map must
give it to the rounding of float64 sums, for every kind of reference, with and without a robust
loss's weights, in several frames.
"""

import numpy as np
import pytest
from gram_reference import FeatureGram, reference_gram

from nlpcal.auxiliary.moments import accumulate_channels
from nlpcal.lag import Series, lag_moments
from nlpcal.moments import (
    Frame,
    MomentBlock,
    accumulate,
    gram_moments,
    moments_from,
    recentred,
    sphere_frame,
    sphere_from_moments,
)
from synthetic import PAPER_FIELD, make_log, planar_directions

#: ||G_new - G_old|| / ||G_old|| allowed: a few thousand roundings of sums of O(1) terms.
GRAM_RTOL = 1e-12


def log_and_references(n=9000, seed=3):
    samples, _ = make_log(n=n, noise=2.0, seed=seed)
    rng = np.random.default_rng(seed)
    series = PAPER_FIELD * (1.0 + 2e-3 * np.sin(np.linspace(0.0, 20.0, n)))
    weights = rng.uniform(0.0, 1.0, n)
    return samples, {"none": None, "constant": PAPER_FIELD, "series": series}, weights


def relative(new, old) -> float:
    return float(np.linalg.norm(new - old) / np.linalg.norm(old))


FRAMES = (
    None,  # the sphere fitted to the samples
    Frame(np.array([2500.0, -1800.0, 900.0]), 0.9 * PAPER_FIELD),  # a frame off the data
)


@pytest.mark.parametrize("kind", ["none", "constant", "series"])
@pytest.mark.parametrize("weighted", [False, True])
@pytest.mark.parametrize("frame", FRAMES)
def test_the_gram_matrix_from_the_moments_is_the_features_gram(kind, weighted, frame):
    samples, references, weights = log_and_references()
    reference = references[kind]
    weight = None
    if weighted:
        # The pass hands the weight function its rows: look them up by position.
        position = {row.tobytes(): i for i, row in enumerate(samples)}

        def weight(raw, ref):
            return weights[[position[row.tobytes()] for row in raw]]

    moments = accumulate(samples, reference, frame=frame, chunk_rows=2000, weight=weight)
    old = reference_gram(
        samples,
        reference,
        moments.frame.centre,
        moments.length,
        weights if weighted else None,
        chunk_rows=2000,
    )
    assert moments.gram.shape == old.shape == (moments.layout.size,) * 2
    assert relative(moments.gram, old) <= GRAM_RTOL
    assert moments.distinct.shape == (moments.moment_set.size,)


def test_the_moments_needed_are_far_fewer_than_the_gram_products():
    # 2K + |m| <= 8 over a and d: 165 + 84 + 35 + 10 + 1; a series adds gamma's powers
    # (J + K <= 4, |m| <= 2J) and the ten unweighted cubic moments of the sphere fit.
    assert gram_moments(False).size == 295
    assert gram_moments(True).size == 483 + 10
    assert gram_moments(False).products < 46 * 47 // 2
    assert gram_moments(True).products < 58 * 59 // 2


@pytest.mark.parametrize("kind", ["none", "constant", "series"])
def test_moments_recentred_equal_those_gathered_in_the_new_frame(kind):
    samples, references, _ = log_and_references(n=7000, seed=5)
    reference = references[kind]
    provisional = Frame(np.array([1500.0, -700.0, 400.0]), 0.95 * PAPER_FIELD)
    first = accumulate(samples, reference, frame=provisional)
    target = sphere_frame(samples)
    length = 1.02 * first.length if kind == "series" else None
    moved = recentred(first, target, length)
    if length is None:
        direct = accumulate(samples, reference, frame=target)
    else:
        work = MomentBlock(target.centre, length, True, 0.0)
        sums, measured, total = work(samples, reference)
        direct = moments_from(sums / len(samples), target, length, len(samples), kind, {}, 0.0)
    assert moved.length == pytest.approx(direct.length, rel=1e-15)
    assert relative(moved.gram, direct.gram) <= GRAM_RTOL
    assert relative(moved.distinct, direct.distinct) <= GRAM_RTOL
    np.testing.assert_array_equal(moved.frame.centre, target.centre)


def test_a_constant_reference_keeps_its_length():
    samples, _, _ = log_and_references(n=500)
    moments = accumulate(samples, PAPER_FIELD)
    with pytest.raises(ValueError):
        recentred(moments, moments.frame, 1.1 * PAPER_FIELD)


@pytest.mark.parametrize("kind", ["none", "constant", "series"])
def test_the_sphere_from_the_moments_is_the_sphere_of_the_rows(kind):
    samples, references, _ = log_and_references(n=6000, seed=7)
    off = Frame(np.array([-900.0, 3000.0, 1200.0]), 1.1 * PAPER_FIELD)
    moments = accumulate(samples, references[kind], frame=off)
    fitted, direct = sphere_from_moments(moments), sphere_frame(samples)
    # Both solve the same least-squares problem in differently scaled units: rounding only.
    np.testing.assert_allclose(fitted.centre, direct.centre, rtol=0, atol=1e-9 * PAPER_FIELD)
    assert fitted.radius == pytest.approx(direct.radius, rel=1e-12)


def test_the_lag_group_from_the_moments_is_the_features_sum():
    # g = (1/N) sum_i w_i x_i f_i and c = (1/N) sum_i w_i x_i^2 (L3 in nlpcal.lag), x = D / F.
    samples, references, _ = log_and_references(n=6000, seed=9)
    reference = references["series"]
    times = np.arange(len(samples)) * 0.1
    moments = accumulate(samples, reference)
    lag = lag_moments(samples, reference, times, moments, noise=0.0)
    R, D, _, _ = Series(reference, times).columns(0, len(samples))
    old = FeatureGram(moments.frame.centre, moments.length, True)(samples, R, derivative=D) / len(
        samples
    )
    assert relative(lag.g, old) <= GRAM_RTOL
    c = np.mean((R / moments.length) ** 2 * (D / R) ** 2)
    assert lag.c_observed == pytest.approx(c, rel=GRAM_RTOL)


@pytest.mark.parametrize("kind", ["constant", "series"])
def test_the_channels_gram_from_the_moments_is_the_features_gram(kind):
    samples, references, _ = log_and_references(n=5000, seed=11)
    rng = np.random.default_rng(11)
    channels = np.column_stack([rng.uniform(0, 40, len(samples)), rng.normal(3, 1, len(samples))])
    moments = accumulate(samples, references[kind])
    found = accumulate_channels(
        samples, channels, references[kind], moments.frame, moments.length, kind
    )
    scaled = (channels - found.channels.centre) / found.channels.scale
    old = FeatureGram(moments.frame.centre, moments.length, kind == "series", channels=2)(
        samples, references[kind], extra=scaled
    ) / len(samples)
    assert found.gram.shape == old.shape == (found.layout.size,) * 2
    assert relative(found.gram, old) <= GRAM_RTOL


def test_samples_in_one_plane_get_the_frame_of_their_mean():
    # A turntable log: every sphere through its circle fits, and the least-squares one is fixed by
    # the noise (four times the field away on this log); the frame falls back to the samples'
    # mean and rms distance, from the rows and from the moments alike.
    rng = np.random.default_rng(5)
    flat, _ = make_log(n=1200, noise=1.0, seed=9, directions=planar_directions(1200, rng))
    frame = sphere_frame(flat)
    np.testing.assert_allclose(frame.centre, flat.mean(axis=0), rtol=1e-12)
    assert frame.radius == pytest.approx(PAPER_FIELD, rel=0.05)
    from_moments = sphere_from_moments(accumulate(flat, PAPER_FIELD, frame=FRAMES[1]))
    np.testing.assert_allclose(from_moments.centre, frame.centre, rtol=0, atol=1e-9 * PAPER_FIELD)
    assert from_moments.radius == pytest.approx(frame.radius, rel=1e-12)
