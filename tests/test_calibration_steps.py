"""`calibrate` as named steps: its keywords are packed into settings objects at once, and the
steps run by hand give the result `calibrate` gives."""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest

import nlpcal
from nlpcal.calibration import estimate, prepare
from nlpcal.calibration.settings import NO_GATE, CalibrationSettings, QualityGate
from nlpcal.calibration.steps import assemble, diagnose, gate, solve
from nlpcal.errors import InputError, QualityError
from synthetic import PAPER_FIELD, band_directions, make_log


def test_every_keyword_of_calibrate_is_packed_into_the_settings():
    # the keywords of calibrate, besides the samples and the progress callback, are those of
    # CalibrationSettings.of with the same defaults: a keyword added to one and not the other
    # fails here
    calibrate = inspect.signature(nlpcal.calibrate).parameters
    packed = inspect.signature(CalibrationSettings.of).parameters
    apart = ("samples", "progress")
    mine = {n: p.default for n, p in calibrate.items() if n not in apart}
    assert mine == {n: p.default for n, p in packed.items()}


def test_the_settings_are_frozen_and_in_the_base_unit():
    settings = CalibrationSettings.of(
        method="joint", unit="uT", target_std=0.05, loss="huber", loss_scale=0.2, cycles=7
    )
    assert settings.loss.scale == pytest.approx(200.0)  # [nT]
    assert settings.stop.target_std == pytest.approx(50.0)  # [nT]
    assert settings.stop.max_cycles == 7
    assert settings.input.unit_source == "option"
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.method = "staged"  # type: ignore[misc]


@pytest.mark.parametrize(
    "options",
    [
        {"method": "newton"},
        {"model": "quadric"},
        {"cycles": 0},
        {"threads": 1.5},
        {"loss": "x"},
        {"lag": "soon"},
    ],
)
def test_options_are_checked_before_the_samples_are_read(options):
    # the samples are not even an array: the option's error comes first
    with pytest.raises(InputError, match=next(iter(options))):
        nlpcal.calibrate(object(), **options)


def test_the_steps_by_hand_give_calibrates_result():
    samples, _ = make_log(n=1500, noise=1.0, seed=4)
    settings = CalibrationSettings.of(method="joint", reference_field=PAPER_FIELD)
    data = prepare(samples, settings)
    problem = data.problem(settings.model, settings)
    solution = solve(problem, settings.method, settings.stop, data.unit)
    diagnosis = diagnose(problem, solution, settings.method, settings.stop, data.unit)
    result = gate(
        assemble(problem, solution, diagnosis, settings.method, data.unit),
        problem,
        diagnosis,
        settings.gate,
    )
    direct = nlpcal.calibrate(samples, method="joint", reference_field=PAPER_FIELD)
    assert result.parameters == direct.parameters
    assert result.standard_errors == direct.standard_errors
    assert result.solver.summary() == direct.solver.summary()


def test_the_gate_alone_refuses_what_the_data_do_not_determine():
    # turns about z with a degree of tilt: the samples lie nearly in one plane
    rng = np.random.default_rng(8)
    samples, _ = make_log(n=3000, noise=2.5, seed=9, directions=band_directions(3000, rng, 1.0))
    settings = CalibrationSettings.of(method="joint")
    data = prepare(samples, settings)
    problem = data.problem("full", settings)
    result = estimate(problem, "joint", settings.stop, data.unit)  # NO_GATE: returned
    assert result.identifiability["not_identifiable"]
    with pytest.raises(QualityError) as refused:
        estimate(
            data.problem("full", settings), "joint", settings.stop, data.unit, quality=QualityGate()
        )
    assert refused.value.status == "Not_Identifiable"
    assert refused.value.overrides == {"require_identifiable": False}
    assert np.isfinite(list(refused.value.result.parameters.values())).all()
    assert NO_GATE.allow_unconverged and not NO_GATE.require_identifiable


@pytest.mark.parametrize("unit", [None, "uT"])
def test_prepare_fits_the_sphere_once(monkeypatch, unit):
    """The unit check of an assumed unit and the moments' frame share one sphere fit, the one
    the moments would fit alone: the same subsample, the same sphere."""
    import nlpcal.calibration.steps as steps_module
    import nlpcal.io.logs as logs_module
    import nlpcal.moments as moments_module

    fit = moments_module.sphere_frame
    samples, _ = make_log(2000, noise=1.0, seed=3)
    samples = samples / 1000.0 if unit == "uT" else samples
    expected = fit(samples * 1000.0 if unit == "uT" else samples)
    calls = []

    def counted(values, *args, **kwargs):
        calls.append(values.shape)
        return fit(values, *args, **kwargs)

    for module in (steps_module, logs_module, moments_module):
        monkeypatch.setattr(module, "sphere_frame", counted)
    field = PAPER_FIELD / 1000.0 if unit == "uT" else PAPER_FIELD
    data = prepare(samples, CalibrationSettings.of(unit=unit, reference_field=field))
    assert len(calls) == 1
    np.testing.assert_array_equal(data.moments.frame.centre, expected.centre)
    assert data.moments.frame.radius == expected.radius


@pytest.mark.parametrize("method", ["staged", "joint"])
@pytest.mark.parametrize("reference", [None, PAPER_FIELD])
def test_the_pass_after_the_solve_gives_each_row_at_its_parameters_and_the_scores(
    method, reference
):
    """The rows the solve leaves to the pass after it are the statistics of |B1| at their own
    parameters, as a pass of their own gives them; its scores are those of a pass of their own
    about the mean |B1| (without a reference they are gathered about another centre and moved:
    exact to rounding)."""
    from nlpcal.calibration.scores import score_block_sums
    from nlpcal.models.zhou2010 import Zhou2010Parameters
    from nlpcal.statistics import field_statistics

    samples, _ = make_log(n=6000, noise=1.0, seed=12)
    settings = CalibrationSettings.of(method=method, reference_field=reference)
    data = prepare(samples, settings)
    problem = data.problem(settings.model, settings)
    solution = solve(problem, settings.method, settings.stop, data.unit)
    exact = [row for row in solution.rows[1:] if not row.get("from_moments")]
    assert len(exact) == (2 if method == "staged" else 1) and not problem.deferred
    for row in exact:
        theta = Zhou2010Parameters.from_dict(row.parameters).theta
        expected = field_statistics(samples, theta, reference)
        for key in ("max", "min", "mean", "std", "objective", "residual_lag1_autocorrelation"):
            assert row[key] == pytest.approx(expected[key], rel=1e-9, abs=1e-12), key
    final = solution.rows[-1]
    series, informations, rows, bias, _ = score_block_sums(
        samples, solution.theta, reference, problem.loss, final.mean, problem.moments.frame.radius
    )
    scores = solution.scores
    assert scores.block_rows == rows
    scale = np.abs(series).max()
    np.testing.assert_allclose(scores.series, series, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(scores.informations(), informations, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(scores.bias["gradient"], bias["gradient"], rtol=1e-9)


def test_every_cycle_shows_its_std_while_its_exact_row_waits_for_the_pass_after_the_solve():
    """Offsets beyond the field: the first cycles' rows are not held by the moments, so the
    progress of such a cycle gathers its row at once; the others show the moments' row (the
    table keeps its exact first and last rows)."""
    samples, _ = make_log(n=3000, noise=1.0, seed=3)
    samples = samples + 60_000.0
    shown = []
    result = nlpcal.calibrate(
        samples,
        method="staged",
        reference_field=PAPER_FIELD,
        progress=lambda cycle, row: shown.append((cycle, row.std, row.get("from_moments"))),
    )
    rows = result.statistics[1:]
    assert [cycle for cycle, _, _ in shown] == list(range(1, len(rows) + 1))
    assert all(std is not None and std > 0 for _, std, _ in shown)  # as it was shown
    assert rows[0].max is not None and rows[-1].max is not None
    assert any(moments for _, _, moments in shown)
