"""The solver report: what finished each block solve, IPOPT's statuses apart from nlpcal's, IPOPT's
options recorded and settable, the reweighting limit said, `compare` and `calibrate` alike."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import nlpcal
import nlpcal.calibration.joint as joint_module
from nlpcal.calibration.result import BlockSolve, SolverReport
from nlpcal.cli import main
from nlpcal.comparison.conjugate_gradient import CGOptions
from nlpcal.errors import InputError, SolveError
from nlpcal.nlp.solver import FINISHERS, NLPCAL_STATUSES, SUCCESS_STATUSES, ipopt_value
from synthetic import make_log

BUNDLED = Path(__file__).resolve().parents[1] / "data" / "example_zhou2010.csv"


@pytest.fixture(scope="module")
def samples():
    return make_log(n=2000, noise=2.5, seed=5)[0]


@pytest.fixture(scope="module")
def log_csv(tmp_path_factory, samples):
    path = tmp_path_factory.mktemp("report") / "log.csv"
    pd.DataFrame(samples, columns=["bx", "by", "bz"]).to_csv(path, index=False)
    return path


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_the_bundled_joint_solve_is_finished_by_a_newton_step_not_ipopt(capsys):
    code, out, _ = run(capsys, "calibrate", BUNDLED, "--method", "joint")
    assert code == 0
    solver = json.loads(out)["solver"]
    assert solver["start"] == "algebraic" and solver["finished_by"] == "newton"
    assert solver["nlpcal_status"] == "At_Stationary_Point"
    assert "ipopt_status" not in solver  # IPOPT never ran, so it has no status
    assert solver["iterations"] == 0 and solver["ipopt_solves"] == 0
    (stage,) = solver["stages"]
    assert stage["finished_by"] == "newton" and "ipopt_status" not in stage
    assert "name" not in solver and "status" not in solver  # the names that said "ipopt"


def test_an_ipopt_finished_solve_reports_ipopts_status_and_iterations(samples):
    result = nlpcal.calibrate(samples)  # the first orthogonal stage starts far from its optimum
    first = result.solver.stages[0]
    assert first.finished_by == "ipopt" and first.ipopt_status in SUCCESS_STATUSES
    assert first.iterations > 0 and first.nlpcal_status is None
    document = result.to_dict()["solver"]
    assert document["stages"][0]["ipopt_status"] == first.ipopt_status
    assert document["ipopt_solves"] == sum(s.ipopt_status is not None for s in result.solver.stages)
    assert document["iterations"] == sum(s.iterations for s in result.solver.stages)
    for stage in document["stages"]:
        assert stage["finished_by"] in FINISHERS
        assert stage.get("nlpcal_status", NLPCAL_STATUSES[0]) in NLPCAL_STATUSES
        assert stage.get("ipopt_status") not in NLPCAL_STATUSES  # never shares a name


def test_compare_and_calibrate_report_the_joint_solve_the_same_way(log_csv, tmp_path, capsys):
    out = tmp_path / "compare.json"
    assert run(capsys, "compare", log_csv, "--cycles", "3", "-q", "-o", out)[0] == 0
    joint_row = json.loads(out.read_text())["joint"]
    # compare starts the joint solve where the conjugate gradient starts (the sphere fit)
    assert joint_row["start"] == "sphere"
    code, text, _ = run(capsys, "calibrate", log_csv, "--method", "joint", "-q")
    solver = json.loads(text)["solver"]
    assert solver["start"] == "algebraic"
    summary_keys = {"start", "finished_by", "iterations", "ipopt_solves"}
    assert summary_keys <= set(joint_row) and summary_keys <= set(solver)
    # the same solve reported the same way: run the joint solve from the sphere fit as compare
    # does, and its report's summary is compare's row
    from nlpcal.calibration.joint import joint_start, run_joint
    from nlpcal.calibration.problem import Problem
    from nlpcal.moments import accumulate

    samples = pd.read_csv(log_csv).to_numpy()
    problem = Problem(samples=samples, reference=None, moments=accumulate(samples, None))
    _, _, report = run_joint(problem, joint_start(problem.moments), "sphere")
    assert {k: joint_row[k] for k in report.summary()} == report.summary()


def test_ipopt_options_are_recorded_and_effective(samples, log_csv, tmp_path, capsys):
    result = nlpcal.calibrate(samples, ipopt_options={"max_iter": 1})
    assert result.solver.ipopt_options["max_iter"] == 1
    ran = [s for s in result.solver.stages if s.ipopt_status is not None]
    assert ran and all(s.iterations <= 1 for s in ran)
    # the first stage needs more than one iteration: IPOPT stops, Newton steps finish it
    first = result.solver.stages[0]
    assert first.ipopt_status == "Maximum_Iterations_Exceeded"
    assert first.finished_by == "newton" and first.nlpcal_status == "At_Data_Resolution"
    default = nlpcal.calibrate(samples)
    assert default.solver.stages[0].iterations > 1  # so max_iter=1 did change the solve
    assert default.solver.ipopt_options["max_iter"] == 200
    out = tmp_path / "p.json"
    argv = ["calibrate", log_csv, "-q", "-o", out]
    options = ["--ipopt-option", "max_iter=1", "--ipopt-option", "mu_strategy=adaptive"]
    assert run(capsys, *argv, *options)[0] == 0
    recorded = json.loads(out.read_text())["solver"]["ipopt_options"]
    assert recorded["max_iter"] == 1 and recorded["mu_strategy"] == "adaptive"
    assert nlpcal.CalibrationResult.load(out).solver.ipopt_options == recorded


def test_an_iteration_limit_the_user_set_is_named_as_the_cause(samples):
    with pytest.raises(SolveError) as failure:
        nlpcal.calibrate(samples, ipopt_options={"max_iter": 0})
    assert failure.value.status == "Maximum_Iterations_Exceeded"
    assert "max_iter 0" in str(failure.value) and "coverage" not in str(failure.value)
    assert failure.value.identifiability is None  # no diagnosis of the data was needed


@pytest.mark.parametrize(
    "option",
    ["no_such_option=1", "mu_strategy=sideways", "max_iter=-3", "tol=abc", "max_iter", "=3"],
)
def test_a_bad_ipopt_option_is_exit_2_with_nothing_written(option, log_csv, tmp_path, capsys):
    out = tmp_path / "p.json"
    code, stdout, err = run(capsys, "calibrate", log_csv, "--ipopt-option", option, "-o", out)
    assert code == 2 and not out.exists() and stdout == ""
    assert "Traceback" not in err and len(err.strip().splitlines()) <= 3


def test_a_bad_ipopt_option_in_python_is_an_input_error(samples):
    with pytest.raises(InputError, match="no_such_option"):
        nlpcal.calibrate(samples, ipopt_options={"no_such_option": 1})


def test_ipopt_option_values_are_typed_as_ipopt_types_them():
    assert ipopt_value("50") == 50 and isinstance(ipopt_value("50"), int)
    assert ipopt_value("1e-8") == 1e-8 and isinstance(ipopt_value("1e-8"), float)
    assert ipopt_value("adaptive") == "adaptive"


@pytest.fixture(scope="module")
def spiked(samples):
    rng = np.random.default_rng(3)
    spiked = samples.copy()
    rows = rng.choice(len(spiked), 100, replace=False)
    spiked[rows] += rng.normal(0.0, 2000.0, (100, 3))
    return spiked


def test_robust_reweighting_stopped_at_its_limit_is_a_warning(spiked, monkeypatch):
    settled = nlpcal.calibrate(spiked, method="joint", loss="huber")
    assert settled.solver.stop_reason == "solved"
    assert not any("reweighting" in w for w in settled.warnings)
    needed = len(settled.solver.stages) - 1
    assert needed > 2
    monkeypatch.setattr(joint_module, "MAX_REWEIGHTS", 2)
    stopped = nlpcal.calibrate(spiked, method="joint", loss="huber")
    assert stopped.solver.stop_reason == "reweighting_limit"
    assert len(stopped.solver.stages) == 3
    assert any("reweighting stopped at its limit" in w for w in stopped.warnings)


def test_a_0_1_0_solver_block_is_read_with_its_statuses_told_apart():
    old = {
        "name": "ipopt",
        "status": "At_Stationary_Point",
        "success": True,
        "iterations": 0,
        "stop_reason": "solved",
        "converged": True,
        "stages": [
            {"cycle": 1, "stage": "orthogonal", "status": "Solve_Succeeded", "iterations": 4},
            {"cycle": 1, "stage": "joint", "status": "At_Stationary_Point", "iterations": 0},
        ],
    }
    report = SolverReport.from_dict(old)
    first, last = report.stages
    assert (first.finished_by, first.ipopt_status, first.nlpcal_status) == (
        "ipopt",
        "Solve_Succeeded",
        None,
    )
    assert (last.finished_by, last.ipopt_status, last.nlpcal_status) == (
        "newton",
        None,
        "At_Stationary_Point",
    )
    assert report.iterations == 4
    assert BlockSolve.from_dict(last.to_dict()) == last  # the new form reads back as written


def test_a_bad_ipopt_option_stops_a_batch_before_any_log(log_csv, tmp_path, capsys):
    out_dir = tmp_path / "fleet"
    argv = ["batch", "calibrate", log_csv, "--out-dir", out_dir, "--ipopt-option", "bogus=1"]
    code, _, err = run(capsys, *argv)
    assert code == 2 and not out_dir.exists() and "bogus" in err


def test_ipopts_own_log_never_mixes_with_the_document_on_stdout(log_csv, capsys):
    code, out, err = run(capsys, "calibrate", log_csv, "--ipopt-option", "print_level=5")
    assert code == 0
    assert json.loads(out)["solver"]["ipopt_options"]["print_level"] == 5
    assert "Ipopt" in err  # IPOPT's log went to stderr


def test_compare_takes_ipopt_options_and_records_them_as_calibrate_does(
    samples, log_csv, tmp_path, capsys
):
    settings = nlpcal.CompareSettings(cycles=2, cg=CGOptions(max_iter=20))
    limited = nlpcal.compare(samples, settings=settings, ipopt_options={"max_iter": 1})
    assert limited.ipopt_options["max_iter"] == 1
    assert (
        limited.ipopt_options
        == nlpcal.calibrate(samples, ipopt_options={"max_iter": 1}).solver.ipopt_options
    )
    # the joint solve needs more than one iteration: IPOPT stopped at the limit
    assert limited.joint["ipopt_status"] == "Maximum_Iterations_Exceeded"
    default = nlpcal.compare(samples, settings=settings)
    assert default.ipopt_options["max_iter"] == 200 and default.joint["iterations"] > 1
    document = limited.to_dict()
    assert document["settings"]["ipopt_options"] == limited.ipopt_options
    assert nlpcal.Comparison.from_dict(document).ipopt_options == limited.ipopt_options
    with pytest.raises(InputError, match="no_such_option"):
        nlpcal.compare(samples, settings=settings, ipopt_options={"no_such_option": 1})
    out = tmp_path / "compare.json"
    argv = ["compare", log_csv, "--cycles", "2", "--cg-max-iter", "20", "-q", "-o", out]
    assert run(capsys, *argv, "--ipopt-option", "max_iter=1")[0] == 0
    assert json.loads(out.read_text())["settings"]["ipopt_options"]["max_iter"] == 1
    bad = tmp_path / "bad.json"
    code, stdout, err = run(capsys, "compare", log_csv, "--ipopt-option", "no_such=1", "-o", bad)
    assert code == 2 and not bad.exists() and "Traceback" not in err


def test_a_solve_reports_its_wall_time_and_its_function_evaluations_alone():
    """`SolveOutcome` times the solver's call and the evaluations of the problem's functions in
    it: CasADi's timers run on across the calls of a built solver, and each outcome gets only
    its own share (the same solve twice costs about the same, not twice as much)."""
    import casadi as ca

    from nlpcal.nlp.solver import build_nlpsol, solve

    x, p = ca.MX.sym("x", 3), ca.MX.sym("p", 3)
    solver = build_nlpsol("timed", x, ca.sumsqr(x - p) + ca.sumsqr(x * x - 1.0), p)
    outcomes = [solve(solver, x0=np.full(3, 0.5), p=[1.0, 2.0, 3.0]) for _ in range(200)]
    assert len({o.iterations for o in outcomes}) == 1 and outcomes[0].iterations > 0
    for outcome in outcomes:
        assert 0.0 < outcome.evaluations_s < outcome.wall_s
    # a running total would make the k-th outcome's evaluations k times one solve's: their sum
    # 100 times the 200 calls' (the evaluations are 2-10 % of a call)
    assert sum(o.evaluations_s for o in outcomes) < sum(o.wall_s for o in outcomes)
