"""The public API's keywords mirror the command line's flags, and the former names of renamed
keywords are still accepted."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

import nlpcal

#: Public function -> the keywords that stand for its command's flags (--reference-field is
#: reference_field=, --bound-deg bound_deg=, ...).
FLAG_KEYWORDS = {
    "calibrate": [
        "method", "model", "reference_field", "unit", "cycles", "loss", "loss_scale", "threads",
        "allow_unconverged",
    ],
    "compare": ["reference_field", "unit", "loss", "loss_scale", "threads"],
    "worst_case": ["angles_deg", "reference_field"],
    "error_map": ["angles_deg", "reference_field", "step_deg"],
    "invert": ["reference_field", "bound_deg"],
    "repeatability": ["reference_field"],
    "fit_drift": ["base_temperature", "diurnal"],
    "calibrate_temperature": ["temperature_model", "base_temperature", "temperature_column"],
    "calibrate_turns": ["reference_field"],
    "calibrate_free": ["reference_field"],
    "attitude": ["declination_deg"],
    "simulate": ["n", "reference_field", "noise", "seed", "attitudes", "max_tilt_deg"],
    "read_log": ["columns", "unit", "reference_column", "reference_field", "reference_model",
                 "drop_invalid", "low_memory"],
    "apply_many": ["flag_outliers", "temperature_column", "force", "scheduler", "workers"],
    "calibrate_many": ["force", "scheduler", "workers"],
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(FLAG_KEYWORDS))
def test_keywords_mirror_the_flags(name):
    parameters = inspect.signature(getattr(nlpcal, name)).parameters
    assert [k for k in FLAG_KEYWORDS[name] if k not in parameters] == []


PROBE = nlpcal.synthetic_rotation((0.07, 0.04, 0.1), n=300, noise_nT=0.5, seed=0)


def test_the_former_field_names_are_still_accepted():
    field = 55_000.0
    assert np.array_equal(
        nlpcal.invert(PROBE, field_nT=field).angles_deg,
        nlpcal.invert(PROBE, reference_field=field).angles_deg,
    )
    assert (
        nlpcal.worst_case((0.1, 0.1, 0.1), field_nT=field).max_abs_error_nT
        == nlpcal.worst_case((0.1, 0.1, 0.1), reference_field=field).max_abs_error_nT
        == nlpcal.worst_case((0.1, 0.1, 0.1), field).max_abs_error_nT
    )
    assert np.array_equal(
        nlpcal.error_map((0.1, 0, 0), field_nT=field, step_deg=10)[2],
        nlpcal.error_map((0.1, 0, 0), field, 10)[2],
    )
    assert nlpcal.simulate(5, field=48_000.0).equals(nlpcal.simulate(5, reference_field=48_000.0))
    runs = [nlpcal.invert(PROBE), nlpcal.invert(PROBE[::-1])]
    assert (
        nlpcal.repeatability(runs, field_nT=field).field_nT
        == nlpcal.repeatability(runs, reference_field=field).field_nT
        == field
    )


def test_the_former_temperature_model_name_is_still_accepted():
    t = np.linspace(0.0, 20.0, 300)  # [degC]
    samples = nlpcal.simulate(300, seed=2)[["bx", "by", "bz"]].to_numpy()
    samples = samples * (1 + 2e-4 * (t - 10.0))[:, None]
    new = nlpcal.calibrate_temperature(samples, t, 49462.0, temperature_model="per-axis")
    old = nlpcal.calibrate_temperature(samples, t, 49462.0, model="per-axis")
    assert new.temperature_model == old.temperature_model
    assert new.temperature_model.kind == "per-axis"
    with pytest.raises(nlpcal.InputError, match="temperature_model"):
        nlpcal.calibrate_temperature(
            samples, t, 49462.0, temperature_model="common", model="per-axis"
        )


def test_a_former_name_that_disagrees_is_refused():
    with pytest.raises(nlpcal.InputError, match="reference_field"):
        nlpcal.invert(PROBE, reference_field=55_000.0, field_nT=50_000.0)
    with pytest.raises(nlpcal.InputError, match="reference_field"):
        nlpcal.simulate(5, reference_field=48_000.0, field=49_000.0)
    with pytest.raises(nlpcal.InputError):
        nlpcal.worst_case((0.1, 0.1, 0.1))  # no field at all


def test_the_compass_takes_reference_field_and_field_nt():
    from nlpcal.simulation.qiu2017 import replica

    turns = replica(seed=0, n=10)["turns"]
    mag = turns[["mx_nT", "my_nT", "mz_nT"]].to_numpy()
    acc = turns[["ax_g", "ay_g", "az_g"]].to_numpy()
    labels = turns["turn"].tolist()
    new = nlpcal.calibrate_turns(mag, acc, labels, reference_field=54_000.0)
    old = nlpcal.calibrate_turns(mag, acc, labels, field_nt=54_000.0)
    assert new.to_dict() == old.to_dict()
    with pytest.raises(nlpcal.InputError, match="reference_field"):
        nlpcal.calibrate_free(mag, acc, reference_field=54_000.0, field_nt=50_000.0)
