"""The moment expansion of Eq. 8 and its reference variants against a per-sample evaluation."""

import numpy as np
import pytest

from nlpcal import moments as mom
from nlpcal.nlp import blocks as problems
from nlpcal.statistics import direct_objective
from synthetic import PAPER_FIELD, PAPER_TRUTH, make_log

THETA_TRUE = np.array(
    [PAPER_TRUTH[k] for k in ("z_x", "z_y", "z_z", "s_x", "s_y", "s_z")]
    + list(np.radians([PAPER_TRUTH[k] for k in ("alpha_deg", "beta_deg", "gamma_deg")]))
)
NEAR = THETA_TRUE + np.array([3.0, -2.0, 4.0, 5e-5, -4e-5, 3e-5, 2e-4, -3e-4, 1e-4])


def _reference(kind, n, rng):
    if kind == "none":
        return None
    if kind == "constant":
        return PAPER_FIELD
    return PAPER_FIELD + 40.0 * np.sin(np.linspace(0, 3, n)) + rng.normal(0, 0.5, n)


def _fast(samples, theta, reference, **kw):
    moments = mom.accumulate(samples, reference, **kw)
    p = problems.pack(moments, theta, np.ones(9), 1.0)
    return float(problems.objective_function(moments.reference)(theta, p)[0])


@pytest.mark.parametrize("kind", ["none", "constant", "series"])
@pytest.mark.parametrize("theta", [THETA_TRUE, NEAR], ids=["truth", "near"])
@pytest.mark.parametrize("noise", [1.0, 16.0])
def test_fast_objective_equals_per_sample_objective(kind, theta, noise):
    # 1e-9 relative: the series in u is cut after u^4, an error of order max|u|^3; with 16 nT
    # noise max|u| is about 3e-3, with 1 nT about 2e-4 (see nlpcal.objective).
    rng = np.random.default_rng(5)
    reference = _reference(kind, 700, rng)
    # A reference series follows the field the sensor sees (diurnal variation).
    field = PAPER_FIELD if kind != "series" else reference[:, None]
    samples, _ = make_log(n=700, noise=noise, seed=3, field=field)
    direct = direct_objective(samples, theta, reference)
    assert _fast(samples, theta, reference) == pytest.approx(direct, rel=1e-9)


@pytest.mark.parametrize("kind", ["none", "constant", "series"])
def test_far_from_the_solution_the_expansion_stays_close(kind):
    # Raw data (all parameters zero) spread |B| by about 5 %; the cut series then errs by ~1e-6.
    rng = np.random.default_rng(6)
    samples, _ = make_log(n=500, noise=2.0, seed=4)
    reference = _reference(kind, len(samples), rng)
    direct = direct_objective(samples, np.zeros(9), reference)
    assert _fast(samples, np.zeros(9), reference) == pytest.approx(direct, rel=1e-5)


def test_moments_are_additive_over_chunks():
    samples, _ = make_log(n=1000, noise=2.0, seed=8)
    field = np.full(len(samples), PAPER_FIELD) + np.linspace(-20, 20, len(samples))
    for reference in (None, PAPER_FIELD, field):
        whole = mom.accumulate(samples, reference, chunk_rows=10_000)
        pieces = mom.accumulate(samples, reference, chunk_rows=97, frame=whole.frame)
        np.testing.assert_allclose(pieces.gram, whole.gram, rtol=1e-12, atol=1e-15)


def test_problem_size_does_not_depend_on_the_number_of_samples():
    small, _ = make_log(n=50, noise=1.0, seed=1)
    large, _ = make_log(n=20_000, noise=1.0, seed=2)
    for reference in (None, PAPER_FIELD):
        sizes = {mom.accumulate(x, reference).gram.shape for x in (small, large)}
        assert len(sizes) == 1
    first = problems.block_problem("joint", "constant")
    again = problems.block_problem("joint", "constant")
    assert first.solver is again.solver  # built once, re-solved with the data as parameters
    assert first.solver.size_in("p") == (9 + 9 + 46 * 46 + 3 + 2, 1)


def test_layouts_hold_the_distinct_features():
    assert mom.layout(False).size == 46  # monomials of degree <= 4, a times degree <= 2, a^2
    assert mom.layout(True).size == 58


@pytest.mark.parametrize("kind", ["none", "constant", "series"])
def test_closed_form_derivatives_equal_automatic_differentiation(kind):
    # The objective's gradient and Hessian come from the chain rule through the moments
    # (nlpcal.nlp.objective.objective_derivatives); CasADi's AD of the objective is the check.
    import casadi as ca

    from nlpcal.nlp.objective import objective_expression

    rng = np.random.default_rng(11)
    samples, _ = make_log(n=600, noise=2.0, seed=12)
    moments = mom.accumulate(samples, _reference(kind, len(samples), rng))
    symbols = problems._symbols(moments.reference)
    theta = ca.MX.sym("theta", 9)
    f = objective_expression(theta, symbols.gram, symbols.centre, symbols.length, kind)
    hess, grad = ca.hessian(f, theta)
    by_ad = ca.Function("by_ad", [theta, symbols.data], [f, grad, hess])
    p = problems.parameter_values(moments)
    for point in (np.zeros(9), THETA_TRUE, NEAR):
        expected = [np.asarray(v, dtype=float) for v in by_ad(point, p)]
        closed = problems.evaluate(problems.objective_function, moments, point)
        for got, want in zip(closed, expected):
            np.testing.assert_allclose(np.reshape(got, want.shape), want, rtol=1e-9, atol=0)
        np.testing.assert_array_equal(closed[2], closed[2].T)


@pytest.mark.parametrize("kind", ["none", "constant", "series"])
def test_a_stage_objective_has_the_entries_of_the_whole_objective_in_its_parameters(kind):
    """A stage's Newton checks read the gradient and Hessian in its three parameters from a
    smaller function (`block_objective_function`): the entries of the nine-parameter ones."""
    rng = np.random.default_rng(5)
    samples, _ = make_log(n=600, noise=2.0, seed=12)
    moments = mom.accumulate(samples, _reference(kind, len(samples), rng))
    for point in (np.zeros(9), THETA_TRUE, NEAR):
        f, grad, hess = problems.evaluate(problems.objective_function, moments, point)
        for block in problems.STAGE_ORDER:
            rows = list(problems.BLOCKS[block])
            mine = problems.evaluate(problems.block_objective_function, moments, point, block)
            assert mine[1].shape == (3,) and mine[2].shape == (3, 3)
            np.testing.assert_allclose(mine[0], f, rtol=1e-12)
            np.testing.assert_allclose(mine[1], grad[rows], rtol=1e-9, atol=1e-12 * abs(grad).max())
            np.testing.assert_allclose(
                mine[2], hess[np.ix_(rows, rows)], rtol=1e-9, atol=1e-12 * abs(hess).max()
            )
            np.testing.assert_array_equal(mine[2], mine[2].T)
    assert problems.block_objective_function(kind, "joint") is problems.objective_function(kind)


def test_an_evaluation_in_place_equals_the_function_call():
    import threading

    samples, _ = make_log(n=400, noise=1.0, seed=13)
    moments = mom.accumulate(samples, PAPER_FIELD)
    p = problems.parameter_values(moments)
    function = problems.summary_function(moments.reference)
    expected = [float(v) for v in function(NEAR, p)]
    assert list(problems.evaluate(problems.summary_function, moments, NEAR)) == expected
    # shared between threads, one evaluation at a time
    results = []

    def evaluate_many(theta):
        results.extend(
            problems.evaluate(problems.value_function, moments, theta) for _ in range(200)
        )

    threads = [threading.Thread(target=evaluate_many, args=(t,)) for t in (NEAR, THETA_TRUE)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    values = {float(function(t, p)[0]) for t in (NEAR, THETA_TRUE)}
    assert {r[0] for r in results} == values and len(results) == 400
    evaluation = problems._evaluation(problems.value_function, moments.reference)
    with pytest.raises(ValueError, match="parameters"):
        evaluation(NEAR, p[:-1])


def test_an_evaluation_reads_parameters_again_unless_nothing_can_change_them():
    """The parameters are copied into the function's buffer once while the same read-only array
    comes again (the Gram matrix of every check of a log); any other array is read every call."""
    samples, _ = make_log(n=400, noise=1.0, seed=13)
    moments = mom.accumulate(samples, PAPER_FIELD)
    function = problems.value_function(moments.reference)
    evaluation = problems._evaluation(problems.value_function, moments.reference)
    other = problems.parameter_values(mom.accumulate(samples[:300], PAPER_FIELD))

    def expected(p):
        return float(function(NEAR, p)[0])

    fixed = problems.parameter_values(moments)  # read-only, its own memory
    assert not fixed.flags.writeable and fixed.base is None
    assert evaluation(NEAR, fixed)[0] == expected(fixed)
    assert evaluation(NEAR, other)[0] == expected(other) != expected(fixed)
    assert evaluation(NEAR, fixed)[0] == expected(fixed)  # held, then another, then again
    writable = fixed.copy()
    assert evaluation(NEAR, writable)[0] == expected(fixed)
    writable[:] = other  # changed in place: read again
    assert evaluation(NEAR, writable)[0] == expected(other)
    view = writable.view()  # read-only, but a view of an array that can change
    view.flags.writeable = False
    assert evaluation(NEAR, view)[0] == expected(other)
    writable[:] = fixed
    assert evaluation(NEAR, view)[0] == expected(fixed)
    with pytest.raises(ValueError, match="parameters"):
        evaluation(NEAR, fixed[:-1])
    assert evaluation(NEAR, fixed)[0] == expected(fixed)  # after a refusal, read again


@pytest.mark.parametrize("model", ["full", "diagonal", "offset"])
@pytest.mark.parametrize("reference", ["none", "constant", "series"])
def test_projection_onto_a_model_is_the_least_squares_one(model, reference):
    """`Variables.project` is the least-squares projection onto the directions a model frees,
    to the bit (a model that only selects parameters takes a shortcut): zeros where it fixes a
    parameter (never -0.0), the mean of tied parameters."""
    from nlpcal.nlp.blocks import variables

    free = variables("joint", reference, model)
    e = free.matrix
    rng = np.random.default_rng(5)
    for _ in range(200):
        theta = rng.standard_normal(9) * 10.0 ** rng.uniform(-4, 5, 9)
        expected = e @ np.linalg.lstsq(e, theta, rcond=None)[0]
        assert free.project(theta).tobytes() == expected.tobytes()
    if model == "offset" and reference != "none":  # one common scale: the mean of the three
        projected = free.project(np.r_[0.0, 0.0, 0.0, 1.0, 2.0, 6.0, 0.0, 0.0, 0.0])
        np.testing.assert_allclose(projected[3:6], 3.0)
