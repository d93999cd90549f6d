"""Standard errors that follow the dependence of the scores: a small Monte Carlo against the
independent forward model of `synthetic`.

A smooth trajectory (body rates AR(1) with coefficient 0.98, about 0.03 rad per sample) in a field
that changes slowly (50 000 + 30 sin(2 pi 1.5 t / T + phase) nT), no reference, N = 2 000, 5 nT:
the scores of neighbouring samples are alike. The same samples' directions drawn independently:
they are not. The thresholds are binomial: with REPLICAS replicas, a parameter's +/-1.96 SE
interval covering the truth (under the gauge) in fewer than COVERED of them has probability below
1e-3 / 18 when the intervals cover 85 % of the time (the page docs/uncertainty.md measures
0.87-0.95 on this case), and |error| < 1 SE in more than WITHIN_ONE of them below 1e-3 / 18
when that happens 68 % of the time (standard errors as large as the spread): with the 18 checks,
a correct implementation fails less than once in 1 000 runs. The widening by the residuals'
lag-1 autocorrelation it replaces had standard errors 5.8 times too large on the independent
directions (every |error| < 1 SE).
"""

import json

import numpy as np
import pytest

import nlpcal
from synthetic import (
    PAPER_TRUTH,
    gauge_truth,
    make_log,
    scenario_log,
    slow_field,
    smooth_directions,
    tilt_directions,
    uniform_directions,
)

REPLICAS = 30
COVERED = 17  # binom.cdf(16, 30, 0.85) < 1e-3 / 18
WITHIN_ONE = 29  # binom.sf(29, 30, 0.68) < 1e-3 / 18
NAMES = list(PAPER_TRUTH)
#: The pooled mean of z^2 over the replicas' 9 standardised errors is about 1 for standard errors
#: as large as the spread (Student's t widening included); the jackknife on the few groups of a
#: short log gave 0.45 on 24 samples and 0.67 on 100 (standard errors 1.2-2 times too wide).
#: Within a replica the nine errors correlate: the mean scatters by at most sqrt(2 / R) (all
#: nine alike), so Z2_SPREADS of those either side fail less than once in 150 runs even then.
Z2_SPREADS = 2.5


def standardised_errors(directions_of) -> np.ndarray:
    """(REPLICAS, 9): (estimate - truth under the gauge) / standard error."""
    truth = gauge_truth()
    z = []
    for seed in range(REPLICAS):
        rng = np.random.default_rng(7000 + seed)
        n = 2000
        directions = directions_of(n, rng)
        samples = scenario_log(n, 5.0, rng, directions, slow_field(n, rng))
        result = nlpcal.calibrate(samples)
        z.append([(result.parameters[k] - truth[k]) / result.standard_errors[k] for k in NAMES])
    return np.array(z)


@pytest.mark.parametrize("directions_of", [smooth_directions, uniform_directions])
def test_standard_errors_cover_a_smooth_trajectory_in_a_slow_field(directions_of):
    z = np.abs(standardised_errors(directions_of))
    covered = (z < 1.96).sum(axis=0)
    within = (z < 1.0).sum(axis=0)
    assert np.all(covered >= COVERED), dict(zip(NAMES, covered))
    assert np.all(within <= WITHIN_ONE), dict(zip(NAMES, within))
    # pooled: standard errors 1.45 times too small (the old widening on the smooth trajectory)
    # give a mean z^2 of about 2.1, covering ones about 0.65-1
    mean_square = float(np.mean(z**2))
    assert abs(mean_square - 1.0) < Z2_SPREADS * np.sqrt(2 / REPLICAS), mean_square


#: With the bias removed, the mean of REPLICAS standardised errors scatters by 1 / sqrt(30) = 0.18:
#: beyond MEAN_ERROR (4.1 of those) with probability 4e-5 per parameter, 4e-4 for the nine.
MEAN_ERROR = 0.75


@pytest.mark.parametrize("loss", ["l2", "huber"])
def test_the_second_order_bias_of_a_short_arc_is_removed(loss):
    """Heading free, roll and pitch within +/-20 deg, 15 nT, a constant reference: uncorrected,
    z_z is biased by about -1.6 standard errors and the scales by +1.6 (coverage 0.6), with
    least squares and with the huber loss alike."""
    z, covered = [], []
    for seed in range(REPLICAS):
        rng = np.random.default_rng(8000 + seed)
        samples = scenario_log(2000, 15.0, rng, tilt_directions(2000, rng), 50_000.0)
        result = nlpcal.calibrate(samples, reference_field=50_000.0, method="joint", loss=loss)
        bias = result.identifiability["second_order_bias"]
        assert bias["applied"] and result.statistics[-1]["label"] == "bias corrected"
        assert any("second-order bias" in w for w in result.warnings)
        errors = [result.parameters[k] - PAPER_TRUTH[k] for k in NAMES]
        z.append(np.array(errors) / [result.standard_errors[k] for k in NAMES])
        shift = result.parameters["z_z"] - bias["parameters_uncorrected"]["z_z"]
        assert shift == pytest.approx(-bias["bias"]["z_z"])
        covered.append(np.abs(z[-1]) < 1.96)
    mean = np.mean(z, axis=0)
    assert np.all(np.abs(mean) < MEAN_ERROR), dict(zip(NAMES, mean))
    assert np.all(np.sum(covered, axis=0) >= COVERED)


def test_the_jackknife_keeps_enough_groups_on_a_short_or_smooth_log():
    """Scores alike across the whole log ask for groups as long as the log; one group would
    give a variance of zero."""
    from nlpcal import inference

    for blocks in (6, 40, 100, 4096):
        length = inference.group_length(1e9, blocks)
        groups = len(range(0, blocks, length))
        assert groups >= inference.MIN_GROUPS, blocks
    assert inference.group_length(2.0, 4096) == 6  # otherwise GROUP_BANDWIDTHS bandwidths


def test_the_floor_is_below_the_result_in_every_direction():
    from nlpcal import inference

    rng = np.random.default_rng(3)
    basis = np.linalg.qr(rng.standard_normal((9, 8)))[0]
    for _ in range(20):
        a, b = rng.standard_normal((2, 9, 12))
        meat, floor = a @ a.T, b @ b.T
        top = inference.loewner_max(meat, floor, basis)
        for other in (meat, floor):
            gap = basis.T @ (top - other) @ basis
            assert np.linalg.eigvalsh(gap)[0] >= -1e-9 * np.abs(gap).max()


@pytest.mark.parametrize("loss", ["l2", "huber"])
@pytest.mark.parametrize("reference", [None, 50_000.0])
def test_few_samples_get_standard_errors_no_narrower_than_independent_ones(loss, reference):
    """40 samples: the jackknife runs on 8 groups, and by chance its variance can fall below that
    of independent samples (to 0.58 of their standard error, a huber fit, before the floor)."""
    rng = np.random.default_rng(40)
    samples = scenario_log(40, 5.0, rng, uniform_directions(40, rng), 50_000.0)
    result = nlpcal.calibrate(samples, reference_field=reference, loss=loss, method="joint")
    dependence = result.identifiability["score_dependence"]
    assert dependence["groups"] >= 6
    for name, error in result.standard_errors.items():
        assert error >= dependence["standard_errors_independent"][name] * (1 - 1e-9), name


@pytest.mark.parametrize("widening", [1.0, 3.0])
def test_a_bias_is_corrected_only_while_the_residuals_pass_for_white_noise(widening):
    """Residuals alike in neighbours are a misfit the bias formula would take for noise: the
    bias is then stated, not corrected."""
    from nlpcal.calibration import correct_bias
    from nlpcal.calibration.result import Identifiability

    parameters = {"z_x": 10.0, "z_z": 20.0}
    block = {
        "bias": {"z_x": 0.1, "z_z": -3.0},
        "bias_in_standard_errors": {"z_x": 0.05, "z_z": -1.5},
    }
    dependence = {"standard_error_widening": {"z_x": 1.0, "z_z": widening}}
    warnings: list = []
    out = correct_bias(parameters, block, Identifiability(score_dependence=dependence), warnings)
    assert len(warnings) == 1 and "-1.50 standard errors (z_z)" in warnings[0]
    if widening <= 2.0:
        assert block["applied"] and out == {"z_x": 9.9, "z_z": 23.0}
        assert block["parameters_uncorrected"] == parameters
    else:
        assert not block["applied"] and out == parameters and "not_applied" in block


@pytest.mark.parametrize("stated", [True, False])
def test_a_bias_is_stated_when_the_standard_errors_are_not(stated):
    """A staged result above its joint optimum (or a planar log) states no standard errors: the
    bias is then neither corrected nor left without a verdict, and above 0.5 standard errors
    a warning says it."""
    from nlpcal.calibration import correct_bias
    from nlpcal.calibration.result import Identifiability

    parameters = {"z_x": 10.0, "z_z": 20.0}
    block = {
        "bias": {"z_x": 0.1, "z_z": -3.0},
        "bias_in_standard_errors": {"z_x": 0.05, "z_z": -1.5},
    }
    warnings: list = []
    out = correct_bias(parameters, block, Identifiability(), warnings, stated)
    assert len(warnings) == 1 and "(z_z)" in warnings[0]
    assert block["applied"] is stated and (out == parameters) is not stated
    assert ("not_applied" in block) is not stated


def noisy_reference_replica(seed: int):
    """A short arc (roll, pitch within +/-20 deg) with 5 nT of sensor noise and a reference
    series with 15 nT of white noise of its own: the residuals' white variance is mostly the
    reference's, which the bias formula must not take for the sensor's."""
    rng = np.random.default_rng(9300 + seed)
    samples = scenario_log(2000, 5.0, rng, tilt_directions(2000, rng), 50_000.0)
    reference = 50_000.0 + 15.0 * rng.standard_normal(2000)
    return nlpcal.calibrate(samples, reference_field=reference, method="joint")


def test_a_noisy_reference_is_not_taken_for_sensor_noise():
    """Before: noise_std 15.8 nT, the bias corrected in every replica, coverage 0.73-0.80. The
    reference's white noise is told apart from the sensor's (noise_std about 5 nT); what is left
    cannot be corrected on so little, so the standard errors are widened by the bias."""
    z = []
    for seed in range(REPLICAS):
        result = noisy_reference_replica(seed)
        block = result.identifiability["second_order_bias"]
        assert 4.0 < block["noise_std"] < 6.5 and 13.0 < block["reference_noise_std"] < 17.0
        assert not block["applied"] and "not_applied" in block
        z.append(
            [(result.parameters[k] - PAPER_TRUTH[k]) / result.standard_errors[k] for k in NAMES]
        )
    # within 1.96 widened standard errors; binomial as COVERED
    assert np.all((np.abs(np.array(z)) < 1.96).sum(axis=0) >= COVERED)


@pytest.mark.parametrize("directions_of", [uniform_directions, smooth_directions])
def test_a_slowly_changing_field_is_not_taken_for_sensor_noise(directions_of):
    """A +/-30 nT slow field without a reference leaves residuals of about 21 nT: before, all of
    it was taken for sensor noise. Their successive differences see the 5 nT of the sensor."""
    rng = np.random.default_rng(61)
    samples = scenario_log(2000, 5.0, rng, directions_of(2000, rng), slow_field(2000, rng))
    block = nlpcal.calibrate(samples).identifiability["second_order_bias"]
    assert 4.0 < block["noise_std"] < 6.0


@pytest.mark.parametrize("n, replicas", [(24, 60), (100, 30)])
def test_independent_samples_of_a_short_log_get_standard_errors_as_large_as_the_spread(n, replicas):
    """Few independent samples: their scores show no dependence, so the standard errors are
    those of independent samples (s^2 A^-1, widened by Student's t on N - p)."""
    from nlpcal import inference

    z = []
    for seed in range(replicas):
        rng = np.random.default_rng(500 + seed)
        samples = scenario_log(n, 5.0, rng, uniform_directions(n, rng), 50_000.0)
        result = nlpcal.calibrate(samples, reference_field=50_000.0, method="joint")
        dependence = result.identifiability["score_dependence"]
        assert dependence["method"] == "independent"
        widening = dependence["standard_error_widening"]
        t = inference.t_widening(n - 9)
        assert all(v == pytest.approx(t, rel=1e-6) for v in widening.values())
        z.append(
            [(result.parameters[k] - PAPER_TRUTH[k]) / result.standard_errors[k] for k in NAMES]
        )
    mean_square = float(np.mean(np.square(z)))
    assert abs(mean_square - 1.0) < Z2_SPREADS * np.sqrt(2 / replicas), mean_square


def test_the_moving_block_jackknife_of_a_mean_is_by_hand():
    """The estimate a mean of K values (A_k = 1): the jackknife by hand over the K - L + 1
    blocks of L values deleted, normalised as overlapping batch means (Kunsch's 1989 times
    K / (K - L)): unbiased for independent values, which the test below checks."""
    from nlpcal import inference

    rng = np.random.default_rng(5)
    k, length = 40, 6
    series = rng.standard_normal((k, 2))
    series -= series.mean(axis=0)  # the scores at the estimate sum to zero
    shares = np.tile(np.eye(2), (k, 1, 1))
    covariance, dof = inference.moving_block_jackknife(series, shares, length, np.eye(2))
    deltas = np.array([series[j : j + length].sum(axis=0) / (k - length) for j in range(35)])
    centred = deltas - deltas.mean(axis=0)
    expected = (k - length) ** 2 / (k * length * 35) * k / (k - length) * centred.T @ centred
    np.testing.assert_allclose(covariance, expected, rtol=1e-12)
    # alike blocks: Satterthwaite's count is K / L, times 3/2 for overlapping ones, less one
    np.testing.assert_allclose(dof, 1.5 * k / length - 1.0)


def test_the_jackknife_variance_of_independent_samples_is_unbiased_with_long_blocks():
    """A line fitted to 600 independent samples, blocks of 100 deleted: Kunsch's normalisation
    gives 0.77 of the variance of the slope and the intercept (the centring of the deltas
    removes a share L / K of it); the batch means' one about 1. The mean of 300 variances
    scatters by about 8 % (each rests on some 8 degrees of freedom)."""
    from nlpcal import inference

    rng = np.random.default_rng(0)
    k, length = 600, 100
    estimates, variances = [], []
    for _ in range(300):
        design = np.column_stack([rng.standard_normal(k) + 0.5, np.ones(k)])
        noise = rng.standard_normal(k)
        fit = np.linalg.lstsq(design, noise, rcond=None)[0]
        scores = design * (noise - design @ fit)[:, None]
        shares = np.einsum("ni,nj->nij", design, design)
        covariance, _ = inference.moving_block_jackknife(scores, shares, length, np.eye(2))
        estimates.append(fit)
        variances.append(np.diag(covariance))
    ratio = np.mean(variances, axis=0) / np.var(estimates, axis=0)
    assert np.all(np.abs(ratio - 1.0) < 0.15), ratio


def test_the_jackknife_variance_moves_little_when_the_block_length_does():
    """Overlapping blocks: a block longer by one changes the variance by about 1 / L; the
    non-overlapping groups jumped with their count (K // L)."""
    from nlpcal import inference

    rng = np.random.default_rng(6)
    k = 2000
    smooth = np.convolve(rng.standard_normal(k + 99), np.ones(100) / 10, mode="valid")
    series = np.column_stack([smooth, rng.standard_normal(k)])
    series -= series.mean(axis=0)
    shares = np.tile(np.eye(2), (k, 1, 1))
    variances = [
        np.diag(inference.moving_block_jackknife(series, shares, length, np.eye(2))[0])
        for length in range(280, 340)
    ]
    steps = np.abs(np.diff(np.log(variances), axis=0))
    assert steps.max() < 0.02, steps.max()


def test_the_meat_of_independent_samples_leaves_out_the_dependence_within_blocks(monkeypatch):
    """Blocks of several samples: their sums' squares would add the dependence within each
    block (a smooth trajectory: Huber's independent standard errors sqrt(5) too wide on 20 000
    samples). The pass sums psi^2 J J^T over every sample instead."""
    from nlpcal.calibration import scores
    from nlpcal.robust import Loss

    rng = np.random.default_rng(8)
    samples = scenario_log(3000, 5.0, rng, smooth_directions(3000, rng), 50_000.0)
    theta = np.zeros(9)
    theta[0:3] = samples.mean(axis=0)
    options = (theta, None, Loss(), 49_000.0, 49_000.0)
    single = scores.score_block_sums(samples, *options)
    assert single[2] == 1
    np.testing.assert_allclose(single[4], single[0].T @ single[0], rtol=1e-9)
    monkeypatch.setattr(scores, "MAX_BLOCKS", 600)  # blocks of 5 alike samples
    blocks = scores.score_block_sums(samples, *options)
    assert blocks[2] == 5
    np.testing.assert_allclose(blocks[4], single[4], rtol=1e-9)
    summed = blocks[0].T @ blocks[0]
    assert np.trace(summed) > 2 * np.trace(single[4])  # what the old floor took


def test_a_large_widening_for_alike_neighbours_is_a_warning_naming_its_cause():
    """A smooth trajectory in a drifting field: standard errors about ten times those of
    independent samples; the warning names the parameter, the cause and what would help. The
    same field with independent directions says nothing of it."""
    from nlpcal.calibration.diagnostics import DEPENDENCE_WARN

    for directions_of, warned in ((smooth_directions, True), (uniform_directions, False)):
        rng = np.random.default_rng(7000)
        samples = scenario_log(2000, 5.0, rng, directions_of(2000, rng), slow_field(2000, rng))
        result = nlpcal.calibrate(samples)
        widening = result.identifiability["score_dependence"]["standard_error_widening"]
        assert (max(widening.values()) > DEPENDENCE_WARN) == warned
        said = [w for w in result.warnings if "autocorrelated scores" in w]
        assert len(said) == int(warned)
        if warned:
            assert max(widening, key=widening.get) in said[0]
            assert "attitude changes slowly" in said[0] and "What would help" in said[0]


def ar1(n, coefficient, rng) -> np.ndarray:
    """A stationary AR(1) series of unit variance."""
    out = np.empty(n)
    out[0] = rng.standard_normal()
    shocks = np.sqrt(1 - coefficient**2) * rng.standard_normal(n)
    for i in range(1, n):
        out[i] = coefficient * out[i - 1] + shocks[i]
    return out


@pytest.mark.parametrize("regressor_rho", [0.0, 0.95])
def test_least_squares_standard_errors_follow_the_scores_not_the_residuals(regressor_rho):
    """The line fits of drift and compass: y = 2 x + 1 + e with e an AR(1) of coefficient 0.9.
    With independent x the slope's scores x_i e_i are independent and its standard error is
    s^2 (X^T X)^-1's (the residuals' widening sqrt((1 + rho) / (1 - rho)) made it 4.4 times too
    wide, mean z^2 0.05); with x an AR(1) of 0.95 they are alike for about 20 samples and the
    standard error widens about 3 times. The mean of z^2 over REPLICAS * 2 slopes is about 1
    either way (the widening by t adds up to 0.15)."""
    from nlpcal import inference

    rng = np.random.default_rng(21)
    z = []
    for _ in range(REPLICAS * 2):
        n = 2000
        x = ar1(n, regressor_rho, rng)
        y = 2.0 * x + 1.0 + ar1(n, 0.9, rng)
        design = np.column_stack([x, np.ones(n)])
        fit = np.linalg.lstsq(design, y, rcond=None)[0]
        result, _ = inference.least_squares_uncertainty(design, y - design @ fit, n - 2)
        z.append((fit[0] - 2.0) / result.standard_errors[0])
    mean_square = float(np.mean(np.square(z)))
    assert abs(mean_square - 1.0) < Z2_SPREADS * np.sqrt(2 / len(z)) + 0.15, mean_square


@pytest.mark.parametrize("reference", [None, 50_000.0])
def test_the_noise_terms_of_the_bias_are_the_derivatives_of_the_sensitivities(reference):
    """The closed form of the pass (the derivative of J along g = M^T u, the trace of the
    Hessian of |B1|) against central differences of `sensitivities` sample by sample, and the
    block sums against a sum over the samples by hand."""
    from nlpcal.calibration import scores
    from nlpcal.nlp.blocks import variable_scale
    from nlpcal.robust import Loss
    from nlpcal.statistics import correction

    rng = np.random.default_rng(9)
    samples = scenario_log(700, 5.0, rng, uniform_directions(700, rng), 50_000.0)
    theta = np.array([40.0, -25.0, 10.0, 0.01, -0.02, 0.015, 0.02, -0.01, 0.03])
    radius, centre = 50_000.0, 49_990.0
    series, informations, rows, bias, meat = scores.score_block_sums(
        samples, theta, reference, Loss(), centre, radius
    )
    derivatives, scale = scores.entry_derivatives(theta), variable_scale(radius)
    magnitude, jacobian, g = scores.sensitivities(samples, theta, derivatives, scale)
    h = 1e-3  # [field unit]: the derivatives' truncation is (h / |B1|)^2 relative
    ahead = scores.sensitivities(samples + h * g, theta, derivatives, scale)[1]
    behind = scores.sensitivities(samples - h * g, theta, derivatives, scale)[1]
    along = (ahead - behind) / (2 * h)
    matrix = correction(theta)[1]
    squares = np.sum(g * g, axis=1)
    trace = (np.sum(matrix * matrix) - squares) / magnitude
    r = magnitude - (centre if reference is None else reference)
    if reference is None:  # the centre profiled out: J - mean J
        jacobian = jacobian - jacobian.mean(axis=0)
    expected = along.sum(axis=0) + 0.5 * (trace[:, None] * jacobian).sum(axis=0)
    np.testing.assert_allclose(bias["gradient"], expected, rtol=1e-6, atol=1e-9)
    assert bias["mean_square_g"] == pytest.approx(np.mean(squares), rel=1e-12)
    assert rows == 1  # 700 samples: blocks of one
    np.testing.assert_allclose(series, r[:, None] * jacobian, rtol=1e-9, atol=1e-9)
    outer = jacobian[:, :, None] * jacobian[:, None, :]
    np.testing.assert_allclose(informations, outer, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(meat, (r[:, None, None] ** 2 * outer).sum(axis=0), rtol=1e-9)


@pytest.mark.parametrize("reference", [None, 50_000.0])
def test_a_robust_pass_in_blocks_sums_the_scores_of_its_samples(reference, monkeypatch):
    """Blocks of several samples (one batched product per chunk, the noise rows in it) and a
    robust loss (psi' in the sums): the block sums of the scores and of the information, the
    noise terms and the meat against sums over the samples of `sensitivities` by hand."""
    from nlpcal.calibration import scores
    from nlpcal.nlp.blocks import variable_scale
    from nlpcal.robust import Loss
    from nlpcal.statistics import correction

    rng = np.random.default_rng(10)
    samples = scenario_log(700, 5.0, rng, uniform_directions(700, rng), 50_000.0)
    theta = np.array([40.0, -25.0, 10.0, 0.01, -0.02, 0.015, 0.02, -0.01, 0.03])
    radius, centre, loss = 50_000.0, 49_990.0, Loss("huber", 6.0)
    monkeypatch.setattr(scores, "MAX_BLOCKS", 90)  # blocks of 8 samples
    series, informations, rows, bias, meat = scores.score_block_sums(
        samples, theta, reference, loss, centre, radius, chunk_rows=100
    )
    derivatives, scale = scores.entry_derivatives(theta), variable_scale(radius)
    magnitude, jacobian, g = scores.sensitivities(samples, theta, derivatives, scale)
    h = 1e-3  # [field unit]
    ahead = scores.sensitivities(samples + h * g, theta, derivatives, scale)[1]
    behind = scores.sensitivities(samples - h * g, theta, derivatives, scale)[1]
    r = magnitude - (centre if reference is None else reference)
    psi, slope = loss.weight(r) * r, loss.slope(r)
    assert 0 < slope.sum() < len(r)  # some samples beyond the scale
    if reference is None:  # the centre profiled out: J - the psi'-weighted mean of J
        jacobian = jacobian - slope @ jacobian / slope.sum()
    matrix = correction(theta)[1]
    squares = np.sum(g * g, axis=1)
    trace = (np.sum(matrix * matrix) - squares) / magnitude
    along = slope @ ((ahead - behind) / (2 * h))
    expected = along + 0.5 * (slope * trace) @ jacobian
    np.testing.assert_allclose(bias["gradient"], expected, rtol=1e-6, atol=1e-9)
    assert bias["mean_square_g"] == pytest.approx(np.mean(squares), rel=1e-12)
    assert rows == 8
    starts = np.arange(0, len(r), rows)
    np.testing.assert_allclose(series, np.add.reduceat(psi[:, None] * jacobian, starts), rtol=1e-9)
    outer = jacobian[:, :, None] * jacobian[:, None, :]
    shares = np.add.reduceat(slope[:, None, None] * outer, starts)
    np.testing.assert_allclose(informations, shares, rtol=1e-9, atol=1e-12 * np.abs(shares).max())
    np.testing.assert_allclose(meat, (psi[:, None, None] ** 2 * outer).sum(axis=0), rtol=1e-9)


def test_zero_residuals_have_no_bias_in_standard_errors():
    """A reference equal to the measured |B_M|: every residual zero, every standard error zero,
    and the second-order bias zero in them too (it was 0/0, NaN, which no result may hold)."""
    samples, _ = make_log(n=3_000, noise=1.0, seed=6)
    reference = np.sqrt((samples**2).sum(axis=1))  # |B_M| to its last bit, as nlpcal takes it
    result = nlpcal.calibrate(samples, reference_field=reference)
    assert set(result.standard_errors.values()) == {0.0}
    bias = result.identifiability["second_order_bias"]["bias_in_standard_errors"]
    assert all(value == 0.0 for value in bias.values()), bias
    json.dumps(result.to_dict(), allow_nan=False)
