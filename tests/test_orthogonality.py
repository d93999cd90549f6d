"""Non-orthogonality (seed 003, Wang et al. 2015) in the angle convention of Zhou et al. 2010.

The synthetic data and the reference values here come from a forward model written in this file
from the geometric description of the angles (rotations of the ideal axes), independently of
`nlpcal.models.zhou2010` and of the solver's correction matrix.
"""

from __future__ import annotations

import json
import math
import sys

import numpy as np
import pandas as pd
import pytest

from nlpcal import orthogonality as ortho
from nlpcal.cli import main
from nlpcal.errors import InputError, QualityError, SolveError
from nlpcal.models import wang2015
from nlpcal.moments import accumulate
from nlpcal.nlp.blocks import moment_parameters
from nlpcal.nlp.orthogonality import inversion_objective, inversion_solver, worst_case_solver
from nlpcal.nlp.solver import SolveOutcome
from nlpcal.orthogonality import inversion as inversion_module
from synthetic import make_log

PAPER_ANGLES = (0.07, 0.04, 0.1)  # the synthetic inversion of section 2 in Wang et al. [deg]
FIELD = 55_000.0  # [nT]


# ------------------------------------------------------------------------------------------------
# independent forward model


def _rotate(vector, axis, angle_rad):
    """Rodrigues' rotation of `vector` about unit `axis` by `angle_rad` (right-handed)."""
    vector, axis = np.asarray(vector, float), np.asarray(axis, float)
    return (
        vector * math.cos(angle_rad)
        + np.cross(axis, vector) * math.sin(angle_rad)
        + axis * np.dot(axis, vector) * (1.0 - math.cos(angle_rad))
    )


def sensor_axes(alpha_deg, beta_deg, gamma_deg):
    """Sensor axes x, y, z in the ideal frame, built from the angle definitions of Zhou 2010.

    z lies on z1. x is ox1 turned by gamma about z1 (toward +y1), then tilted by alpha out of the
    x1-y1 plane toward -z1. y is oy1 turned by beta about x1 (toward +z1), staying in y1-z1.
    """
    ex, ey, ez = np.eye(3)
    x = _rotate(ex, ez, math.radians(gamma_deg))
    x = _rotate(x, np.cross(ez, x), math.radians(alpha_deg))  # about z1 x x: tilts toward -z1
    y = _rotate(ey, ex, math.radians(beta_deg))
    return np.vstack([x, y, ez])


def probe_output(field_vectors, angles_deg):
    """B': each axis reads the projection of the true field on its direction. [nT]"""
    return np.asarray(field_vectors, float) @ sensor_axes(*angles_deg).T


def unit_vectors(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack(
        np.broadcast_arrays(np.cos(p) * np.cos(t), np.cos(p) * np.sin(t), np.sin(p)), axis=-1
    )


def grid_error(angles_deg, field, step_deg=0.5):
    """dB = |B'| - |B| on a dense (theta, phi) grid; returns theta, phi, dB (n_phi, n_theta)."""
    theta = np.arange(0.0, 360.0, step_deg)
    phi = np.arange(-90.0, 90.0 + step_deg / 2, step_deg)
    u = unit_vectors(theta[None, :], phi[:, None])
    return (
        theta,
        phi,
        field
        * (
            np.linalg.norm(probe_output(u.reshape(-1, 3), angles_deg), axis=1).reshape(u.shape[:2])
            - 1.0
        ),
    )


def small_angle_value(angles_deg, field):
    """(B/2) max |eig| of the symmetric quadratic form of the angles, Q = d(T^T T)/d(angles)."""
    a, b, g = np.radians(angles_deg)
    q = np.array([[0.0, g, -a], [g, 0.0, b], [-a, b, 0.0]])
    return 0.5 * field * np.max(np.abs(np.linalg.eigvalsh(q)))


def rotation_log(angles_deg, field=FIELD, n=500, noise=0.0, seed=0):
    """Probe output for directions spread evenly over the sphere (golden-angle spiral). [nT]"""
    rng = np.random.default_rng(seed)
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    azimuth = np.radians(137.50776405) * k + rng.uniform(0, 2 * np.pi)
    directions = np.stack(
        [np.sqrt(1 - z**2) * np.cos(azimuth), np.sqrt(1 - z**2) * np.sin(azimuth), z], axis=1
    )
    output = probe_output(field * directions, angles_deg)
    return output + rng.normal(0.0, noise, output.shape) if noise else output


# ------------------------------------------------------------------------------------------------
# the forward model agrees with nlpcal's convention


def test_independent_model_reproduces_the_worked_example_of_zhou2010():
    # zhou2010 docstring: alpha = 1 deg, 50 000 nT along +z1 reads (-872.6, 0, 50 000) nT
    reading = probe_output([[0.0, 0.0, 50_000.0]], (1.0, 0.0, 0.0))[0]
    np.testing.assert_allclose(reading, [-872.6, 0.0, 50_000.0], atol=0.05)


def test_total_field_error_matches_the_independent_model():
    rng = np.random.default_rng(1)
    angles = rng.uniform(-2, 2, 3)
    theta, phi = rng.uniform(0, 360, 50), rng.uniform(-90, 90, 50)
    expected = (
        np.linalg.norm(probe_output(FIELD * unit_vectors(theta, phi), angles), axis=1) - FIELD
    )
    np.testing.assert_allclose(
        wang2015.total_field_error(angles, FIELD, theta, phi), expected, rtol=0, atol=1e-8
    )


# ------------------------------------------------------------------------------------------------
# worst case


def test_paper_value_01_deg_at_55000_nT():
    result = ortho.worst_case((0.1, 0.1, 0.1), FIELD)
    # REFERENCE.md: about 96 nT in the Zhou convention (the paper: "about 95 nT"); small-angle
    # value B * 0.1 deg = 95.99 nT, the second-order terms add 0.03 nT.
    assert result.max_abs_error_nT == pytest.approx(96.02, abs=0.01)
    assert result.most_negative.delta_B_nT == pytest.approx(-96.02, abs=0.01)
    assert result.largest_positive.delta_B_nT == pytest.approx(48.00, abs=0.01)
    assert result.small_angle_nT == pytest.approx(FIELD * math.radians(0.1), rel=1e-12)


def test_worst_case_agrees_with_dense_grid_and_small_angle_value():
    rng = np.random.default_rng(2024)
    for _ in range(30):
        angles = rng.uniform(-0.5, 0.5, 3)
        field = rng.uniform(20_000, 70_000)
        result = ortho.worst_case(angles, field)
        _, _, error = grid_error(angles, field, step_deg=0.5)
        top, bottom = error.max(), error.min()
        scale = max(top, -bottom)
        # A grid can only miss the optimum, by at most ~(curvature) * (half a step)^2:
        # 3 * scale * (0.25 deg)^2 ~ 6e-5 * scale; 2e-4 leaves room.
        assert result.largest_positive.delta_B_nT >= top - 1e-9 * scale
        assert result.largest_positive.delta_B_nT <= top + 2e-4 * scale
        assert result.most_negative.delta_B_nT <= bottom + 1e-9 * scale
        assert result.most_negative.delta_B_nT >= bottom - 2e-4 * scale
        assert result.max_abs_error_nT == pytest.approx(scale, rel=2e-4)
        # the reported directions do give the reported errors (independent model)
        for extreme in (result.largest_positive, result.most_negative):
            b = probe_output(field * unit_vectors(extreme.theta_deg, extreme.phi_deg)[None], angles)
            assert np.linalg.norm(b) - field == pytest.approx(
                extreme.delta_B_nT, rel=1e-9, abs=1e-9
            )
            assert 0.0 <= extreme.theta_deg < 360.0 and -90.0 <= extreme.phi_deg <= 90.0
        # first-order value: relative error O(largest angle [rad]) <= 0.0087 here
        expected = small_angle_value(angles, field)
        assert result.max_abs_error_nT == pytest.approx(
            expected, rel=2 * np.radians(np.abs(angles).max())
        )
        assert result.small_angle_nT == pytest.approx(expected, rel=1e-12)


def test_worst_case_large_angles_still_global():
    # a few degrees: far from the small-angle regime, the grid still confirms the maximum
    angles = (-2.34, 1.29, -0.27)  # Zhou 2010's probe
    result = ortho.worst_case(angles, 49_500.0)
    _, _, error = grid_error(angles, 49_500.0, step_deg=0.5)
    assert result.largest_positive.delta_B_nT == pytest.approx(error.max(), rel=2e-4)
    assert result.most_negative.delta_B_nT == pytest.approx(error.min(), rel=2e-4)


def test_orthogonal_axes_have_no_error():
    result = ortho.worst_case((0.0, 0.0, 0.0), FIELD)
    assert result.max_abs_error_nT == pytest.approx(0.0, abs=1e-9)


def test_implied_worst_case_of_paper_repeatability():
    # section 3: an angle error of 0.004 deg means at most 3.8 nT at 55 000 nT
    assert ortho.implied_worst_case(0.004, FIELD) == pytest.approx(3.84, abs=0.005)


def test_worst_case_problem_is_built_once():
    ortho.worst_case((0.1, 0.2, 0.3), FIELD)
    before = worst_case_solver.cache_info()
    ortho.worst_case((0.3, -0.2, 0.1), 30_000.0)
    after = worst_case_solver.cache_info()
    assert after.misses == before.misses and after.hits > before.hits


@pytest.mark.parametrize(
    "angles", [(0.1, 0.1), (0.1, float("nan"), 0.1), (90.0, 0.0, 0.0), ("a", 0, 0)]
)
def test_bad_angles_are_input_errors(angles):
    with pytest.raises(InputError):
        ortho.worst_case(angles, FIELD)


@pytest.mark.parametrize("field", [0.0, -5.0, float("inf"), "x"])
def test_bad_field_is_an_input_error(field):
    with pytest.raises(InputError):
        ortho.worst_case((0.1, 0.1, 0.1), field)


# ------------------------------------------------------------------------------------------------
# inversion


@pytest.mark.parametrize("field", [None, FIELD])
def test_paper_synthetic_inversion_is_exact(field):
    # section 2: 55 000 nT, angles (0.07, 0.04, 0.1) deg, bounds +-0.5 deg, start 0
    result = ortho.invert(rotation_log(PAPER_ANGLES, n=200), field_nT=field)
    np.testing.assert_allclose(result.angles_deg, PAPER_ANGLES, atol=1e-8)
    assert result.success and result.status == "Solve_Succeeded"
    assert result.rms_after_nT < 1e-6 < 1.0 < result.rms_before_nT
    assert not any(result.bound_active) and not result.warnings


@pytest.mark.parametrize("field", [None, FIELD])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_level_inversion_within_0002_deg(field, seed):
    # 1 nT white noise per axis: the standard error is ~2e-4 deg, so 0.002 deg is ~10 sigma
    rng = np.random.default_rng(seed)
    truth = rng.uniform(-0.3, 0.3, 3)
    result = ortho.invert(rotation_log(truth, n=400, noise=1.0, seed=seed), field_nT=field)
    assert np.abs(result.angles_deg - truth).max() < 0.002
    assert result.angles_std_deg is not None and (result.angles_std_deg < 5e-4).all()
    assert result.rms_after_nT == pytest.approx(1.0, rel=0.15)


def test_inversion_accepts_list_array_and_dataframe():
    data = rotation_log(PAPER_ANGLES, n=50)
    frame = pd.DataFrame(data, columns=["bx", "by", "bz"])
    results = [ortho.invert(x).angles_deg for x in (data.tolist(), data, frame)]
    for angles in results:
        np.testing.assert_allclose(angles, PAPER_ANGLES, atol=1e-8)


def test_bound_active_warning_when_truth_is_outside():
    truth = (0.7, 0.04, -0.1)
    data = rotation_log(truth, n=300, noise=0.5)
    result = ortho.invert(data, bound_deg=0.5)
    assert result.bound_active == [True, False, False]
    assert result.angles_deg[0] == pytest.approx(0.5, abs=1e-6)
    assert len(result.warnings) == 1 and "outside the bounds" in result.warnings[0]
    assert result.to_dict()["any_bound_active"] is True
    assert result.to_dict()["verdict"] == {"status": "warnings", "reasons": result.warnings}
    wider = ortho.invert(data, bound_deg=[1.0, 0.5, 0.5])
    assert not any(wider.bound_active) and not wider.warnings
    assert wider.verdict.status == "ok"
    np.testing.assert_allclose(wider.angles_deg, truth, atol=0.002)


def test_inversion_objective_matches_direct_per_sample_evaluation():
    # The moment objective of the built problem against a plain loop over samples. The moments
    # carry |B1|^2 / F^2 - 1 = u to fourth order, so the relative error is at most max|u|^3
    # (`nlpcal.nlp.objective`): 1e-9 at the generating angles, about 1e-7 away from them.
    truth = (0.2, -0.1, 0.3)
    data = rotation_log(truth, n=37, noise=2.0)
    for angles, bound in ((np.array([0.05, -0.02, 0.11]), None), (np.array(truth), 1e-9)):
        corrected = np.array([np.linalg.solve(sensor_axes(*angles), b) for b in data])
        magnitude = np.linalg.norm(corrected, axis=1)
        for reference, centre in ((None, magnitude.mean()), (54_990.0, 54_990.0)):
            moments = accumulate(data, reference)
            value = float(
                inversion_objective(moments.reference)(angles, moment_parameters(moments))[0]
            )
            max_u = np.abs((magnitude / centre) ** 2 - 1).max()
            assert value == pytest.approx(np.mean((magnitude - centre) ** 2), rel=bound or max_u**3)


def test_inversion_problem_is_built_once_for_every_log_length():
    ortho.invert(rotation_log(PAPER_ANGLES, n=100))
    before = inversion_solver.cache_info()
    ortho.invert(rotation_log(PAPER_ANGLES, n=90, seed=3), field_nT=FIELD)
    ortho.invert(rotation_log(PAPER_ANGLES, n=5000, seed=4))
    assert inversion_solver.cache_info().misses == before.misses


def test_repeatability_like_table_4():
    truth = (0.064, 0.01, 0.103)
    runs = [ortho.invert(rotation_log(truth, n=300, noise=3.0, seed=s)) for s in range(4)]
    report = ortho.repeatability(runs, field_nT=FIELD)
    angles = np.array([r.angles_deg for r in runs])
    np.testing.assert_allclose(report.mean_angles_deg, angles.mean(axis=0))
    assert report.max_abs_deviation_deg == pytest.approx(np.abs(angles - angles.mean(axis=0)).max())
    assert report.implied_worst_case_nT == pytest.approx(
        ortho.implied_worst_case(report.max_abs_deviation_deg, FIELD)
    )
    # FIELD * d [rad] to first order
    assert report.implied_worst_case_nT == pytest.approx(
        FIELD * math.radians(report.max_abs_deviation_deg), rel=1e-3
    )
    np.testing.assert_allclose(report.mean_angles_deg, truth, atol=0.002)
    document = report.to_dict()
    assert document["n_runs"] == 4 and document["field_source"] == "reference"
    with pytest.raises(InputError):
        ortho.repeatability(runs[:1])


@pytest.mark.parametrize(
    "samples, options, words",
    [
        (np.ones((5, 3)), {}, "at least 10"),
        (np.full((20, 3), np.nan), {}, "NaN"),
        (np.ones((20, 2)), {}, "shape"),
        (None, {"bound_deg": 0.0}, "bounds"),
        (None, {"bound_deg": [0.5, 0.5]}, "bounds"),
        (None, {"start_deg": (0.9, 0, 0)}, "outside the bounds"),
        (None, {"field_nT": -1.0}, "positive"),
    ],
)
def test_inversion_rejects_bad_input(samples, options, words):
    if samples is None:
        samples = rotation_log(PAPER_ANGLES, n=50)
    with pytest.raises(InputError, match=words):
        ortho.invert(samples, **options)


def test_inversion_rejects_zero_magnitude_samples():
    data = rotation_log(PAPER_ANGLES, n=50)
    data[3] = 0.0
    with pytest.raises(InputError, match="zero magnitude"):
        ortho.invert(data)


def test_inversion_failure_is_a_solve_error(monkeypatch):
    monkeypatch.setattr(inversion_module, "solve", _failing_solve)
    with pytest.raises(SolveError) as info:
        ortho.invert(rotation_log(PAPER_ANGLES, n=50))
    assert info.value.status == "Maximum_Iterations_Exceeded"


def _failing_solve(solver, **kwargs):
    return SolveOutcome(
        x=np.asarray(kwargs["x0"], float),
        f=1.0,
        status="Maximum_Iterations_Exceeded",
        success=False,
        iterations=200,
    )


# ------------------------------------------------------------------------------------------------
# command line


def _run(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


def _write_log(path, angles, *, n=300, noise=0.5, seed=0, columns=("bx", "by", "bz")):
    frame = pd.DataFrame(rotation_log(angles, n=n, noise=noise, seed=seed), columns=columns)
    frame.insert(0, "time_s", np.arange(n) * 0.1)
    frame.to_csv(path, index=False)
    return path


def test_cli_worst_case_to_stdout(capsys):
    code, out, err = _run(
        ["orthogonality", "worst-case", "--angles-deg", "0.1", "0.1", "0.1", "--field", "55000"],
        capsys,
    )
    assert code == 0
    document = json.loads(out)
    assert document["max_abs_error_nT"] == pytest.approx(96.02, abs=0.01)
    assert document["angles_deg"] == [0.1, 0.1, 0.1] and document["field_nT"] == 55000.0
    for key in ("largest_positive", "most_negative"):
        assert set(document[key]) >= {"delta_B_nT", "theta_deg", "phi_deg"}
    assert {"theta_deg", "phi_deg", "analytic"} <= set(document)


def test_cli_worst_case_to_file(tmp_path, capsys):
    out_path = tmp_path / "wc.json"
    code, out, err = _run(
        [
            "orthogonality",
            "worst-case",
            "--angles-deg",
            "0.5",
            "-0.2",
            "0.3",
            "--field",
            "48000",
            "-o",
            str(out_path),
        ],
        capsys,
    )
    assert code == 0 and out == "" and "wrote" in err
    assert json.loads(out_path.read_text())["field_nT"] == 48000.0


@pytest.mark.parametrize(
    "argv",
    [
        ["--angles-deg", "0.1", "nan", "0.1", "--field", "55000"],
        ["--angles-deg", "0.1", "90", "0.1", "--field", "55000"],
        ["--angles-deg", "0.1", "x", "0.1", "--field", "55000"],
        ["--angles-deg", "0.1", "0.1", "--field", "55000"],
        ["--angles-deg", "0.1", "0.1", "0.1", "--field", "-3"],
        ["--angles-deg", "0.1", "0.1", "0.1"],
        ["--angles-deg", "0.1", "0.1", "0.1", "--field", "55000", "-o", "/no/such/dir/x.json"],
    ],
)
def test_cli_worst_case_bad_input_exits_2(argv, capsys):
    code, out, err = _run(["orthogonality", "worst-case", *argv], capsys)
    assert code == 2 and out == ""
    message = err.strip().splitlines()
    assert message[0].startswith("nlpcal orthogonality") and len(message) <= 2


def test_cli_map_csv_and_png(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    png, csv = tmp_path / "map.png", tmp_path / "map.csv"
    code, out, err = _run(
        [
            "orthogonality",
            "map",
            "--angles-deg",
            "0.1",
            "0.1",
            "0.1",
            "--field",
            "55000",
            "-o",
            str(png),
            "--csv",
            str(csv),
            "--step-deg",
            "2",
        ],
        capsys,
    )
    assert code == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size < 200_000
    from PIL import Image

    assert Image.open(png).mode in ("RGB", "RGBA")  # a colour scale is not cut into 256 bands
    table = pd.read_csv(csv)
    assert list(table.columns) == ["theta_deg", "phi_deg", "delta_B_nT"]
    assert len(table) == 180 * 91
    assert table["delta_B_nT"].min() == pytest.approx(-96.02, abs=0.2)


def test_cli_map_csv_to_stdout(capsys):
    code, out, err = _run(
        [
            "orthogonality",
            "map",
            "--angles-deg",
            "0",
            "0",
            "0.2",
            "--field",
            "50000",
            "--csv",
            "-",
            "--step-deg",
            "10",
        ],
        capsys,
    )
    assert code == 0 and out.splitlines()[0] == "theta_deg,phi_deg,delta_B_nT"
    assert len(out.splitlines()) == 1 + 36 * 19


def test_cli_map_without_matplotlib_exits_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    png = tmp_path / "map.png"
    code, out, err = _run(
        [
            "orthogonality",
            "map",
            "--angles-deg",
            "0.1",
            "0.1",
            "0.1",
            "--field",
            "55000",
            "-o",
            str(png),
        ],
        capsys,
    )
    assert code == 2 and "pip install 'nlpcal[plot]'" in err and not png.exists()


@pytest.mark.parametrize(
    "extra", [[], ["--csv", "-", "--step-deg", "0"], ["--csv", "-", "--step-deg", "45"]]
)
def test_cli_map_bad_usage_exits_2(extra, capsys):
    code, out, err = _run(
        ["orthogonality", "map", "--angles-deg", "0.1", "0.1", "0.1", "--field", "55000", *extra],
        capsys,
    )
    assert code == 2 and out == ""


def test_cli_invert_one_log(tmp_path, capsys):
    log = _write_log(tmp_path / "rot.csv", PAPER_ANGLES)
    out_path = tmp_path / "angles.json"
    code, out, err = _run(
        ["orthogonality", "invert", str(log), "--field", "55000", "-o", str(out_path)], capsys
    )
    assert code == 0 and out == ""
    document = json.loads(out_path.read_text())
    np.testing.assert_allclose(document["angles_deg"], PAPER_ANGLES, atol=0.002)
    assert document["variant"] == "reference" and document["status"] == "Solve_Succeeded"
    assert document["bound_active"] == [False, False, False] and document["iterations"] > 0
    assert {"objective_nT2", "angles_std_deg", "warnings", "any_bound_active"} <= set(document)


def test_cli_invert_units_and_columns(tmp_path, capsys):
    frame = pd.DataFrame(rotation_log(PAPER_ANGLES, n=200) / 1000.0, columns=["u", "v", "w"])
    log = tmp_path / "ut.csv"
    frame.to_csv(log, index=False)
    code, out, err = _run(
        ["orthogonality", "invert", str(log), "--columns", "u", "v", "w", "--unit", "uT"], capsys
    )
    assert code == 0
    document = json.loads(out)
    np.testing.assert_allclose(document["angles_deg"], PAPER_ANGLES, atol=1e-6)
    assert document["corrected_mean_nT"] == pytest.approx(FIELD, rel=1e-9)


def test_cli_invert_several_logs_reports_repeatability(tmp_path, capsys):
    logs = [
        str(_write_log(tmp_path / f"run{i}.csv", (0.064, 0.0, 0.103), noise=3.0, seed=i))
        for i in range(3)
    ]
    code, out, err = _run(["orthogonality", "invert", *logs, "--field", "55000"], capsys)
    assert code == 0
    document = json.loads(out)
    assert document["n_runs"] == 3 and [r["log"] for r in document["runs"]] == logs
    assert document["angles_deg"] == document["mean_angles_deg"]
    assert document["implied_worst_case_nT"] == pytest.approx(
        FIELD * math.radians(document["max_abs_deviation_deg"]), rel=1e-3
    )


def test_cli_invert_bound_active_warns_and_exits_0(tmp_path, capsys):
    log = _write_log(tmp_path / "rot.csv", (0.04, -0.8, 0.1))
    code, out, err = _run(["orthogonality", "invert", str(log), "--bound-deg", "0.5"], capsys)
    assert code == 0
    assert "warning" in err and "beta" in err and "outside the bounds" in err
    document = json.loads(out)
    assert document["bound_active"] == [False, True, False] and document["any_bound_active"]


def test_cli_invert_drop_invalid(tmp_path, capsys):
    log = _write_log(tmp_path / "rot.csv", PAPER_ANGLES)
    lines = log.read_text().splitlines()
    lines[5] = "0.4,abc,1,2"
    log.write_text("\n".join(lines) + "\n")
    code, out, err = _run(["orthogonality", "invert", str(log)], capsys)
    assert code == 2 and "--drop-invalid" in err
    code, out, err = _run(["orthogonality", "invert", str(log), "--drop-invalid"], capsys)
    assert code == 0 and "dropped 1" in err
    assert json.loads(out)["n_samples"] == 299


@pytest.mark.parametrize(
    "case",
    [
        "missing",
        "directory",
        "empty",
        "no-columns",
        "bad-column",
        "two-columns",
        "few-rows",
        "bound",
        "bound-three",
        "unit",
        "field",
        "out-folder",
    ],
)
def test_cli_invert_bad_input_exits_2(case, tmp_path, capsys):
    log = _write_log(tmp_path / "rot.csv", PAPER_ANGLES, n=60)
    argv = ["orthogonality", "invert", str(log)]
    if case == "missing":
        argv[2] = str(tmp_path / "nope.csv")
    elif case == "directory":  # a folder is a log of many files: this one has none
        (tmp_path / "no_logs").mkdir()
        argv[2] = str(tmp_path / "no_logs")
    elif case == "empty":
        (tmp_path / "empty.csv").write_text("")
        argv[2] = str(tmp_path / "empty.csv")
    elif case == "no-columns":
        _write_log(log, PAPER_ANGLES, columns=("a", "b", "c"))
    elif case == "bad-column":
        argv += ["--columns", "bx", "by", "bq"]
    elif case == "two-columns":
        argv += ["--columns", "bx", "by"]
    elif case == "few-rows":
        _write_log(log, PAPER_ANGLES, n=5)
    elif case == "bound":
        argv += ["--bound-deg", "-1"]
    elif case == "bound-three":
        argv += ["--bound-deg", "0.5", "0.5"]
    elif case == "unit":
        argv += ["--unit", "furlong"]
    elif case == "field":
        argv += ["--field", "0"]
    elif case == "out-folder":
        argv += ["-o", str(tmp_path / "no" / "out.json")]
    code, out, err = _run(argv, capsys)
    assert code == 2 and out == ""
    message = err.strip().splitlines()
    assert message and message[0].startswith("nlpcal orthogonality") and len(message) <= 2


def test_cli_invert_solve_failure_exits_1_and_keeps_existing_output(tmp_path, capsys, monkeypatch):
    log = _write_log(tmp_path / "rot.csv", PAPER_ANGLES, n=60)
    out_path = tmp_path / "angles.json"
    out_path.write_text("previous\n")
    monkeypatch.setattr(inversion_module, "solve", _failing_solve)
    code, out, err = _run(["orthogonality", "invert", str(log), "-o", str(out_path)], capsys)
    assert code == 1 and "Maximum_Iterations_Exceeded" in err and str(log) in err
    assert out_path.read_text() == "previous\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["angles.json", "rot.csv"]


def test_cli_missing_subcommand_exits_2(capsys):
    code, out, err = _run(["orthogonality"], capsys)
    assert code == 2


def test_cli_verbose_sends_ipopt_log_to_stderr(tmp_path, capsys):
    log = _write_log(tmp_path / "rot.csv", PAPER_ANGLES, n=60)
    code, out, err = _run(["orthogonality", "invert", str(log), "-v"], capsys)
    assert code == 0 and "EXIT" in err
    assert json.loads(out)["status"] == "Solve_Succeeded"  # stdout holds only the JSON


def test_invert_reads_the_unit_from_the_column_names_and_flags_near_bound_solutions(
    tmp_path, capsys
):
    # Angles well outside the default +-0.5 deg bound, log in uT by its column names.
    rng = np.random.default_rng(21)
    v = rng.standard_normal((1500, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    a, b, g = np.radians([-2.0, -1.5, 1.0])
    T = np.array(
        [
            [np.cos(a) * np.cos(g), np.cos(a) * np.sin(g), -np.sin(a)],
            [0.0, np.cos(b), np.sin(b)],
            [0.0, 0.0, 1.0],
        ]
    )
    out = 49000.0 * v @ T.T / 1000.0
    path = tmp_path / "rot_ut.csv"
    pd.DataFrame(out, columns=["mx_uT", "my_uT", "mz_uT"]).to_csv(path, index=False)
    result_path = tmp_path / "inv.json"
    code = main(["orthogonality", "invert", str(path), "--field", "49000", "-o", str(result_path)])
    err = capsys.readouterr().err
    assert code == 0
    assert "unit uT taken from the column names" in err
    document = json.loads(result_path.read_text())
    assert all(document["bound_active"])
    assert "objective" in document
    assert "bound" in err


def test_invert_fails_when_offsets_and_scales_were_not_removed(tmp_path, capsys):
    # 80-120 nT offsets and 0.5 % scale errors, 1 nT of noise: three angles cannot explain the
    # data; the forward model is the tests' own (tests/synthetic.py, Eq. 4 typed in again)
    angles = {"alpha_deg": 0.07, "beta_deg": 0.04, "gamma_deg": 0.1}
    dirty = {"z_x": 80.0, "z_y": -120.0, "z_z": 100.0, "s_x": 0.005, "s_y": -0.005, "s_z": 0.005}
    samples = make_log(n=2000, noise=1.0, seed=8, truth={**dirty, **angles}, field=FIELD)[0]
    with pytest.raises(QualityError) as caught:
        ortho.invert(samples)
    assert caught.value.status == "Model_Unexplained"
    assert "calibrate first" in caught.value.reason
    assert caught.value.overrides == {"require_explained": False}
    kept = ortho.invert(samples, require_explained=False)
    assert any("do not explain" in w for w in kept.warnings)
    path = tmp_path / "dirty.csv"
    pd.DataFrame(samples, columns=["bx_nT", "by_nT", "bz_nT"]).to_csv(path, index=False)
    out = tmp_path / "angles.json"
    assert main(["orthogonality", "invert", str(path), "-o", str(out)]) == 1
    assert "calibrate first" in capsys.readouterr().err and not out.exists()
    # the same probe with offsets and scales removed: the angles within their standard errors
    clean = {name: 0.0 for name in dirty}
    samples = make_log(n=2000, noise=1.0, seed=8, truth={**clean, **angles}, field=FIELD)[0]
    result = ortho.invert(samples)
    assert not result.warnings
    errors = np.asarray(result.angles_std_deg)
    assert (np.abs(result.angles_deg - list(angles.values())) < 4 * errors).all()
