"""The nine-parameter calibration on real MEMS logs of ../shared/data/real (skipped without it)."""

import json

import numpy as np
import pandas as pd
import pytest

from nlpcal import calibrate
from nlpcal.calibration import CalibrationResult, calibrate_log
from nlpcal.errors import QualityError, SolveError
from nlpcal.io import read_log


def _log(real_data, folder, name, columns, factor):
    path = real_data / folder / name
    if not path.exists():
        pytest.skip(f"{path} is absent")
    return pd.read_csv(path)[columns].to_numpy(float) * factor


def test_full_sphere_hmc5883l(real_data):
    # A hand-rotated HMC5883L over the whole sphere, in gauss (SOURCE.md: raw |B| spread 13.6 %).
    samples = _log(
        real_data,
        "sunsided_hmc5883l_fullsphere",
        "hmc5883l_mag_derived.csv",
        ["mx_gauss", "my_gauss", "mz_gauss"],
        1e5,
    )
    staged = calibrate(samples, method="staged")
    joint = calibrate(samples, method="joint")
    measured = staged.statistics[0]["std"]
    assert joint.statistics[-1]["std"] < measured / 20
    assert staged.statistics[-1]["std"] == pytest.approx(joint.statistics[-1]["std"], rel=1e-4)
    for name in ("z_x", "z_y", "z_z"):
        assert staged.parameters[name] == pytest.approx(joint.parameters[name], abs=1.0)
    assert joint.identifiability["coverage"]["covered"] >= 24
    assert joint.identifiability["not_identifiable"] == []
    # Where the moment expansion is inexact (|B1| still varies by percent), the exact optimum is
    # estimated to be a small fraction of a standard error away.
    shift = joint.identifiability.get("exact_optimum_shift_in_standard_errors")
    assert shift is None or shift < 0.1


def test_partial_coverage_is_reported(real_data):
    # The x-IMU3 example log mostly lies flat: its field directions cover a few bins only.
    samples = _log(
        real_data,
        "xio_fusion_ximu3",
        "sensor_data.csv",
        ["Magnetometer X (uT)", "Magnetometer Y (uT)", "Magnetometer Z (uT)"],
        1e3,
    )
    try:
        result = calibrate(samples, method="staged", cycles=10)
    except SolveError as failure:
        assert "rotate the sensor through more attitudes" in str(failure)
        return
    assert result.identifiability["coverage"]["covered"] < 13
    assert any("poor attitude coverage" in w for w in result.warnings)
    assert np.isfinite(result.statistics[-1]["std"])


def _cli(capsys, *argv):
    from nlpcal.cli import main

    code = main([str(a) for a in argv])
    return code, capsys.readouterr()


@pytest.mark.parametrize(
    "path, arguments, columns",
    [
        ("bazhin_ellipsoid_fit/mag_out.txt", ["--unit", "raw"], ["0", "1", "2"]),
        ("wagonwheel_magcal/data.csv", ["--unit", "raw"], ["1", "2", "3"]),
        ("freeimu_gui_accmag/magn.txt", ["--unit", "raw"], ["0", "1", "2"]),
    ],
)
def test_headerless_whitespace_and_timed_logs_calibrate_as_they_are(
    real_data, tmp_path, capsys, path, arguments, columns
):
    log = real_data / path
    if not log.exists():
        pytest.skip(f"{log} is absent")
    out = tmp_path / "p.json"
    code, captured = _cli(capsys, "calibrate", log, *arguments, "--method", "joint", "-o", out)
    assert code == 0, captured.err
    document = json.loads(out.read_text())
    assert document["input"]["columns"] == columns
    assert document["input"]["layout"]["header"] is False
    final, measured = document["statistics"][-1], document["statistics"][0]
    assert final["std"] < measured["std"] / 5


def test_unit_mistakes_on_real_logs_are_warned_about(real_data, capsys, tmp_path):
    # counts (no unit in a headerless file) and gauss (names without units): nT is assumed, ruled
    # out by the magnitudes, and the samples are kept as raw counts
    for path, suggestion in (
        ("bazhin_ellipsoid_fit/mag_out.txt", "--unit mG"),
        ("ck_explorer_accmag/acc_mag_log.csv", "--unit G"),
    ):
        log = real_data / path
        if not log.exists():
            pytest.skip(f"{log} is absent")
        code, captured = _cli(capsys, "stats", log)
        assert code == 0
        assert "far from Earth's field" in captured.err and suggestion in captured.err
        assert "[raw]" in captured.out


#: The real logs whose columns carry no unit, and what nlpcal reads their columns as.
UNITLESS = (
    "bazhin_ellipsoid_fit/mag_out.txt",
    "ck_explorer_accmag/acc_mag_log.csv",
    "freeimu_gui_accmag/magn.txt",
    "wagonwheel_magcal/data.csv",
)


@pytest.mark.realdata
@pytest.mark.parametrize("path", UNITLESS)
def test_unitless_real_logs_are_recorded_as_assumed_raw_and_not_exported(
    real_data, tmp_path, capsys, path
):
    log = real_data / path
    if not log.exists():
        pytest.skip(f"{log} is absent")
    params = tmp_path / "p.json"
    code, captured = _cli(
        capsys, "calibrate", log, "--method", "joint", "--allow-unidentifiable", "-o", params
    )
    assert code == 0, captured.err
    document = json.loads(params.read_text())
    assert document["unit_source"] == "assumed" and document["input"]["unit_source"] == "assumed"
    # every one of them is far from Earth's field in nT: recorded as counts, the warning kept
    assert document["unit"] == "raw" and document["input"]["log_unit"] == "raw"
    assert any("far from Earth's field" in w for w in document["warnings"])
    for fmt in ("ardupilot", "px4"):
        code, captured = _cli(capsys, "export", params, "--format", fmt)
        assert code == 2 and captured.out == ""
        assert "--unit" in captured.err and "reference field" in captured.err


@pytest.mark.realdata
def test_a_unitless_log_given_its_unit_exports_what_apply_computes(real_data, tmp_path, capsys):
    log = real_data / "ck_explorer_accmag/acc_mag_log.csv"
    if not log.exists():
        pytest.skip(f"{log} is absent")
    params = tmp_path / "p.json"
    code, captured = _cli(capsys, "calibrate", log, "--unit", "G", "-o", params)
    assert code == 0, captured.err
    document = json.loads(params.read_text())
    assert (document["unit"], document["unit_source"]) == ("nT", "option")
    assert not any("far from Earth's field" in w for w in document["warnings"])
    code, captured = _cli(capsys, "export", params, "--format", "ardupilot")
    assert code == 0, captured.err
    rows = [line.split(",") for line in captured.out.splitlines() if not line.startswith("#")]
    values = {name: float(value) for name, value in rows}
    result = CalibrationResult.load(params)
    samples = read_log(log, unit="G").samples  # [nT]
    ofs = np.array([values[f"COMPASS_OFS_{a}"] for a in "XYZ"])  # [mG]
    dia = [values[f"COMPASS_DIA_{a}"] for a in "XYZ"]
    odi = [values[f"COMPASS_ODI_{a}"] for a in "XYZ"]
    d = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]], [odi[1], odi[2], dia[2]]])
    corrected = (samples / 100.0 + ofs) @ d.T * 100.0  # ArduPilot: m' = D (m + OFS) [mG] -> nT
    b1 = result.apply(samples, unit="nT")
    # the autopilot's field is R^T B1: the same magnitudes; offsets are -Z in mG. Exported with
    # 17 significant digits: agreement to double precision of a 5e4 nT field. [nT]
    np.testing.assert_allclose(-ofs * 100.0, result.model.offsets, rtol=0, atol=1e-6)
    magnitude = np.linalg.norm(corrected, axis=1) - np.linalg.norm(b1, axis=1)
    assert np.abs(magnitude).max() < 1e-6


def test_the_zero_row_of_the_rasteiro_logs_is_left_out(real_data):
    path = real_data / "rasteiro_robot_multisensor" / "MPU6050RM3100_derived.csv"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    log = read_log(path)
    assert log.unit == "uT" and log.dropped == 1 and not log.kept[0]
    assert not (log.samples == 0).all(axis=1).any()
    result = calibrate(log.samples, method="joint")
    corrected_spread = result.statistics[-1]["std"] / result.statistics[-1]["mean"]
    assert corrected_spread < 0.012  # 0.0101 without the row, 0.0216 with it


def test_the_upright_log_fails_the_quality_check_and_says_why(real_data, tmp_path, capsys):
    path = real_data / "xio_fusion_ximu3" / "sensor_data.csv"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    out = tmp_path / "p.json"
    code, captured = _cli(capsys, "calibrate", path, "-q", "-o", out)
    assert code == 1 and not out.exists()
    assert "do not determine" in captured.err
    assert "never pointed along" in captured.err and "+z" in captured.err


def test_the_joint_solve_on_the_upright_log_blames_the_coverage(real_data, tmp_path, capsys):
    path = real_data / "xio_fusion_ximu3" / "sensor_data.csv"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    out = tmp_path / "p.json"
    code, captured = _cli(capsys, "calibrate", path, "--method", "joint", "-o", out)
    # IPOPT wanders on the cap (it stops at its iteration limit) or settles on a far-away sphere
    # that leaves parameters undetermined, as the rounding of the moments has it: either way
    # exit 1, nothing written, and the attitudes named as the cause
    assert code == 1 and not out.exists()
    assert "8 of 26 direction bins visited" in captured.err
    assert "rotate the sensor through more attitudes" in captured.err


@pytest.mark.parametrize(("method", "loss"), [("staged", "huber"), ("joint", "cauchy")])
def test_robust_fits_of_messy_logs_report_a_true_covariance_or_fail(real_data, loss, method):
    # Residuals thousands of nT wide and a poorly covered sphere: the sandwich's meat from the
    # weighted moments is not positive there, and must not reach a result as negative variances.
    for name in ("MPU6050RM3100_derived.csv",):
        log = read_log(real_data / "rasteiro_robot_multisensor" / name)
        try:
            result = calibrate_log(log, method=method, loss=loss, allow_unconverged=True)
        except QualityError as failure:
            assert "do not determine" in failure.reason
            continue
        covariance = np.asarray(result.covariance)
        assert np.linalg.eigvalsh(covariance)[0] >= -1e-9 * np.abs(covariance).max()
        assert all(np.isfinite(v) and v > 0 for v in result.standard_errors.values())


@pytest.mark.parametrize("name", ["MPU6050RM3100_derived.csv", "MPU6500RM3100_derived.csv"])
def test_the_staged_huber_fit_of_the_rm3100_logs_ends_at_the_joint_one(real_data, name):
    # Offsets the attitudes determine weakly and 30 % of the samples down-weighted: a staged
    # cycle that reweights before least squares has converged crawls along the valley to its
    # cycle limit, and the exact-optimum check once measured the unweighted objective (2.5
    # standard errors "away" from a fit at the Huber optimum).
    path = real_data / "rasteiro_robot_multisensor" / name
    if not path.exists():
        pytest.skip(f"{path} is absent")
    log = read_log(path)
    joint = calibrate_log(log, method="joint", loss="huber")
    staged = calibrate_log(log, method="staged", loss="huber")
    assert staged.solver.stop_reason == "rtol"
    # at the resolution of the solves: the standard errors of independent samples (the stated
    # ones are up to 70 times wider here, for the dependence of neighbouring samples)
    resolution = joint.identifiability["score_dependence"]["standard_errors_independent"]
    for key, value in joint.parameters.items():
        assert abs(staged.parameters[key] - value) <= 0.2 * resolution[key], key
    for fit in (joint, staged):
        assert fit.identifiability["exact_optimum_shift_in_standard_errors"] < 0.1
        assert not any("exact optimum" in w for w in fit.warnings)


def test_the_slowly_turned_rm3100_log_says_why_its_standard_errors_are_wide(real_data):
    # A robot turning slowly: the scores of neighbouring samples stay alike for about 170
    # samples, and the standard errors are tens of times those of independent samples.
    path = real_data / "rasteiro_robot_multisensor" / "MPU6500RM3100_derived.csv"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    result = calibrate_log(read_log(path), method="joint")
    widening = result.identifiability["score_dependence"]["standard_error_widening"]
    assert max(widening.values()) > 3.0
    said = [w for w in result.warnings if "autocorrelated scores" in w]
    assert len(said) == 1 and max(widening, key=widening.get) in said[0]
