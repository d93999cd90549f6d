"""The staged cycle stops early when its rate of convergence shows it cannot meet its rtol rule
within its limit, and never when it would have; `simulate --attitudes tilt` writes such a log."""

import numpy as np
import pandas as pd
import pytest

import nlpcal
from nlpcal.calibration.staged import cycles_to_converge
from nlpcal.cli import main
from nlpcal.errors import QualityError
from nlpcal.simulation import simulate
from synthetic import make_log, tilt_directions


@pytest.fixture(scope="module")
def tilted():
    """2000 samples, 5 nT of noise, heading free, roll and pitch within +-20 deg."""
    rng = np.random.default_rng(4)
    return make_log(n=2000, noise=5.0, seed=4, directions=tilt_directions(2000, rng))[0]


def test_the_prediction_of_a_geometric_sequence_is_exact():
    q, c, floor = 0.9, 50.0, 10.0
    f = floor + c * q ** np.arange(30)
    rate, cycles = cycles_to_converge(f[:12], 1e-6)
    assert rate == pytest.approx(q, rel=1e-9)
    # the first k > 11 whose decrease c q^(k-1) (1 - q) is at most 1e-6 f_11, counted from 11
    k = 12
    while c * q ** (k - 1) * (1 - q) > 1e-6 * f[11]:
        k += 1
    assert cycles == k - 11
    assert cycles_to_converge(f[:12], 0.0) is None  # rtol 0: the rule never holds, run on
    assert cycles_to_converge(f[:6], 1e-6) is None  # too few cycles to read a rate
    speeding = floor + np.cumsum(np.r_[c, -(q ** (np.arange(1, 12) ** 1.5))])  # faster and faster
    assert cycles_to_converge(speeding, 1e-6) is None


def test_a_tilt_limited_log_fails_after_a_few_cycles_with_advice(tilted):
    with pytest.raises(QualityError) as caught:
        nlpcal.calibrate(tilted, unit="nT")
    failure = caught.value
    assert failure.status == "Staged_Unconverged" and "allow_unconverged" in failure.overrides
    result = failure.result
    assert result.solver.stop_reason == "predicted_unconverged"
    assert len(result.statistics) - 1 < 50  # of the 500 allowed
    last = result.solver.stages[-1]
    assert last.predicted_cycles > 500 and 0 < last.convergence_rate < 1
    assert "--method joint" in failure.reason and "--allow-unconverged" in failure.reason


def test_allow_unconverged_runs_to_the_limit(tilted):
    result = nlpcal.calibrate(tilted, unit="nT", cycles=60, allow_unconverged=True)
    assert result.solver.stop_reason == "max_cycles" and len(result.statistics) - 1 == 60


@pytest.mark.parametrize("attitudes", ["uniform", "turntable", "clustered"])
def test_the_prediction_never_stops_a_cycle_that_converges(attitudes):
    samples = simulate(2000, seed=1, noise=1.0, attitudes=attitudes).to_numpy()
    predicted = nlpcal.calibrate(samples, unit="nT", require_identifiable=False)
    assert predicted.solver.stop_reason == "rtol"
    unpredicted = nlpcal.calibrate(
        samples, unit="nT", require_identifiable=False, allow_unconverged=True
    )
    assert len(predicted.statistics) == len(unpredicted.statistics)


def test_simulate_writes_a_tilt_limited_log(tmp_path):
    out = tmp_path / "tilt.csv"
    argv = ["simulate", "--attitudes", "tilt", "--max-tilt-deg", "20", "--noise", "0", "-q"]
    assert main([*argv, "--params", str(_ideal(tmp_path)), "-o", str(out)]) == 0
    field = pd.read_csv(out).to_numpy()
    # an ideal sensor: the field is 30 deg from down; roll and pitch of at most 20 deg each tilt
    # the z axis by at most acos(cos^2 20 deg) = 28.0 deg, so it stays 2 .. 58 deg from z
    angle = np.degrees(np.arccos(field[:, 2] / np.linalg.norm(field, axis=1)))
    assert angle.min() >= 30 - 28.0 - 1e-6 and angle.max() <= 30 + 28.0 + 1e-6
    assert angle.max() - angle.min() > 40  # and the tilts do reach the limits
    heading = np.degrees(np.arctan2(field[:, 1], field[:, 0]))
    assert np.histogram(heading, bins=8, range=(-180, 180))[0].min() > 100  # heading is free
    for bad in (["--max-tilt-deg", "0"], ["--max-tilt-deg", "91"], ["--attitudes", "uniform"]):
        rejected = tmp_path / "rejected.csv"
        command = ["simulate", "--attitudes", "tilt", "--max-tilt-deg", "20", *bad]
        assert main([*command, "-o", str(rejected), "-q"]) == 2 and not rejected.exists()


def _ideal(tmp_path):
    path = tmp_path / "ideal.json"
    names = ("z_x", "z_y", "z_z", "s_x", "s_y", "s_z", "alpha_deg", "beta_deg", "gamma_deg")
    path.write_text(pd.Series({n: 0.0 for n in names}).to_json().join(['{"parameters": ', "}"]))
    return path
