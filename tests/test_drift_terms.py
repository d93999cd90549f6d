"""Drift terms of long records in the joint calibration against a scalar reference: the full
temperature model (per-axis coefficients of offsets and scales, and of the angles) and scale
factors linear in time. Data from the independent forward model `drifting_sensor_output` in
synthetic.py; tolerances are the ones the done-when of the feature states, or five standard
errors (the noise is fixed by the seed; five leave a margin for any BLAS kernel's rounding)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from nlpcal.cli import main
from nlpcal.drift.temperature import TemperatureCalibrationResult, calibrate_temperature
from nlpcal.errors import InputError
from nlpcal.formats.affine import TemperatureDrift
from synthetic import PAPER_TRUTH, drifting_sensor_output, uniform_directions

WITHIN_SE = 5.0
T0 = 10.0  # [degC]
SIGMA = np.array([12e-6, -8e-6, 20e-6])  # [1/degC]
ZETA = np.array([0.3, -0.2, 0.5])  # [nT/degC]
ETA_DEG = np.array([2.0, -1.0, 3.0]) / 3600.0  # [deg/degC]
DRIFT = np.array([3e-6, -2e-6, 5e-6])  # [1/d]
ARCSEC = 1.0 / 3600.0  # [deg]


def swarm_like(n=100_000, noise=0.1, seed=3, days=None, drift=(0.0, 0.0, 0.0)):
    """Uniform attitudes, a field magnitude that goes from 25 000 to 50 000 nT along an orbit, a
    25 degC temperature swing up and down, white noise of `noise` nT per axis; the scalar
    reference exact. Returns (raw [nT], temperature [degC], reference [nT])."""
    rng = np.random.default_rng(seed)
    u = np.arange(n) / n
    temperature = T0 + 12.5 * np.sin(2 * np.pi * 7.3 * u) * np.sqrt(np.sin(np.pi * u))
    magnitude = 37_500.0 + 12_500.0 * np.cos(2 * np.pi * 15.5 * u)
    field = magnitude[:, None] * uniform_directions(n, rng)
    days = np.zeros(n) if days is None else days
    raw = drifting_sensor_output(
        field, PAPER_TRUTH, temperature - T0, days, SIGMA, ZETA, ETA_DEG, np.asarray(drift)
    )
    return raw + noise * rng.standard_normal(raw.shape), temperature, magnitude


def test_the_full_temperature_model_on_a_swarm_like_record():
    """1e5 samples, 0.1 nT noise, a 25 degC swing: per-axis scale temperature coefficients
    within 0.1 ppm/degC, non-orthogonality within 0.5 arcsec, residual rms <= 1.1 x noise."""
    raw, temperature, reference = swarm_like()
    result = calibrate_temperature(
        raw, temperature, reference, temperature_model="full", base_temperature=T0
    )
    model = result.temperature_model
    assert model.kind == "full"
    assert np.all(np.abs(np.array(model.scale_slope_per_degC) - SIGMA) < 0.1e-6)
    for name in ("alpha_deg", "beta_deg", "gamma_deg"):
        assert abs(result.parameters[name] - PAPER_TRUTH[name]) < 0.5 * ARCSEC, name
    assert result.statistics[-1]["rmse"] <= 1.1 * 0.1
    errors = result.temperature_standard_errors
    for k, axis in enumerate("xyz"):
        assert (
            abs(model.offset_slope_per_degC[k] - ZETA[k])
            < WITHIN_SE * errors[f"offset_slope_{axis}_per_degC"]
        )
    for k, angle in enumerate(("alpha", "beta", "gamma")):
        gap = abs(model.angle_slope_deg_per_degC[k] - ETA_DEG[k])
        assert gap < WITHIN_SE * errors[f"{angle}_slope_deg_per_degC"], angle
    assert not result.calibration.identifiability["not_identifiable"] and not result.warnings
    again = TemperatureCalibrationResult.from_json(result.to_json())
    assert again.temperature_model == model
    corrected = again.apply(raw[:100], temperature[:100])
    assert np.allclose(np.linalg.norm(corrected, axis=1), reference[:100], atol=1.0)


def test_the_per_axis_model_cannot_follow_drifting_angles():
    """The same record under the per-axis model (angles temperature-free) leaves residuals well
    above the noise: the angle coefficients of the full model are what the data need."""
    raw, temperature, reference = swarm_like(n=20_000)
    result = calibrate_temperature(raw, temperature, reference, temperature_model="per-axis")
    assert result.statistics[-1]["rmse"] > 2 * 0.1


@pytest.mark.parametrize("kind", ["common", "per-axis"])
def test_scale_factors_linear_in_time_are_recovered(kind):
    n = 30_000
    times = np.linspace(0.0, 40.0 * 86_400.0, n)  # 40 days [s]
    t_ref = 20.0 * 86_400.0
    drift = np.full(3, DRIFT[0]) if kind == "common" else DRIFT
    raw, temperature, reference = swarm_like(n=n, days=(times - t_ref) / 86_400.0, drift=drift)
    result = calibrate_temperature(
        raw,
        temperature,
        reference,
        temperature_model="full",
        base_temperature=T0,
        times=times,
        time_drift=kind,
    )
    assert result.time_drift.kind == kind and result.time_drift.reference_time_s == t_ref
    errors = result.time_drift_standard_errors
    names = (
        ["scale_slope_per_day"] if kind == "common" else [f"scale_slope_{a}_per_day" for a in "xyz"]
    )
    for k, name in enumerate(names):
        assert abs(result.time_drift.scale_slope_per_day[k] - drift[k]) < WITHIN_SE * errors[name]
        assert errors[name] < 0.05 * abs(drift[k])  # determined, not merely covered
    assert result.statistics[-1]["rmse"] <= 1.1 * 0.1
    document = json.loads(result.to_json())
    assert document["time_drift"]["kind"] == kind
    again = TemperatureCalibrationResult.from_json(result.to_json())
    corrected = again.apply(raw[:50], temperature[:50], times=times[:50])
    assert np.allclose(np.linalg.norm(corrected, axis=1), reference[:50], atol=1.0)
    with pytest.raises(InputError):
        again.apply(raw[:50], temperature[:50])  # no times
    with pytest.raises(InputError):
        TemperatureDrift.from_result(again, "nT")  # the exports carry neither term


def test_what_a_scalar_reference_cannot_determine_is_refused():
    raw, temperature, reference = swarm_like(n=3_000)
    ramp = np.linspace(0.0, 25.0, raw.shape[0]) + T0  # temperature in step with time
    times = np.arange(raw.shape[0]) * 60.0
    cases = (
        (ramp, times, "per-axis"),  # collinear: drift in time or temperature coefficient?
        (temperature, np.full(raw.shape[0], 5.0), "common"),  # no span of time
        (temperature, None, "common"),  # no times at all
    )
    for temps, when, kind in cases:
        with pytest.raises(InputError):
            calibrate_temperature(raw, temps, reference, times=when, time_drift=kind)


def test_the_command_line_records_both_terms_and_apply_refuses_the_time_drift(tmp_path, capsys):
    n = 20_000
    times = np.linspace(0.0, 30.0 * 86_400.0, n)
    raw, temperature, reference = swarm_like(
        n=n, days=(times - times[-1] / 2) / 86_400.0, drift=DRIFT
    )
    start = pd.Timestamp("2026-01-01T00:00:00Z")
    frame = pd.DataFrame(raw, columns=["bx", "by", "bz"])
    frame["utc"] = (start + pd.to_timedelta(times, unit="s")).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    frame["temp_c"] = temperature
    frame["scalar_nT"] = reference
    frame.to_csv(tmp_path / "long.csv", index=False)
    output = tmp_path / "p.json"
    argv = ["calibrate", str(tmp_path / "long.csv"), "--reference-column", "scalar_nT",
            "--temperature-column", "temp_c", "--temperature-model", "full",
            "--time-drift", "per-axis", "--time-column", "utc", "-o", str(output)]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    document = json.loads(output.read_text())
    assert document["temperature_model"]["kind"] == "full"
    drift = document["time_drift"]
    assert drift["kind"] == "per-axis" and drift["time_column"] == "utc"
    assert drift["reference_time_s"] == pytest.approx(start.timestamp() + 15 * 86_400.0)
    for k, axis in enumerate("xyz"):
        gap = abs(drift["scale_slope_per_day"][k] - DRIFT[k])
        assert gap < WITHIN_SE * drift["standard_errors"][f"scale_slope_{axis}_per_day"]
    capsys.readouterr()
    code = main(["apply", str(output), str(tmp_path / "long.csv"), "-o", str(tmp_path / "o.csv")])
    err = capsys.readouterr().err
    assert code == 2 and "time_drift" in err and not (tmp_path / "o.csv").exists()
    for bad in (
        ["--time-drift", "common"],  # without a temperature column
        ["--temperature-column", "temp_c", "--time-drift", "common"],  # without times
    ):
        code = main(["calibrate", str(tmp_path / "long.csv"), "--reference-column", "scalar_nT",
                     *bad, "-o", str(tmp_path / "q.json")])  # fmt: skip
        assert code == 2 and not (tmp_path / "q.json").exists()
        assert "Traceback" not in capsys.readouterr().err
