"""nlpcal.calibrate: truth recovery, reference modes, the gauge, Table 1 rows and bad input."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

import nlpcal
from nlpcal import CalibrationResult, calibrate
from nlpcal.calibration.coverage import PLANAR_NOISE, bin_hits, direction_bins, flatness
from nlpcal.errors import InputError, QualityError, SolveError
from nlpcal.moments import Frame
from nlpcal.nlp import steps
from nlpcal.nlp.solver import SolveOutcome
from resolution import assert_same_optimum
from synthetic import (
    PAPER_FIELD,
    PAPER_TRUTH,
    band_directions,
    circle_directions,
    make_log,
    planar_directions,
)

OFFSETS = ("z_x", "z_y", "z_z")
SCALES = ("s_x", "s_y", "s_z")
ANGLES = ("alpha_deg", "beta_deg", "gamma_deg")


@pytest.fixture(scope="module")
def noisy():
    # The acceptance set: 2 500 uniform attitudes, 2.5 nT noise per axis.
    samples, _ = make_log(n=2500, noise=2.5, seed=21)
    return samples


def _ratios(params):
    g = np.array([1 + params[k] for k in SCALES])
    return g / g[0]


def assert_recovered(params, *, absolute_scale, offset_tol=0.5, scale_tol=2e-5, angle_tol=1e-3):
    for k in OFFSETS:
        assert abs(params[k] - PAPER_TRUTH[k]) < offset_tol, k
    if absolute_scale:
        for k in SCALES:
            assert abs(params[k] - PAPER_TRUTH[k]) < scale_tol, k
    else:
        np.testing.assert_allclose(_ratios(params), _ratios(PAPER_TRUTH), rtol=0, atol=scale_tol)
    for k in ANGLES:
        assert abs(params[k] - PAPER_TRUTH[k]) < angle_tol, k


# Tolerances of the issue: offsets 0.5 nT, scales 2e-5, angles 0.001 deg. The standard errors at
# this noise are about 0.09 nT, 2.5e-6 and 2.3e-4 deg, so the tolerances are 4-6 sigma.
@pytest.mark.parametrize("method", ["staged", "joint"])
@pytest.mark.parametrize("with_reference", [False, True])
def test_recovers_the_truth_from_noisy_data(noisy, method, with_reference):
    result = calibrate(
        noisy, method=method, reference_field=PAPER_FIELD if with_reference else None
    )
    assert_recovered(result.parameters, absolute_scale=with_reference)
    assert result.solver.success
    # The truth lies within four standard errors of the estimate.
    for k in OFFSETS + ANGLES:
        assert abs(result.parameters[k] - PAPER_TRUTH[k]) < 4 * result.standard_errors[k], k


# Noise-free data: a solve stops once the spread is at the resolution of the float64 moments
# (PRECISION_FLOOR: a spread of 1e-8 L, about 5e-4 nT here). Where it ends below that, joint or
# staged, depends on the rounding of the moments (CPU, BLAS kernel, numpy version): the
# parameters are as good as those of a log with that much noise, whose standard errors at 600
# samples are about 4e-5 nT, 1e-9 and 1e-7 deg (the noisy set's above, scaled by the noise and
# by sqrt(N)). The tolerances are 10-27 of them, for either method.
@pytest.mark.parametrize("method", ["staged", "joint"])
def test_noise_free_data_are_recovered_to_the_resolution_of_the_moments(method):
    samples, _ = make_log(n=600, noise=0.0, seed=2)
    result = calibrate(samples, method=method, reference_field=PAPER_FIELD, rtol=1e-14)
    assert_recovered(
        result.parameters,
        absolute_scale=True,
        offset_tol=1e-3,
        scale_tol=1e-8,
        angle_tol=1e-6,
    )
    assert result.statistics[-1]["std"] < 1e-3


def test_staged_equals_joint_at_convergence(noisy):
    staged = calibrate(noisy, method="staged", rtol=1e-13, cycles=200)
    joint = calibrate(noisy, method="joint")
    assert_same_optimum(staged.parameters, joint.parameters, joint.standard_errors)


def test_reference_series_identifies_all_nine():
    # The field drifts by +-60 nT during the log; a proton magnetometer samples it.
    n = 2500
    rng = np.random.default_rng(9)
    field = PAPER_FIELD + 60 * np.sin(np.linspace(0, 2 * np.pi, n)) + rng.normal(0, 0.2, n)
    samples, _ = make_log(n=n, noise=2.5, seed=22, field=field[:, None])
    for method in ("staged", "joint"):
        result = calibrate(samples, method=method, reference_field=field)
        assert_recovered(result.parameters, absolute_scale=True)
        assert result.reference.mode == "series"
    # Ignoring the drift (a constant reference) leaves a visibly worse fit.
    constant = calibrate(samples, method="joint", reference_field=float(field.mean()))
    assert constant.statistics[-1]["objective"] > 100 * result.statistics[-1]["objective"]


def test_gauge_without_reference(noisy):
    result = calibrate(noisy, method="joint")
    assert sum(result.parameters[k] for k in SCALES) == pytest.approx(0.0, abs=1e-12)
    assert result.gauge["constraint"] == "s_x + s_y + s_z = 0"
    assert result.reference.to_dict() == {"mode": "none"}
    # a note on the method, not a warning about the data
    assert any("no reference field" in n for n in result.notes)
    assert not any("reference field" in w for w in result.warnings)
    with_ref = calibrate(noisy, method="joint", reference_field=PAPER_FIELD)
    assert with_ref.gauge is None and with_ref.notes == []


def test_table1_rows(noisy):
    result = calibrate(noisy, method="staged", cycles=4, rtol=0.0)
    labels = [row["label"] for row in result.statistics]
    assert labels == ["measured", "cycle 1", "cycle 2", "cycle 3", "cycle 4"]
    magnitude = np.linalg.norm(result.apply(noisy), axis=1)
    last = result.statistics[-1]
    assert last["max"] == pytest.approx(magnitude.max(), rel=1e-12)
    assert last["min"] == pytest.approx(magnitude.min(), rel=1e-12)
    assert last["mean"] == pytest.approx(magnitude.mean(), rel=1e-12)
    assert last["std"] == pytest.approx(magnitude.std(ddof=0), rel=1e-9)
    assert last["range"] == pytest.approx(np.ptp(magnitude), rel=1e-12)
    measured = np.linalg.norm(noisy, axis=1)
    assert result.statistics[0]["std"] == pytest.approx(measured.std(), rel=1e-9)
    stds = [row["std"] for row in result.statistics]
    assert all(b <= a * (1 + 1e-12) for a, b in zip(stds, stds[1:]))  # never increases
    assert any("maximum of 4 cycles" in w for w in result.warnings)
    joint = calibrate(noisy, method="joint")
    assert [row["label"] for row in joint.statistics] == ["measured", "joint"]


def test_stop_rules(noisy):
    by_target = calibrate(noisy, target_std=100.0)
    assert by_target.solver.stop_reason == "target_std"
    assert len(by_target.statistics) == 2
    by_range = calibrate(noisy, target_range=1e5)
    assert by_range.solver.stop_reason == "target_range"
    converged = calibrate(noisy, rtol=1e-6)
    assert converged.solver.stop_reason == "rtol"


def test_array_likes_give_the_same_answer(noisy):
    small = noisy[:400]
    from_array = calibrate(small, method="joint")
    from_list = calibrate(small.tolist(), method="joint").parameters
    from_frame = calibrate(pd.DataFrame(small, columns=["bx", "by", "bz"]), method="joint")
    for other in (from_list, from_frame.parameters):  # memory layout changes summation order
        assert_same_optimum(other, from_array.parameters, from_array.standard_errors)


def test_json_round_trip(noisy, tmp_path):
    result = calibrate(noisy[:500], method="joint", reference_field=PAPER_FIELD)
    again = CalibrationResult.from_json(result.to_json())
    assert again.parameters == result.parameters
    assert again.statistics == result.statistics
    np.testing.assert_array_equal(again.apply(noisy[:5]), result.apply(noisy[:5]))
    result.save(tmp_path / "p.json")
    assert CalibrationResult.load(tmp_path / "p.json").to_dict() == result.to_dict()
    doc = result.to_dict()
    assert doc["format_version"] == 2 and doc["nlpcal_version"] == nlpcal.__version__
    with pytest.raises(InputError):
        CalibrationResult.from_dict({"format_version": 3, "parameters": doc["parameters"]})
    with pytest.raises(InputError):
        CalibrationResult.from_dict({"format_version": 1, "parameters": {"z_x": 0}})


@pytest.mark.parametrize("method", ["staged", "joint"])
def test_rotation_about_one_axis_is_reported_as_not_identifiable(method):
    # Field directions in the sensor's x-y plane only: the z axis never sees the field, so its
    # offset, its scale and the angles that mix it in are not determined. Either the solve ends
    # and flags them, or IPOPT wanders along the null directions and the failure names them.
    rng = np.random.default_rng(4)
    samples, _ = make_log(n=800, noise=1.0, seed=5, directions=planar_directions(800, rng))
    try:
        result = calibrate(samples, method=method, reference_field=PAPER_FIELD)
    except SolveError as failure:
        named = set(failure.identifiability["not_identifiable"])
    else:
        named = set(result.identifiability["not_identifiable"])
        assert any("not identifiable" in w for w in result.warnings)
    assert named & {"z_z", "s_z", "alpha_deg", "beta_deg"}


@pytest.mark.parametrize("method", ["staged", "joint"])
@pytest.mark.parametrize("reference", [None, PAPER_FIELD])
@pytest.mark.parametrize(
    ("axis", "half_angle", "noise"),
    [((0, 0, 1), 90, 1.0), ((1, 2, 2), 60, 1.0), ((1, 2, 2), 60, 0.0)],
)
def test_turns_about_one_axis_never_give_a_result(method, reference, axis, half_angle, noise):
    # One circle of field directions, and so a planar ellipse of samples: a family of ellipsoids
    # passes through it. Without a reference the joint optimum even scales the blind axis towards
    # zero with a healthy-looking Hessian; the flatness of the samples is what tells.
    rng = np.random.default_rng(8)
    samples, _ = make_log(
        n=1200, noise=noise, seed=9, directions=circle_directions(1200, rng, axis, half_angle)
    )
    # Refused either way: after the solve (QualityError), or when a solve that wandered along
    # the blind directions failed (SolveError; which problem fails first depends on rounding).
    # Either refusal says the samples lie in one plane, within the noise (noise-free samples: a
    # thickness at rounding level, on every BLAS kernel), and names the blind parameters.
    with pytest.raises((QualityError, SolveError)) as info:
        calibrate(samples, method=method, reference_field=reference)
    identifiability = info.value.identifiability
    flat = identifiability["flatness"]
    assert flat["planar"] and flat["within_noise"]
    unit_axis = np.asarray(axis) / np.linalg.norm(axis)
    assert abs(np.dot(flat["normal"], unit_axis)) == pytest.approx(1.0, abs=1e-3)  # 2.6 deg
    assert {"z_z", "s_z"} <= set(flat["parameters"]) <= set(identifiability["not_identifiable"])
    assert "tilting it out of that plane" in str(info.value)


@pytest.mark.parametrize("tilt_deg", [1.0, 2.0])
def test_a_few_degrees_of_tilt_are_not_a_result_either(tilt_deg):
    # Turns about z with tilts of a degree or two: the Hessian is just regular, but the estimates
    # of the z parameters lie many standard errors from the truth (bias, not noise).
    rng = np.random.default_rng(8)
    samples, _ = make_log(
        n=3000, noise=2.5, seed=9, directions=band_directions(3000, rng, tilt_deg)
    )
    with pytest.raises(QualityError) as info:
        calibrate(samples, method="joint")
    assert "lie nearly in one plane" in str(info.value)
    flat = info.value.result.identifiability["flatness"]
    assert flat["planar"] and not flat["within_noise"]
    assert {"s_z", "alpha_deg", "beta_deg"} <= set(flat["parameters"])
    kept = calibrate(samples, method="joint", require_identifiable=False)
    assert kept.standard_errors is None and kept.covariance is None  # none that would hold
    # a known field magnitude holds the blind axis: the result and its standard errors stand,
    # unless the Hessian's own rule finds a direction the data do not determine
    try:
        held = calibrate(samples, method="joint", reference_field=PAPER_FIELD)
    except QualityError as failure:
        assert "plane" not in failure.reason and tilt_deg < 2.0
    else:
        assert not held.identifiability["flatness"]["planar"]
        for name in ("alpha_deg", "beta_deg"):
            gap = abs(held.parameters[name] - PAPER_TRUTH[name]) / held.standard_errors[name]
            assert gap < 4.0, (name, gap)


def test_a_noisy_full_sphere_is_never_taken_for_a_plane():
    samples, _ = make_log(n=3000, noise=0.12 * PAPER_FIELD, seed=9)
    flat = flatness(samples, noise=0.12 * PAPER_FIELD)
    assert not flat["planar"] and flat["out_of_plane_std"] > 0.5 * flat["in_plane_std"]


@pytest.mark.parametrize("rounding", [0.0, 1e-8, 1e-7])
def test_a_plane_to_rounding_is_a_plane_whatever_noise_it_is_judged_against(rounding):
    # Noise-free samples on one circle: their thickness is rounding (0 on one BLAS kernel, 1e-8
    # of the extent on another), as is their noise. Rounding against rounding decides nothing:
    # the cloud is planar, even judged against a noise level far below its thickness.
    rng = np.random.default_rng(8)
    samples, _ = make_log(
        n=1200, noise=0.0, seed=9, directions=circle_directions(1200, rng, (1, 2, 2), 60)
    )
    normal = flatness(samples, noise=1.0)["normal"]
    extent = flatness(samples, noise=1.0)["in_plane_std"]
    wobble = rounding * extent * np.sqrt(2.0) * np.sin(np.arange(len(samples)))  # std: rounding
    flat = flatness(samples + np.outer(wobble, normal), noise=1e-12, reference=True)
    assert flat["planar"] and flat["within_noise"], flat["out_of_plane_std"] / extent
    assert {"z_z", "s_z"} <= set(flat["parameters"])


def test_a_narrow_band_of_tilts_is_not_taken_for_a_plane():
    rng = np.random.default_rng(8)
    samples, _ = make_log(n=3000, noise=1.0, seed=9, directions=band_directions(3000, rng, 20))
    result = calibrate(samples, method="joint", reference_field=PAPER_FIELD)
    flat = result.identifiability["flatness"]
    assert not flat["planar"] and flat["parameters"] == []
    assert flat["out_of_plane_std"] > 1000 * PLANAR_NOISE  # nT: the tilts, not the noise


def test_uniform_coverage_is_reported_as_identifiable(noisy):
    result = calibrate(noisy, method="joint", reference_field=PAPER_FIELD)
    assert result.identifiability["not_identifiable"] == []
    assert result.identifiability["poorly_determined"] == []
    assert result.identifiability["coverage"]["covered"] == 26
    assert not any("coverage" in w for w in result.warnings)


def test_each_vector_falls_in_the_bin_of_its_nearest_direction():
    # bin_hits finds the nearest of the 26 directions without their cosines: against the
    # cosines themselves (the largest one's bin), on vectors of every scale and a few
    # components near zero; on the bin directions and their multiples; and no bin for a vector
    # that has no direction
    names, directions = direction_bins()
    rng = np.random.default_rng(21)
    vectors = rng.standard_normal((30000, 3)) * np.exp(rng.uniform(-30, 30, (30000, 1)))
    vectors[::7, 1] *= 1e-9
    cosines = vectors @ directions.T
    expected = np.bincount(np.argmax(cosines, axis=1), minlength=26)
    assert np.array_equal(bin_hits(vectors), expected)
    on_bins = np.concatenate([directions * k for k in (1e-300, 1.0, 2.0, 6e4)])
    assert np.array_equal(bin_hits(on_bins), np.full(26, 4))
    lattice = (
        np.array([v for v in np.ndindex(5, 5, 5) if v != (2, 2, 2)], dtype=float) - 2.0
    )  # integer vectors, many on the bins' boundaries of sign
    expected = np.bincount(np.argmax(lattice @ directions.T, axis=1), minlength=26)
    assert np.array_equal(bin_hits(lattice), expected)
    nothing = np.array([[0.0, 0.0, 0.0], [np.nan, 1.0, 0.0], [np.inf, 0.0, 0.0]])
    assert bin_hits(nothing).sum() == 0
    assert len(names) == 26 and names[bin_hits([[0.0, 0.0, -5.0]]).argmax()] == "-z"


def test_a_cap_of_directions_is_reported_as_poor_coverage():
    # Field directions within 40 deg of the sensor's +z axis: a cap, as on a vehicle.
    rng = np.random.default_rng(8)
    v = rng.standard_normal((3000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    cap = v[v[:, 2] > np.cos(np.radians(40))][:1500]
    samples, _ = make_log(n=len(cap), noise=1.0, seed=9, directions=cap)
    try:
        result = calibrate(samples, method="joint", reference_field=PAPER_FIELD)
    except SolveError as failure:  # IPOPT may wander along the weak directions
        assert "rotate the sensor through more attitudes" in str(failure)
    else:
        assert result.identifiability["coverage"]["covered"] < 13
        assert any("poor attitude coverage" in w for w in result.warnings)


@pytest.mark.parametrize(
    "bad, message",
    [
        (np.zeros((5, 3)) + np.arange(3), "need at least 10"),
        (np.ones((50, 3)), "all samples are equal"),
        (np.full((50, 2), 1.0), "shape (N, 3)"),
        (np.where(np.eye(50, 3) > 0, np.nan, 1.0) + np.arange(150).reshape(50, 3), "NaN"),
        ([["a", "b", "c"]] * 20, "numeric"),
    ],
)
def test_bad_samples(bad, message):
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        calibrate(bad)


def test_bad_options(noisy):
    with pytest.raises(InputError, match="unknown method"):
        calibrate(noisy, method="cg")
    with pytest.raises(InputError, match="positive"):
        calibrate(noisy, reference_field=-5.0)
    with pytest.raises(InputError, match="non-positive"):
        calibrate(noisy, reference_field=np.r_[np.full(len(noisy) - 1, 5e4), 0.0])
    with pytest.raises(InputError, match="values for"):
        calibrate(noisy, reference_field=np.full(10, 5e4))
    with pytest.raises(InputError, match="cycles"):
        calibrate(noisy, cycles=0)
    with pytest.raises(InputError, match="target_std"):
        calibrate(noisy, target_std=-1.0)
    with pytest.raises(InputError, match="target_range"):
        calibrate(noisy, target_range=float("nan"))
    with pytest.raises(InputError, match="rtol"):
        calibrate(noisy, rtol=float("nan"))


def test_ipopt_failure_is_surfaced(noisy, monkeypatch):
    from nlpcal.nlp import steps as problems
    from nlpcal.nlp.solver import SolveOutcome

    def failing(*args, **kwargs):
        return SolveOutcome(
            x=np.zeros(len(kwargs["x0"])),
            f=1.0,
            status="Maximum_Iterations_Exceeded",
            success=False,
            iterations=200,
        )

    monkeypatch.setattr(problems, "solve", failing)
    with pytest.raises(SolveError) as info:
        calibrate(noisy[:200], method="staged")
    assert info.value.status == "Maximum_Iterations_Exceeded"
    # The joint solve from the sphere fit (the algebraic fit can be the optimum already, and is
    # then not handed to IPOPT).
    monkeypatch.setattr("nlpcal.calibration.joint.algebraic_start", lambda moments: None)
    with pytest.raises(SolveError) as info:
        calibrate(noisy[:200], method="joint")
    assert info.value.status == "Maximum_Iterations_Exceeded"


def test_unidentifiable_results_fail_the_quality_check_but_can_be_inspected():
    # The sensor turned about its z axis only, with a reference field: z never sees the field.
    rng = np.random.default_rng(11)
    samples, _ = make_log(n=800, noise=1.0, seed=12, directions=planar_directions(800, rng))
    for method in ("staged", "joint"):
        try:
            calibrate(samples, method=method, reference_field=PAPER_FIELD)
        except QualityError as failure:
            assert failure.status == "Not_Identifiable"
            assert failure.result.identifiability["not_identifiable"]
            assert "do not determine" in str(failure)
        except SolveError as failure:  # IPOPT wandered along the free direction instead
            assert "rotate the sensor through more attitudes" in str(failure)
        else:
            pytest.fail("an unidentifiable calibration passed the quality check")


def test_a_constant_axis_is_bad_input():
    samples, _ = make_log(n=300, noise=1.0, seed=13)
    samples[:, 2] = 116.29
    with pytest.raises(InputError, match="z column is constant"):
        calibrate(samples)


def test_a_stage_that_ends_below_the_precision_floor_is_solved(monkeypatch):
    # Root cause of a staged noise-free failure seen on some BLAS kernels (OPENBLAS_CORETYPE=
    # Haswell or Zen): a stage that starts just above PRECISION_FLOOR and ends below it cannot
    # meet IPOPT's tolerance (the gradient there is rounding noise) and IPOPT may run out of
    # iterations. Such a stage is solved to the resolution of the data, not failed.
    from nlpcal.moments import accumulate

    samples, _ = make_log(n=600, noise=0.0, seed=2)
    moments = accumulate(samples, PAPER_FIELD)
    floor = steps.PRECISION_FLOOR * moments.length**2
    truth = np.concatenate(
        [
            [PAPER_TRUTH[f"z_{a}"] for a in "xyz"],
            [PAPER_TRUTH[f"s_{a}"] for a in "xyz"],
            np.radians([PAPER_TRUTH[k] for k in ANGLES]),
        ]
    )
    start = truth + np.r_[0, 0, 0, 3e-8, 0, 0, 0, 0, 0]  # a scale error of 3e-8 above the floor

    answer = np.array([-3e-5, 0.0, 0.0])  # the truth, in the scale block's scaled variables

    def run_out_of_iterations(solver, **kwargs):
        # IPOPT's answer in the failing case: `answer`, but Maximum_Iterations_Exceeded
        return SolveOutcome(
            x=answer,
            f=1e-3,
            status="Maximum_Iterations_Exceeded",
            success=False,
            iterations=200,
        )

    monkeypatch.setattr(steps, "solve", run_out_of_iterations)
    step = steps.block_step(moments, "scale", start)
    assert step.f_start > floor and step.f_end <= floor
    assert step.status == "At_Precision_Floor"
    # Above the floor a failed answer stands only where Newton steps finish it; one they cannot
    # (a scale 5e-3 off, five times the longest finishing step) is a failure. Nearer answers
    # are not asserted here: on noise-free data whether a Newton step lands within the
    # resolution of a zero objective is decided by rounding.
    answer = np.array([5.0, 0.0, 0.0])
    with pytest.raises(SolveError) as failed:
        steps.block_step(moments, "scale", truth + np.r_[0, 0, 0, 1e-5, 0, 0, 0, 0, 0])
    assert failed.value.status == "Maximum_Iterations_Exceeded"


@pytest.mark.parametrize("noise", [0.01, 0.02, 0.05, 0.2])
@pytest.mark.parametrize("with_reference", [False, True])
def test_low_noise_logs_calibrate_with_the_staged_cycle(noise, with_reference):
    # A fluxgate's 0.01-0.2 nT in 49 500 nT: the moment objective rounds at 1e-7 to 1e-5 of
    # itself near the optimum. With IPOPT's tolerance below that noise the staged cycle failed
    # on 33 of 50 such simulated logs (IPOPT lost in its line search); the cycle has to reach
    # the joint optimum (the quality check).
    reference = {"reference_field": PAPER_FIELD} if with_reference else {}
    for seed in range(3):
        samples, _ = make_log(n=2000, noise=noise, seed=seed)
        staged = calibrate(samples, method="staged", **reference)
        joint = calibrate(samples, method="joint", **reference)
        gap = staged.identifiability["joint_gap"]["max_gap_in_standard_errors"]
        assert gap < 0.2
        for k, se in joint.standard_errors.items():
            assert abs(staged.parameters[k] - joint.parameters[k]) < 0.2 * se, k


@pytest.mark.parametrize(
    "status", ["Search_Direction_Becomes_Too_Small", "Error_In_Step_Computation"]
)
def test_ipopt_giving_up_where_newton_steps_reach_the_resolution_is_solved(status, monkeypatch):
    # IPOPT stopping in the rounding noise of a low-noise log, whatever its reason: its last
    # point is solved when Newton steps from it reach a hundredth of a standard error. From a
    # point they cannot finish (here, the start of the first stage) it is a failure.
    from nlpcal.moments import accumulate

    samples, _ = make_log(n=2000, noise=0.01, seed=1)
    moments = accumulate(samples, None)
    real_solve = steps.solve

    def gave_up(solver, **kwargs):  # IPOPT's own answer, reported as a failure
        return replace(real_solve(solver, **kwargs), status=status, success=False)

    monkeypatch.setattr(steps, "solve", gave_up)
    step = steps.block_step(moments, "orthogonal", np.zeros(9))
    assert step.status == "At_Data_Resolution" and step.f_end < step.f_start
    solved = steps.block_step(moments, "orthogonal", step.theta)  # already at its optimum
    assert solved.status == "At_Stationary_Point"
    np.testing.assert_allclose(solved.theta, step.theta, rtol=0, atol=1e-9)

    def gave_up_at_the_start(solver, **kwargs):
        return replace(real_solve(solver, **kwargs), x=kwargs["x0"], status=status, success=False)

    monkeypatch.setattr(steps, "solve", gave_up_at_the_start)
    with pytest.raises(SolveError) as info:
        steps.block_step(moments, "orthogonal", np.zeros(9))
    assert info.value.status == status


@pytest.mark.parametrize("block", ["orthogonal", "scale", "offset"])
def test_ipopt_starts_from_the_newton_step_of_the_start(block, monkeypatch):
    # A stage that starts off its optimum, by less than a finishing step (0.45 of the scaled
    # variables: 22 nT for an offset, 4.5e-4 for a scale, 0.26 deg for an angle): IPOPT starts
    # where the start's Newton step lands, and ends where it ends from the start itself.
    from nlpcal.moments import accumulate

    samples, _ = make_log(n=2000, noise=1.0, seed=3)
    moments = accumulate(samples, None)
    start = steps.block_step(moments, "joint", np.zeros(9)).theta
    free = list(nlpcal.nlp.blocks.BLOCKS[block])
    start[free] += (
        0.45 * np.array([1.0, -1.0, 0.5]) * steps.variable_scale(moments.frame.radius)[free]
    )
    real_solve = steps.solve
    starts = []

    def recorded(solver, **kwargs):
        starts.append(kwargs["x0"])
        return real_solve(solver, **kwargs)

    monkeypatch.setattr(steps, "solve", recorded)
    warm = steps.block_step(moments, block, start)
    assert len(starts) == 1 and np.any(starts[0])

    def from_the_start(solver, **kwargs):
        return real_solve(solver, **{**kwargs, "x0": np.zeros_like(kwargs["x0"])})

    monkeypatch.setattr(steps, "solve", from_the_start)
    cold = steps.block_step(moments, block, start)
    assert cold.iterations > warm.iterations
    np.testing.assert_allclose(warm.theta, cold.theta, rtol=0, atol=1e-9 * moments.length)


def test_a_negative_objective_is_a_failure_not_a_floor(monkeypatch):
    # Turns about one axis with 0.01 nT of noise, in the frame of the least-squares sphere through
    # their circle (136 times the field away; `sphere_frame` takes the samples' mean for a log in
    # one plane): the staged cycle leaves the region where the moment series holds and the
    # objective, a variance, goes negative.
    rng = np.random.default_rng(5)
    samples, _ = make_log(n=2000, noise=0.01, seed=5, directions=planar_directions(2000, rng))
    unit = samples / PAPER_FIELD
    design = np.column_stack([2.0 * unit, np.ones(len(unit))])
    fit, *_ = np.linalg.lstsq(design, np.einsum("ij,ij->i", unit, unit), rcond=None)
    far = Frame(fit[:3] * PAPER_FIELD, float(np.sqrt(fit[3] + fit[:3] @ fit[:3])) * PAPER_FIELD)
    for where in ("nlpcal.moments", "nlpcal.calibration.steps"):
        monkeypatch.setattr(f"{where}.sphere_frame", lambda *args, **kwargs: far)
    with pytest.raises(SolveError) as info:
        calibrate(samples, method="staged")
    assert info.value.status == "Negative_Objective"
    assert "went negative" in str(info.value) and "one plane" in str(info.value)


def test_a_failure_blames_the_coverage_only_when_it_is_to_blame(noisy, monkeypatch):
    def failing(*args, **kwargs):
        return SolveOutcome(
            x=np.zeros(len(kwargs["x0"])),
            f=2.0,
            status="Restoration_Failed",
            success=False,
            iterations=3,
        )

    monkeypatch.setattr(steps, "solve", failing)
    monkeypatch.setattr("nlpcal.calibration.joint.algebraic_start", lambda moments: None)
    with pytest.raises(SolveError) as info:
        calibrate(noisy, method="joint")
    assert "rotate the sensor" not in str(info.value)
    assert "coverage is not the likely cause; try --method staged" in str(info.value)


@pytest.mark.parametrize("reference", [None, PAPER_FIELD])
def test_cycle_rows_from_the_moments_agree_with_passes_over_the_data(reference):
    from nlpcal.calibration.problem import Problem
    from nlpcal.calibration.staged import StopRule, run_staged
    from nlpcal.moments import accumulate
    from nlpcal.simulation import simulate

    samples = simulate(3000, attitudes="turntable", noise=1.0, seed=4).to_numpy()
    rows = {}
    for exact in (True, False):
        problem = Problem(samples, reference, accumulate(samples, reference))
        rows[exact] = run_staged(problem, StopRule(max_cycles=8, rtol=0, every_row_exact=exact))[1]
    for exact_row, moment_row in zip(rows[True][2:-1], rows[False][2:-1]):
        assert moment_row.from_moments and moment_row.max is None and "max" not in moment_row
        assert moment_row["mean"] == pytest.approx(exact_row["mean"], abs=1e-3)  # nT
        assert moment_row["std"] == pytest.approx(exact_row["std"], rel=1e-6)
        assert moment_row["objective"] == pytest.approx(exact_row["objective"], rel=1e-6)
    for table in rows.values():  # the first and the last cycle are passes over the data
        assert table[1].max is not None and table[-1].max is not None
    assert rows[False][-1]["std"] == pytest.approx(rows[True][-1]["std"], rel=1e-9)


# A MEMS-like sensor: offsets larger than the field, scale errors of several per cent.
MEMS_TRUTH = {
    "z_x": 61_000.0,
    "z_y": -23_000.0,
    "z_z": 8_000.0,
    "s_x": 0.12,
    "s_y": -0.07,
    "s_z": 0.03,
    "alpha_deg": 3.1,
    "beta_deg": -1.7,
    "gamma_deg": 2.4,
}


def test_moment_rows_hold_on_a_mems_like_log():
    """Rows from the moments agree with passes over the data; where the expansion behind them
    does not hold (the raw log of a sensor whose offsets exceed the field) there is no such row."""
    from nlpcal.calibration.problem import Problem
    from nlpcal.calibration.staged import StopRule, run_staged
    from nlpcal.moments import accumulate

    samples, _ = make_log(n=4000, noise=500.0, seed=5, truth=MEMS_TRUTH, field=50_000.0)
    rows = {}
    for exact in (True, False):
        problem = Problem(samples, None, accumulate(samples))
        rule = StopRule(max_cycles=8, rtol=0, every_row_exact=exact)
        rows[exact] = run_staged(problem, rule)[1]
    assert any(row.get("from_moments") for row in rows[False])
    for exact_row, row in zip(rows[True][1:], rows[False][1:]):
        assert row["mean"] == pytest.approx(exact_row["mean"], rel=1e-7)
        assert row["std"] == pytest.approx(exact_row["std"], rel=1e-4)
    assert problem.moment_row("raw", np.zeros(9), iterations=0, wall_s=0.0) is None


@pytest.mark.parametrize("reference", [None, 50_000.0])
def test_the_algebraic_fit_is_the_truth_without_noise(reference):
    from nlpcal.calibration.joint import algebraic_start
    from nlpcal.models.zhou2010 import Zhou2010Parameters
    from nlpcal.moments import accumulate

    samples, _ = make_log(n=3000, noise=0.0, seed=6, truth=MEMS_TRUTH, field=50_000.0)
    theta = algebraic_start(accumulate(samples, reference))
    found = Zhou2010Parameters.from_theta(theta).to_dict()
    expected = dict(MEMS_TRUTH)
    if reference is None:  # the gauge: the gains averaging one
        gains = np.array([1 + MEMS_TRUTH[k] for k in SCALES])
        expected.update(zip(SCALES, gains / gains.mean() - 1))
    for name, value in expected.items():
        assert found[name] == pytest.approx(value, rel=1e-8, abs=1e-6), name


@pytest.mark.parametrize("reference", [None, PAPER_FIELD])
def test_a_start_not_re_solved_is_within_a_hundredth_of_a_standard_error(
    noisy, reference, monkeypatch
):
    """The joint solve's stationary start against IPOPT forced to solve from it."""
    result = calibrate(noisy, method="joint", reference_field=reference)
    assert result.solver.status == "At_Stationary_Point"
    from nlpcal.calibration.joint import algebraic_start
    from nlpcal.models.zhou2010 import Zhou2010Parameters
    from nlpcal.moments import accumulate

    real_solve = steps.solve

    def from_the_start(solver, **kwargs):  # IPOPT from the start itself, not its Newton step
        return real_solve(solver, **{**kwargs, "x0": np.zeros_like(kwargs["x0"])})

    monkeypatch.setattr(steps, "solve", from_the_start)
    moments = accumulate(noisy, reference)
    forced = steps.block_step(moments, "joint", algebraic_start(moments), stationary=0.0)
    assert forced.iterations > 0
    solved = Zhou2010Parameters.from_theta(forced.theta).to_dict()
    for name, error in result.standard_errors.items():
        assert abs(result.parameters[name] - solved[name]) <= 0.01 * error, name


def test_threads_are_checked_and_leave_blas_as_they_found_it(noisy):
    import threading

    import threadpoolctl

    def blas_threads():
        return [
            m["num_threads"] for m in threadpoolctl.threadpool_info() if m["user_api"] == "blas"
        ]

    before = blas_threads()
    for bad in (True, 0, 1.5, "2"):
        with pytest.raises(InputError, match="threads"):
            calibrate(noisy, method="joint", threads=bad)
    one = calibrate(noisy, method="joint", threads=np.int64(1))
    two = calibrate(noisy, method="joint", threads=2)
    assert_same_optimum(one.parameters, two.parameters, two.standard_errors)  # other sums
    assert blas_threads() == before
    # Calls that overlap in threads: the last one out restores the limits.
    calls = [
        threading.Thread(target=calibrate, args=(noisy,), kwargs={"method": m, "threads": t})
        for m, t in (("joint", 1), ("staged", None), ("joint", 2))
    ]
    for call in calls:
        call.start()
    for call in calls:
        call.join()
    assert blas_threads() == before


def test_a_newton_step_within_the_resolution_is_taken_whichever_way_f_rounds(monkeypatch):
    # The objective's last bits (1e-10 of f on a 1 nT log) follow the kernel that summed the
    # moments. A Newton step that promises less than the data resolve (STATIONARY_SE standard
    # errors) is taken even where f reads higher after it, so that those bits do not choose
    # between two answers up to STATIONARY_SE standard errors apart (they did: 8e-3 SE between
    # the numpy and the compiled kernel on 10^7 samples). A longer step whose f rises by more
    # than PRECISION_FLOOR L^2 (2.5e-7 nT^2 here, f about 1 nT^2) is not.
    from nlpcal.calibration.joint import joint_start
    from nlpcal.moments import accumulate
    from nlpcal.nlp.blocks import variables

    samples, _ = make_log(n=20_000, noise=1.0, seed=4)
    moments = accumulate(samples, PAPER_FIELD)
    optimum = steps.block_step(moments, "joint", joint_start(moments)).theta
    free = variables("joint", moments.reference)
    errors = calibrate(samples, method="joint", reference_field=PAPER_FIELD).standard_errors
    z_x = errors["z_x"]  # [nT], the offsets' unit here
    real = steps.evaluate

    for off_se, taken in ((0.005, True), (0.5, False)):
        start = optimum + np.r_[off_se * z_x, np.zeros(8)]
        point = steps._Newton.at(moments, free, start, np.zeros(free.size))
        assert point.within() == taken

        def rounding_up(function, moments, theta, f=point.f):  # f after the step reads higher
            values = real(function, moments, theta)
            return (f + 1e-6 * abs(f),) if function is steps.value_function else values

        monkeypatch.setattr(steps, "evaluate", rounding_up)
        landed = point.taken()
        monkeypatch.setattr(steps, "evaluate", real)
        assert (landed is not point) == taken, off_se
        if taken:
            np.testing.assert_allclose(landed.x, point.step)
