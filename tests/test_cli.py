"""The core commands through main(argv): simulate, calibrate, apply, stats, and their errors."""

import json

import numpy as np
import pandas as pd
import pytest

from nlpcal.cli import main
from nlpcal.models.zhou2010 import Zhou2010Parameters, correct
from resolution import assert_same_optimum
from synthetic import PAPER_FIELD, PAPER_TRUTH, make_log


@pytest.fixture(scope="module")
def log_csv(tmp_path_factory):
    samples, _ = make_log(n=2500, noise=2.5, seed=31)
    path = tmp_path_factory.mktemp("logs") / "log.csv"
    frame = pd.DataFrame(samples, columns=["bx", "by", "bz"])
    frame["proton_nT"] = PAPER_FIELD
    frame["note"] = "lab"
    frame.to_csv(path, index=False)
    return path


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("method", ["staged", "joint"])
def test_calibrate_recovers_the_truth(log_csv, tmp_path, capsys, method):
    out_path = tmp_path / "params.json"
    code, out, err = run(capsys, "calibrate", log_csv, "--method", method, "-o", out_path)
    assert code == 0 and out == ""
    assert "measured" in err and "note: no reference field" in err
    # the verdict comes before the rest of the summary; the gauge is a note, not a warning
    summary = err[err.index("nlpcal: verdict: ") :]
    assert summary.startswith("nlpcal: verdict: ok") and "warning: no reference" not in err
    assert err.count("note: no reference field") == 1
    doc = json.loads(out_path.read_text())
    assert set(doc["parameters"]) == set(PAPER_TRUTH)
    for row in doc["statistics"]:  # rows from the moments leave out max, min and range
        exact = {"max", "min", "range"} if not row.get("from_moments") else set()
        assert {"label", "mean", "std", *exact} <= set(row)
    assert doc["statistics"][0]["label"] == "measured"
    assert doc["method"] == method and doc["unit"] == "nT" and doc["format_version"] == 2
    assert doc["gauge"]["constraint"] == "s_x + s_y + s_z = 0"
    solver = doc["solver"]
    assert solver["finished_by"] in ("ipopt", "newton")
    if solver["finished_by"] == "ipopt":  # IPOPT's status, nlpcal's beside it when it decided
        assert solver["ipopt_status"] in (
            "Solve_Succeeded",
            "Solved_To_Acceptable_Level",
            "Search_Direction_Becomes_Too_Small",
        )
    # The joint solve may start at its optimum (the algebraic fit): a Newton step finishes it,
    # IPOPT does not run, and its status is nlpcal's own.
    assert solver["iterations"] > 0 or solver["nlpcal_status"] == "At_Stationary_Point"
    p = doc["parameters"]
    for k in ("z_x", "z_y", "z_z"):
        assert abs(p[k] - PAPER_TRUTH[k]) < 0.5
    g, t = (
        np.array([1 + p[f"s_{a}"] for a in "xyz"]),
        np.array([1 + PAPER_TRUTH[f"s_{a}"] for a in "xyz"]),
    )
    np.testing.assert_allclose(g / g[0], t / t[0], atol=2e-5)
    for k in ("alpha_deg", "beta_deg", "gamma_deg"):
        assert abs(p[k] - PAPER_TRUTH[k]) < 1e-3


def test_calibrate_with_a_reference_identifies_the_scales(log_csv, tmp_path, capsys):
    for flags in (["--reference-field", PAPER_FIELD], ["--reference-column", "proton_nT"]):
        out_path = tmp_path / "p.json"
        code, _, err = run(
            capsys, "calibrate", log_csv, *flags, "--method", "joint", "-o", out_path
        )
        assert code == 0, err
        doc = json.loads(out_path.read_text())
        assert "gauge" not in doc  # no gauge: left out, never null
        for k in ("s_x", "s_y", "s_z"):
            assert abs(doc["parameters"][k] - PAPER_TRUTH[k]) < 2e-5
    assert doc["reference"]["column"] == "proton_nT"


def test_calibrate_to_stdout_and_in_microtesla(log_csv, tmp_path, capsys):
    frame = pd.read_csv(log_csv)
    frame[["bx", "by", "bz"]] /= 1000.0
    frame = frame.rename(columns={"bx": "mag_x", "by": "mag_y", "bz": "mag_z"})
    path = tmp_path / "ut.csv"
    frame.to_csv(path, index=False)
    code, out, _ = run(capsys, "calibrate", path, "--unit", "uT", "--method", "joint")
    assert code == 0
    doc = json.loads(out)
    assert doc["unit"] == "nT" and doc["input"]["log_unit"] == "uT"
    assert abs(doc["parameters"]["z_y"] - PAPER_TRUTH["z_y"]) < 0.5


def test_apply_reproduces_eq4_and_keeps_other_columns(log_csv, tmp_path, capsys):
    params = tmp_path / "p.json"
    assert run(capsys, "calibrate", log_csv, "--method", "joint", "-o", params)[0] == 0
    corrected = tmp_path / "c.csv"
    code, _, err = run(capsys, "apply", params, log_csv, "-o", corrected)
    assert code == 0, err
    out = pd.read_csv(corrected)
    raw = pd.read_csv(log_csv)
    assert list(out.columns) == ["bx", "by", "bz", "proton_nT", "note", "b_total", "valid"]
    assert (out["note"] == "lab").all() and (out["valid"] == 1).all()
    model = Zhou2010Parameters.from_dict(json.loads(params.read_text())["parameters"])
    expected = correct(raw[["bx", "by", "bz"]].to_numpy(), model)
    np.testing.assert_allclose(out[["bx", "by", "bz"]].to_numpy(), expected, rtol=1e-9)
    np.testing.assert_allclose(out["b_total"], np.linalg.norm(expected, axis=1), rtol=1e-9)
    assert out["b_total"].std() < 3.0


def test_stats_rows(log_csv, tmp_path, capsys):
    code, out, _ = run(capsys, "stats", log_csv, "--json")
    assert code == 0
    doc = json.loads(out)
    magnitude = np.linalg.norm(pd.read_csv(log_csv)[["bx", "by", "bz"]].to_numpy(), axis=1)
    row = doc["rows"][0]
    assert row["label"] == "measured"
    assert row["std"] == pytest.approx(magnitude.std(), rel=1e-9)
    assert row["range"] == pytest.approx(np.ptp(magnitude), rel=1e-12)
    params = tmp_path / "p.json"
    run(capsys, "calibrate", log_csv, "--method", "joint", "-o", params)
    code, out, _ = run(capsys, "stats", log_csv, "--params", params)
    assert code == 0 and "measured" in out and "corrected" in out


def test_simulate_preset_and_custom_truth(tmp_path, capsys):
    out = tmp_path / "sim.csv"
    assert run(capsys, "simulate", "-n", 300, "--noise", 0.5, "--seed", 4, "-o", out)[0] == 0
    frame = pd.read_csv(out)
    assert list(frame.columns) == ["bx", "by", "bz"] and len(frame) == 300
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"parameters": {**PAPER_TRUTH, "z_x": 500.0}, "field_nT": 30000}))
    out2 = tmp_path / "sim2.csv"
    assert run(capsys, "simulate", "--params", truth, "-n", 2000, "--noise", 0, "-o", out2)[0] == 0
    code, text, _ = run(capsys, "calibrate", out2, "--method", "joint", "--reference-field", 30000)
    assert code == 0
    assert json.loads(text)["parameters"]["z_x"] == pytest.approx(500.0, abs=1e-6)
    # Same seed, same log.
    run(capsys, "simulate", "-n", 300, "--noise", 0.5, "--seed", 4, "-o", tmp_path / "again.csv")
    assert (tmp_path / "again.csv").read_text() == out.read_text()


def test_python_dash_m(log_csv):
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "nlpcal", "stats", str(log_csv)], capture_output=True, text=True
    )
    assert done.returncode == 0 and "measured" in done.stdout


# --- errors ---------------------------------------------------------------------------------


def write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


def good_rows(n=30, seed=0):
    samples, _ = make_log(n=n, noise=1.0, seed=seed)
    return "\n".join(",".join(f"{v:.3f}" for v in row) for row in samples)


@pytest.mark.parametrize(
    "name, text, extra, message",
    [
        ("missing.csv", None, [], "no such file"),
        ("empty.csv", "", [], "empty"),
        ("text.csv", "bx,by,bz\n" + good_rows() + "\n1,abc,3\n", [], "non-numeric"),
        ("nan.csv", "bx,by,bz\n" + good_rows() + "\n1,,3\n", [], "non-numeric"),
        ("few.csv", "bx,by,bz\n1,2,3\n4,5,6\n7,8,9\n", [], "at least 10"),
        ("nocols.csv", "a,b,c\n" + good_rows(), [], "no magnetometer columns"),
        (
            "ambig.csv",
            "bx,by,bz,x,y,z\n" + "\n".join(r + "," + r for r in good_rows().split("\n")),
            [],
            "ambiguous",
        ),
        ("equal.csv", "bx,by,bz\n" + "\n".join(["1,2,3"] * 30), [], "all samples are equal"),
        ("cols.csv", "bx,by,bz\n" + good_rows(), ["--columns", "bx", "by", "qq"], "'qq' not found"),
        (
            "refneg.csv",
            "bx,by,bz,f\n" + "\n".join(r + ",-5" for r in good_rows().split("\n")),
            ["--reference-column", "f"],
            "non-positive",
        ),
        ("refmiss.csv", "bx,by,bz\n" + good_rows(), ["--reference-column", "f"], "'f' not found"),
        ("badref.csv", "bx,by,bz\n" + good_rows(), ["--reference-field", "-3"], "positive"),
    ],
)
def test_calibrate_input_errors_exit_2(tmp_path, capsys, name, text, extra, message):
    path = tmp_path / name if text is None else write(tmp_path, name, text)
    code, out, err = run(capsys, "calibrate", path, *extra)
    assert code == 2
    assert message in err
    assert "Traceback" not in err and out == ""
    # one sentence for the error, last; warnings about the data (a unit that does not fit,
    # repeated rows) may come before it
    lines = err.strip().splitlines()
    assert lines[-1].startswith("nlpcal calibrate: error: ")
    assert all(line.startswith("nlpcal: ") for line in lines[:-1])


def test_drop_invalid_reports_the_count(tmp_path, capsys):
    path = write(tmp_path, "x.csv", "bx,by,bz\n" + good_rows(200) + "\n1,abc,3\n,,\n")
    code, out, err = run(capsys, "calibrate", path, "--drop-invalid", "--method", "joint")
    assert code == 0 and "dropped 2 row(s)" in err
    assert json.loads(out)["input"]["rows_dropped"] == 2


def test_usage_errors_exit_2(capsys, log_csv):
    assert run(capsys, "calibrate", log_csv, "--method", "cg")[0] == 2
    assert (
        run(
            capsys, "calibrate", log_csv, "--reference-field", 1, "--reference-column", "proton_nT"
        )[0]
        == 2
    )
    assert run(capsys, "frobnicate")[0] == 2
    assert run(capsys)[0] == 2
    assert run(capsys, "simulate", "--preset", "nope")[0] == 2
    assert run(capsys, "simulate", "-n", 0)[0] == 2
    assert run(capsys, "--version")[0] == 0


def test_apply_and_stats_errors(tmp_path, capsys, log_csv):
    bad = write(tmp_path, "bad.json", "{not json")
    code, _, err = run(capsys, "apply", bad, log_csv, "-o", tmp_path / "c.csv")
    assert code == 2 and "not a valid" in err
    wrong = write(tmp_path, "wrong.json", json.dumps({"hello": 1}))
    assert run(capsys, "apply", wrong, log_csv)[0] == 2
    assert run(capsys, "stats", tmp_path / "missing.csv")[0] == 2
    header_only = write(tmp_path, "header.csv", "bx,by,bz\n")
    code, _, err = run(capsys, "stats", header_only)
    assert code == 2 and "no data rows" in err
    assert not (tmp_path / "c.csv").exists()


def test_failed_solve_exits_1_and_keeps_the_old_output(tmp_path, capsys, log_csv, monkeypatch):
    from nlpcal.nlp import steps as problems
    from nlpcal.nlp.solver import SolveOutcome

    out_path = write(tmp_path, "p.json", "previous result\n")

    def failing(*args, **kwargs):
        return SolveOutcome(
            x=np.zeros(len(kwargs["x0"])),
            f=2.0,
            status="Restoration_Failed",
            success=False,
            iterations=3,
        )

    monkeypatch.setattr(problems, "solve", failing)
    code, _, err = run(capsys, "calibrate", log_csv, "-o", out_path)
    assert code == 1 and "Restoration_Failed" in err
    assert out_path.read_text() == "previous result\n"
    assert not list(tmp_path.glob(".p.json.*"))  # no temporary file left behind


def test_output_folder_missing_exits_2(tmp_path, capsys, log_csv):
    code, _, err = run(
        capsys, "calibrate", log_csv, "--method", "joint", "-o", tmp_path / "nope" / "p.json"
    )
    assert code == 2 and "does not exist" in err


def test_low_memory_gives_the_same_answer(log_csv, tmp_path, capsys):
    frame = pd.read_csv(log_csv)
    frame[["bx", "by", "bz", "proton_nT"]] /= 1000.0
    frame = frame.rename(columns={"proton_nT": "proton"})  # in the log's unit, uT
    path = tmp_path / "ut.csv"
    frame.to_csv(path, index=False)
    docs = []
    for extra in ([], ["--low-memory"]):
        code, out, err = run(
            capsys,
            "calibrate",
            path,
            "--unit",
            "uT",
            "--method",
            "joint",
            "--reference-column",
            "proton",
            *extra,
        )
        assert code == 0, err
        assert "pandas" in err and "engine" in err
        docs.append(json.loads(out))
    assert_same_optimum(docs[1]["parameters"], docs[0]["parameters"], docs[0]["standard_errors"])
    for name, error in docs[0]["standard_errors"].items():  # the scores' pass splits alike
        assert docs[1]["standard_errors"][name] == pytest.approx(error, rel=1e-6), name
    assert docs[1]["input"]["csv_engine"].startswith("c ")
    code, _, err = run(capsys, "calibrate", tmp_path / "missing.csv", "--low-memory")
    assert code == 2 and "no such file" in err


def test_unit_from_column_names(log_csv, tmp_path, capsys):
    frame = pd.read_csv(log_csv)[["bx", "by", "bz"]] / 1000.0
    frame.columns = ["Magnetometer X (uT)", "Magnetometer Y (uT)", "Magnetometer Z (uT)"]
    path = tmp_path / "named.csv"
    frame.to_csv(path, index=False)
    code, out, err = run(capsys, "calibrate", path, "--method", "joint")
    assert code == 0 and "unit uT taken from the column names" in err
    doc = json.loads(out)
    assert doc["input"]["log_unit"] == "uT"
    assert abs(doc["parameters"]["z_x"] - PAPER_TRUTH["z_x"]) < 0.5
    code, _, err = run(capsys, "calibrate", path, "--method", "joint", "--unit", "nT")
    assert code == 0 and "suggest uT, but --unit is nT" in err


def test_unidentifiable_log_exits_1_and_writes_nothing(tmp_path, capsys):
    from synthetic import planar_directions

    rng = np.random.default_rng(11)
    samples, _ = make_log(n=800, noise=1.0, seed=12, directions=planar_directions(800, rng))
    path = tmp_path / "planar.csv"
    pd.DataFrame(samples, columns=["bx", "by", "bz"]).to_csv(path, index=False)
    out_path = tmp_path / "p.json"
    code, _, err = run(capsys, "calibrate", path, "--reference-field", PAPER_FIELD, "-o", out_path)
    assert code == 1
    assert "quality check failed" in err or "solve failed" in err
    assert "rotate the sensor through more attitudes" in err
    assert not out_path.exists()
    constant = tmp_path / "constant.csv"
    frame = pd.DataFrame(samples, columns=["bx", "by", "bz"])
    frame["bz"] = 5.0
    frame.to_csv(constant, index=False)
    code, _, err = run(capsys, "calibrate", constant)
    assert code == 2 and "constant" in err


def test_apply_keeps_other_columns_exactly(log_csv, tmp_path, capsys):
    frame = pd.read_csv(log_csv)
    frame.insert(0, "unix_time", 1700000000.002 + np.arange(len(frame)) * 0.001)
    path = tmp_path / "timed.csv"
    frame.to_csv(path, index=False)
    params = tmp_path / "p.json"
    assert run(capsys, "calibrate", path, "--method", "joint", "-o", params)[0] == 0
    assert run(capsys, "apply", params, path, "-o", tmp_path / "c.csv")[0] == 0

    def times(csv):  # the text of the column, as written
        return pd.read_csv(csv, dtype={"unix_time": str})["unix_time"].tolist()

    assert times(tmp_path / "c.csv") == times(path)


def test_units_of_reference_column_and_applied_log(log_csv, tmp_path, capsys):
    # Field in uT (by the column names), proton reference in nT (by its name).
    frame = pd.read_csv(log_csv)
    frame[["bx", "by", "bz"]] /= 1000.0
    frame = frame.rename(columns={"bx": "mx_uT", "by": "my_uT", "bz": "mz_uT"})
    path = tmp_path / "mixed.csv"
    frame[["mx_uT", "my_uT", "mz_uT", "proton_nT"]].to_csv(path, index=False)
    params = tmp_path / "p.json"
    code, _, err = run(
        capsys,
        "calibrate",
        path,
        "--reference-column",
        "proton_nT",
        "--method",
        "joint",
        "-o",
        params,
        "--low-memory",
    )
    assert code == 0, err
    assert "read in nT" in err
    doc = json.loads(params.read_text())
    for k in ("s_x", "s_y", "s_z"):
        assert abs(doc["parameters"][k] - PAPER_TRUTH[k]) < 2e-5
    # Parameters from the uT log applied to an nT log: the nT log's column names win over the
    # unit recorded with the parameters.
    nt_params = tmp_path / "nt.json"
    assert run(capsys, "calibrate", log_csv, "--method", "joint", "-o", nt_params)[0] == 0
    code, out, err = run(capsys, "apply", nt_params, path)
    assert code == 0 and "unit uT taken from the column names" in err
    corrected = pd.read_csv(__import__("io").StringIO(out))
    assert corrected["b_total"].std() < 3e-3  # in uT: 2.5 nT of noise


def test_the_help_names_the_columns_apply_writes():
    from nlpcal import correction
    from nlpcal.cli import apply

    assert (apply.TOTAL_COLUMN, apply.OUTLIER_COLUMN) == (
        correction.TOTAL_COLUMN,
        correction.OUTLIER_COLUMN,
    )


def test_no_command_writes_over_one_of_its_inputs(log_csv, tmp_path, capsys):
    folder = tmp_path / "work"
    folder.mkdir()
    log = folder / "log.csv"
    log.write_bytes(log_csv.read_bytes())
    params = folder / "params.json"
    assert run(capsys, "calibrate", log, "--method", "joint", "--unit", "nT", "-o", params)[0] == 0
    exported = folder / "cal.m"
    assert run(capsys, "export", params, "--format", "matlab", "-o", exported)[0] == 0
    attempts = [
        ("export", params, "--format", "matlab", "-o", params),
        ("import", exported, "--format", "matlab", "-o", exported),
        ("report", params, log, "-o", params),
        ("report", params, log, "-o", log),
        ("calibrate", log, "--method", "joint", "-o", folder / "p2.json", "--plot", log),
        ("calibrate", log, "--method", "joint", "-o", params, "--plot", params),
        ("apply", params, log, "-o", folder / "c.csv", "--plot", params),
        ("apply", params, folder / "*.csv", "-o", log),  # a pattern that matches the output
        ("apply", params, folder, "-o", log),  # a folder that holds it
    ]
    before = {p: p.read_bytes() for p in (log, params, exported)}
    for argv in attempts:
        code, out, err = run(capsys, *argv)
        assert code == 2 and "is also an input" in err, (argv, err)
        assert {p: p.read_bytes() for p in before} == before, argv
    # files of an input folder that are not logs are not inputs: a rerun may replace them
    for _ in range(2):
        code, _, err = run(capsys, "calibrate", folder, "--method", "joint", "-o", params)
        assert code == 0, err


def test_stats_says_when_the_reference_is_not_the_calibrations(log_csv, tmp_path, capsys):
    params = tmp_path / "p.json"
    argv = ("calibrate", log_csv, "--method", "joint", "--reference-field", PAPER_FIELD)
    assert run(capsys, *argv, "-o", params)[0] == 0
    code, _, err = run(
        capsys, "stats", log_csv, "--params", params, "--reference-column", "proton_nT"
    )
    assert code == 0 and "the calibration was made against" not in err
    other = tmp_path / "other.csv"
    frame = pd.read_csv(log_csv)
    frame["proton_nT"] = PAPER_FIELD * 1.02
    frame.to_csv(other, index=False)
    code, _, err = run(
        capsys, "stats", other, "--params", params, "--reference-column", "proton_nT"
    )
    assert code == 0 and "(2.0% apart): the corrected row's RMSE includes that difference" in err


def test_the_version_is_written_once():
    from importlib import metadata

    import nlpcal

    try:
        installed = metadata.version("nlpcal")
    except metadata.PackageNotFoundError:
        pytest.skip("nlpcal is not installed")
    assert installed == nlpcal.__version__  # pyproject.toml reads it from nlpcal/version.py


def test_sigterm_during_an_ipopt_solve_is_a_termination():
    # CasADi checks for signals while IPOPT runs; the one it catches must come back as the
    # command line's Terminated (exit 143, "terminated"), not as an internal error. No clock
    # decides when the signal comes: IPOPT's first iteration callback says it is running, and a
    # thread sends SIGTERM then. The callback runs once (its step is 10^9 iterations) and the
    # thread needs the GIL, which the callback holds until it returns (no forced switch within
    # a switch interval of 1000 s), so the signal always lands in IPOPT's own iterations. The
    # solve cannot end by itself first: no tolerance is reachable, acceptable points do not
    # count, and only its wall-time limit (60 s, a hang's guard) would stop it.
    import os
    import signal
    import sys
    import threading

    import casadi as ca

    from nlpcal.cli import Terminated, _terminate
    from nlpcal.nlp.solver import IpoptOptions, solve

    n = 400
    x, p = ca.SX.sym("x", n), ca.SX.sym("p")
    rosenbrock = 100 * ca.sum1((x[1:] - x[:-1] ** 2) ** 2) + ca.sum1((1 - x) ** 2) + p
    running, stop = threading.Event(), threading.Event()

    class Running(ca.Callback):
        """IPOPT's iteration callback: sets `running`."""

        def __init__(self):
            ca.Callback.__init__(self)
            self.construct("running", {})

        def get_n_in(self):
            return ca.nlpsol_n_out()

        def get_n_out(self):
            return 1

        def get_name_in(self, i):
            return ca.nlpsol_out(i)

        def get_sparsity_in(self, i):
            size = {"x": n, "lam_x": n, "f": 1, "p": 1, "lam_p": 1}.get(ca.nlpsol_out(i), 0)
            return ca.Sparsity.dense(size) if size else ca.Sparsity(0, 0)

        def eval(self, arg):
            running.set()
            return [0]

    callback = Running()
    settings = IpoptOptions(
        tol=1e-300,
        acceptable_iter=0,
        max_iter=10**9,
        extra=(("hessian_approximation", "limited-memory"), ("max_wall_time", 60.0)),
    ).as_casadi()
    settings.update(iteration_callback=callback, iteration_callback_step=10**9)
    solver = ca.nlpsol("endless", "ipopt", {"x": x, "f": rosenbrock, "p": p}, settings)

    def terminate_when_running():
        running.wait()
        if not stop.is_set():
            os.kill(os.getpid(), signal.SIGTERM)

    previous = signal.signal(signal.SIGTERM, _terminate)
    interval = sys.getswitchinterval()
    sender = threading.Thread(target=terminate_when_running, daemon=True)
    try:
        sys.setswitchinterval(1000.0)
        sender.start()
        with pytest.raises(Terminated):
            solve(solver, x0=np.full(n, -1.2), p=0.0)
    finally:
        sys.setswitchinterval(interval)
        stop.set()  # the sender never waits past the test
        running.set()
        sender.join()
        signal.signal(signal.SIGTERM, previous)


def test_ctrl_c_as_the_command_line_is_read_is_one_line(monkeypatch, capsys):
    """A Ctrl-C before any command starts (its parser is built from every subcommand's module)
    is "interrupted", exit 130, as anywhere later, not a traceback."""
    from nlpcal import cli

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["calibrate", "log.csv"]) == 130
    assert capsys.readouterr().err == "nlpcal: interrupted\n"


def test_a_ctrl_c_that_casadi_hands_back_wrapped_is_an_interruption(monkeypatch, capsys):
    """numpy reading a CasADi result runs CasADi's Python code from C++; a Ctrl-C there comes
    back as a SystemError caused by the KeyboardInterrupt: "interrupted", not an internal
    error."""
    from nlpcal import cli

    def wrapped():
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as interruption:
            raise SystemError(
                "<function DM.__array__> returned a result with an exception set"
            ) from interruption

    monkeypatch.setattr(cli, "_check_environment", wrapped)
    assert cli.main(["simulate", "-n", "10"]) == 130
    assert capsys.readouterr().err == "nlpcal simulate: interrupted\n"
