"""`nlpcal platform fit|apply` and `nlpcal.fit_tolles_lawson`: Tolles-Lawson compensation on a
synthetic figure-of-merit box made by the independent forward model of tests/synthetic.py (exact
derivatives of the direction cosines, a slow field variation below the band, white noise).

The reference of the fit is computed here, as MagNav.jl does it and independently of nlpcal:
the design typed in again, a zero-phase Butterworth band-pass over the whole record (filtfilt),
its ends trimmed, and a ridge solve on the scaled columns with the parameter chosen by
generalised cross-validation through a singular value decomposition."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

import nlpcal
from nlpcal.cli import main
from synthetic import TL_TRUTH, platform_record

signal = pytest.importorskip("scipy.signal")

RATE_HZ = 10.0
BAND_HZ = (0.1, 0.9)


@pytest.fixture(scope="module")
def box():
    """The done-when box: 12 000 samples at 10 Hz, the 18 true terms, 0.01 nT of noise."""
    return platform_record(n=12_000, rate_hz=RATE_HZ, noise=0.01, seed=5)


def reference_design(vector, rate_hz):
    """MagNav.jl's create_TL_A typed in again: cosines, |B| cos_i cos_j, |B| cos_i d(cos_j)/dt
    (central differences, np.gradient)."""
    bt = np.linalg.norm(vector, axis=1)
    c = vector / bt[:, None]
    dc = np.gradient(c, 1.0 / rate_hz, axis=0)
    induced = [bt * c[:, i] * c[:, j] for i in range(3) for j in range(i, 3)]
    eddy = [bt * c[:, i] * dc[:, j] for i in range(3) for j in range(3)]
    return np.column_stack([c, *induced, *eddy])


def zero_phase_ridge(vector, scalar, rate_hz=RATE_HZ, band=BAND_HZ, trim=20):
    """The band-passed residual std of MagNav's fit (filtfilt, trimmed ends), the ridge
    parameter of the scaled columns chosen by GCV over a fine grid. [nT]"""
    sos = signal.butter(4, band, btype="bandpass", fs=rate_hz, output="sos")
    a = signal.sosfiltfilt(sos, reference_design(vector, rate_hz), axis=0)[trim:-trim]
    y = signal.sosfiltfilt(sos, scalar)[trim:-trim]
    scale = np.linalg.norm(a, axis=0)
    u, s, vt = np.linalg.svd(a / scale, full_matrices=False)
    uy = u.T @ y
    n = len(y)
    best = None
    for lam in np.logspace(-14, 2, 321) * s[0] ** 2:
        shrink = s**2 / (s**2 + lam)
        residual = y - u @ (shrink * uy)
        gcv = n * residual @ residual / (n - shrink.sum()) ** 2
        if best is None or gcv < best[0]:
            best = (gcv, residual)
    return float(np.std(best[1]))


def band_passed_noise_std(noise, rate_hz=RATE_HZ, band=BAND_HZ) -> float:
    """What an exact compensation leaves: the noise, band-passed (zero phase). [nT]"""
    sos = signal.butter(4, band, btype="bandpass", fs=rate_hz, output="sos")
    return float(np.std(signal.sosfiltfilt(sos, noise)[20:-20]))


@pytest.mark.parametrize("terms", [18, 16])
def test_the_box_is_compensated_as_well_as_the_zero_phase_reference(box, terms):
    vector, scalar, platform, magnitude = box
    fit = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ, terms=terms)
    reference = zero_phase_ridge(vector, scalar)
    # the done-when criterion: within 5 % of the zero-phase ridge reference
    assert fit.compensated_std == pytest.approx(reference, rel=0.05)
    # and both at the noise: the platform's 4 nT of band-passed field are gone
    noise = band_passed_noise_std(scalar - magnitude - platform)
    assert fit.compensated_std < 1.5 * noise
    assert fit.uncompensated_std > 500 * noise
    assert fit.improvement_ratio == pytest.approx(fit.uncompensated_std / fit.compensated_std)


def test_the_compensated_scalar_is_the_earth_field_plus_noise(box):
    vector, scalar, platform, magnitude = box
    fit = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ)
    left = fit.compensate(vector, scalar) - magnitude
    # at every frequency, not only in the band: 0.01 nT of noise, 7.8 nT of platform field;
    # the few rows at the ends where the derivative is one-sided add a little
    assert np.std(left) < 0.015
    assert np.std(platform) > 500 * np.std(left)
    assert np.mean(fit.compensate(vector, scalar)) == pytest.approx(np.mean(scalar), abs=1e-9)


def test_18_terms_are_not_individually_meaningful_and_it_says_so(box):
    vector, scalar, _, _ = box
    fit = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ)
    assert not fit.coefficients_meaningful
    assert fit.condition_number > 1e3
    assert max(fit.variance_inflation) > 1e6  # cos^2 sum to 1: induced_zz follows the others
    assert "not individually meaningful" in fit.statement
    assert fit.names == nlpcal.platform.terms.term_names(18)
    document = fit.to_dict()
    assert document["coefficients_meaningful"] is False
    assert [c["name"] for c in document["coefficients"]] == fit.names


def test_well_conditioned_terms_are_called_meaningful(box):
    """A channel alone, independent of the attitude: its coefficient means what it says."""
    vector, scalar, _, magnitude = box
    rng = np.random.default_rng(2)
    current = np.convolve(rng.uniform(0, 40, scalar.size), np.ones(10) / 10, mode="same")  # [A]
    recorded = magnitude + 0.05 * current + 0.01 * rng.standard_normal(scalar.size)
    fit = nlpcal.fit_tolles_lawson(
        vector, recorded, rate_hz=RATE_HZ, terms=16, aux=current, aux_names=["current_A"]
    )
    assert fit.names[-1] == "current_A"
    assert fit.coefficient_units[-1] == "nT per unit of current_A"
    # the band-passed current varies by about 2 A against 0.004 nT of band-passed noise over
    # 11 700 rows: a standard error near 2e-5 nT/A, far inside 1 %
    assert fit.coefficients[-1] == pytest.approx(0.05, rel=0.01)
    assert fit.variance_inflation[-1] < 10


def test_one_pass_over_blocks_is_the_causal_filter_over_the_whole_record(box):
    """The carried state: the sums gathered in blocks of 997 rows (threads) equal the causal
    filter run over the whole record at once from the steady state, computed here."""
    vector, scalar, _, _ = box
    small = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ, terms=16, chunk_rows=997)
    whole = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ, terms=16, chunk_rows=10**6)
    # the same sums to rounding; GCV's minimum is flat in lambda, which rounding moves by a few
    # per cent, so the coefficients are compared through what they do: the compensation, to
    # 1 % of the 0.01 nT noise
    assert small.compensated_std == pytest.approx(whole.compensated_std, rel=1e-7)
    left = small.compensate(vector, scalar) - whole.compensate(vector, scalar)
    assert np.abs(left).max() < 1e-4
    # the whole record filtered at once, causally, twice the Butterworth (|H|^2 as filtfilt)
    once = signal.butter(4, BAND_HZ, btype="bandpass", fs=RATE_HZ, output="sos")
    sos = np.vstack([once, once])
    full = reference_design(vector, RATE_HZ)  # 16 terms: without induced zz (8), eddy z dz (17)
    columns = np.column_stack([full[:, [*range(8), *range(9, 17)]], scalar])
    zi = signal.sosfilt_zi(sos)[:, :, None] * columns[0][None, None, :]
    filtered = signal.sosfilt(sos, columns, axis=0, zi=zi)[0][whole.settling_rows :]
    x, y = filtered[:, :-1], filtered[:, -1]
    scale = np.linalg.norm(x, axis=0)
    r = (x / scale).T @ (x / scale)
    beta = np.linalg.solve(r + whole.ridge_parameter * np.eye(16), (x / scale).T @ y) / scale
    np.testing.assert_allclose(whole.coefficients, beta, rtol=1e-6)
    assert whole.compensated_std == pytest.approx(np.std(y - x @ beta), rel=1e-9)


def test_dask_arrays_give_the_fit_of_numpy(box):
    da = pytest.importorskip("dask.array")
    vector, scalar, _, _ = box
    in_memory = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ, terms=16)
    lazy = nlpcal.fit_tolles_lawson(
        da.from_array(vector, chunks=(1500, 3)),
        da.from_array(scalar, chunks=1500),
        rate_hz=RATE_HZ,
        terms=16,
    )
    assert lazy.compensated_std == pytest.approx(in_memory.compensated_std, rel=1e-7)
    left = lazy.compensate(vector, scalar) - in_memory.compensate(vector, scalar)
    assert np.abs(left).max() < 1e-4  # 1 % of the noise (see the test above)
