"""Fleets of logs: one output per log, a summary with every log's status, reruns that skip."""

import json
import os

import numpy as np
import pandas as pd
import pytest

import nlpcal
from nlpcal.batch import APPLY_COLUMNS, CALIBRATION_COLUMNS, calibrate_many, output_names
from nlpcal.cli import main
from nlpcal.models.zhou2010 import PARAMETER_NAMES
from synthetic import PAPER_FIELD, make_log, planar_directions

#: The summary's columns, as the command line documents them.
DOCUMENTED = [
    "log",
    "status",
    "verdict",
    "exit_status",
    "model",
    *[f"{name}{tail}" for name in PARAMETER_NAMES for tail in ("", "_se")],
    "std_measured",
    "std_corrected",
    "coverage_fraction",
    "warnings",
    "message",
    "unit",
    "unit_source",
    "n_samples",
    "output",
    "action",
    "seconds",
]


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def cone_directions(n, rng, half_angle_deg=10.0):
    """Directions within a cone about z: the attitudes of a sensor barely turned."""
    found = np.empty((0, 3))
    while len(found) < n:
        v = rng.standard_normal((20 * n, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        found = np.vstack([found, v[v[:, 2] > np.cos(np.radians(half_angle_deg))]])
    return found[:n]


def write(path, samples):
    pd.DataFrame(samples, columns=["bx", "by", "bz"]).to_csv(path, index=False)


@pytest.fixture
def fleet(tmp_path):
    folder = tmp_path / "fleet"
    folder.mkdir()
    for k in range(3):
        write(folder / f"sensor_{k}.csv", make_log(n=1200, noise=1.0, seed=300 + k)[0])
    rng = np.random.default_rng(5)
    flat, _ = make_log(n=1200, noise=1.0, seed=9, directions=planar_directions(1200, rng))
    write(folder / "sensor_flat.csv", flat)  # a turntable log: refused
    cone, _ = make_log(n=1200, noise=1.0, seed=9, directions=cone_directions(1200, rng))
    write(folder / "sensor_cone.csv", cone)  # solved, but z_z and s_z are not determined
    (folder / "sensor_text.csv").write_text("bx,by,bz\n1,2,3\n4,five,6\n")
    (folder / "sensor_cols.csv").write_text("a,b\n1,2\n")
    return folder


@pytest.mark.slow  # end to end, seconds
def test_one_bad_log_never_stops_the_others(fleet, tmp_path, capsys):
    out_dir = tmp_path / "out"
    code, out, err = run(capsys, "batch", "calibrate", fleet / "*.csv", "--out-dir", out_dir)
    assert code == 2 and out == "" and "Traceback" not in err
    summary = pd.read_csv(out_dir / "summary.csv")
    assert list(summary.columns) == DOCUMENTED == list(CALIBRATION_COLUMNS)
    by_log = summary.set_index(summary["log"].map(lambda p: os.path.basename(p)))
    expected = {
        "sensor_0.csv": ("ok", 0),
        "sensor_1.csv": ("ok", 0),
        "sensor_2.csv": ("ok", 0),
        "sensor_cols.csv": ("bad-input", 2),
        "sensor_cone.csv": ("quality-failed", 1),
        "sensor_text.csv": ("bad-input", 2),
    }
    # The turntable log is refused either by the quality check or, when the staged cycle
    # wandered along the blind directions first, by the failed solve (which of the two, the
    # floating-point kernel's rounding decides); exit 1 and the plane are the same either way.
    flat = by_log.loc["sensor_flat.csv"]
    assert flat["status"] in ("quality-failed", "solve-failed")
    expected["sensor_flat.csv"] = (flat["status"], 1)
    assert {log: (row.status, row.exit_status) for log, row in by_log.iterrows()} == expected
    assert list(summary["log"]) == sorted(summary["log"])  # the order of the logs
    ok = by_log.loc["sensor_0.csv"]
    result = nlpcal.CalibrationResult.load(out_dir / "sensor_0.params.json")
    for name in PARAMETER_NAMES:
        assert ok[name] == pytest.approx(result.parameters[name], rel=1e-15)
        assert ok[f"{name}_se"] == pytest.approx(result.standard_errors[name], rel=1e-15)
    assert ok["std_measured"] == pytest.approx(result.statistics[0]["std"], rel=1e-15)
    assert ok["std_corrected"] == pytest.approx(result.statistics[-1]["std"], rel=1e-15)
    assert ok["coverage_fraction"] == result.identifiability["coverage"]["fraction"]
    assert ok["n_samples"] == 1200 and ok["verdict"] == result.verdict.status
    cone = by_log.loc["sensor_cone.csv"]  # parameters in the summary, but no params.json
    assert "do not determine z_z, s_z" in cone["message"] and np.isfinite(cone["z_x"])
    assert cone["verdict"] == "failed" and flat["verdict"] == "failed"
    assert "lie in one plane" in flat["message"]
    if flat["status"] == "solve-failed":
        assert "solver status" in flat["message"] and np.isnan(flat["z_x"])
    assert "five" not in by_log.loc["sensor_text.csv", "message"]
    assert "non-numeric" in by_log.loc["sensor_text.csv", "message"]
    assert sorted(p.name for p in out_dir.iterdir()) == [
        "batch.json",
        "sensor_0.params.json",
        "sensor_1.params.json",
        "sensor_2.params.json",
        "summary.csv",
    ]
    refused = sum(status == "quality-failed" for status, _ in expected.values())
    assert "sensor_text.csv: bad-input" in err and f"quality-failed {refused}" in err


def test_a_rerun_skips_logs_whose_output_is_newer_unless_forced(fleet, tmp_path):
    out_dir = tmp_path / "out"
    first = calibrate_many(fleet, out_dir, options={"method": "joint"})
    written = {p.name: p.stat().st_mtime_ns for p in out_dir.glob("*.params.json")}
    os.utime(fleet / "sensor_1.csv")  # a log changed since its calibration
    seen = []
    again = calibrate_many(
        fleet, out_dir, options={"method": "joint"}, progress=lambda *a: seen.append(a[:2])
    )
    actions = {os.path.basename(r["log"]): r["action"] for r in again.rows}
    assert actions["sensor_0.csv"] == actions["sensor_2.csv"] == "skipped"
    assert actions["sensor_1.csv"] == "run" and actions["sensor_text.csv"] == "run"
    assert (out_dir / "sensor_0.params.json").stat().st_mtime_ns == written["sensor_0.params.json"]
    assert seen[-1] == (7, 7) and len(seen) == 5  # the five logs run, as each finished
    skipped = next(r for r in again.rows if r["log"].endswith("sensor_0.csv"))
    done = next(r for r in first.rows if r["log"].endswith("sensor_0.csv"))
    for key in ("z_x", "z_x_se", "std_corrected", "coverage_fraction", "warnings", "status"):
        assert skipped[key] == done[key]
    forced = calibrate_many(fleet, out_dir, options={"method": "joint"}, force=True)
    assert all(r["action"] == "run" for r in forced.rows)
    # The cone of directions fails its solve: the moment objective's series does not hold at the
    # start of the undetermined directions. The turntable log (its samples lie in one plane) is
    # refused by the quality check or by the failed solve, as in the first test.
    status = {os.path.basename(r["log"]): r["status"] for r in forced.rows}
    assert status["sensor_cone.csv"] == "solve-failed"
    assert status["sensor_flat.csv"] in ("quality-failed", "solve-failed")
    failed = {"solve-failed": 1}
    failed[status["sensor_flat.csv"]] = failed.get(status["sensor_flat.csv"], 0) + 1
    assert forced.exit_status == 2 and forced.counts() == {"ok": 3, "bad-input": 2, **failed}


def test_a_rerun_with_other_options_does_every_log_again(fleet, tmp_path):
    out_dir = tmp_path / "out"
    first = calibrate_many(fleet, out_dir, options={"method": "joint"})
    assert first.counts()["ok"] == 3
    again = calibrate_many(
        fleet, out_dir, options={"method": "joint"}, read_options={"reference_field": 50000.0}
    )
    assert all(r["action"] == "run" for r in again.rows)
    result = nlpcal.CalibrationResult.load(out_dir / "sensor_0.params.json")
    assert result.reference.mode == "constant"  # not the first run's parameters
    same = calibrate_many(
        fleet, out_dir, options={"method": "joint"}, read_options={"reference_field": 50000.0}
    )
    skipped = [r for r in same.rows if r["action"] == "skipped"]
    assert len(skipped) == 3 and all(r["status"] == "ok" for r in skipped)


def test_a_log_that_fails_now_loses_the_output_an_earlier_run_wrote(fleet, tmp_path):
    out_dir = tmp_path / "out"
    calibrate_many(fleet, out_dir, options={"method": "joint"})
    assert (out_dir / "sensor_1.params.json").exists()
    (fleet / "sensor_1.csv").write_text("bx,by,bz\n1,2,3\n")  # the log is replaced by a bad one
    again = calibrate_many(fleet, out_dir, options={"method": "joint"})
    row = next(r for r in again.rows if r["log"].endswith("sensor_1.csv"))
    assert row["status"] == "bad-input" and not (out_dir / "sensor_1.params.json").exists()
    third = calibrate_many(fleet, out_dir, options={"method": "joint"})
    row = next(r for r in third.rows if r["log"].endswith("sensor_1.csv"))
    assert row["status"] == "bad-input" and row["action"] == "run"


def test_a_broken_batch_record_means_every_log_again(fleet, tmp_path):
    out_dir = tmp_path / "out"
    calibrate_many(fleet, out_dir, options={"method": "joint"})
    (out_dir / "batch.json").write_text('{"format": "nlpcal-batch", "outputs": [1]}')
    again = calibrate_many(fleet, out_dir, options={"method": "joint"})
    assert all(r["action"] == "run" for r in again.rows)
    assert again.notes and "every log is done again" in again.notes[0]
    record = json.loads((out_dir / "batch.json").read_text())
    assert record["format_version"] == 1 and len(record["outputs"]) == 3


def test_a_fleet_on_dask_threads_gives_the_same_summary(fleet, tmp_path):
    pytest.importorskip("dask")
    here = calibrate_many(fleet, tmp_path / "a", options={"method": "joint"})
    there = calibrate_many(fleet, tmp_path / "b", options={"method": "joint"}, scheduler="threads")
    assert [r["status"] for r in there.rows] == [r["status"] for r in here.rows]
    for first, second in zip(here.rows, there.rows):
        if first["status"] == "ok":  # one IPOPT solve at a time: threads share no solver state
            assert second["z_x"] == first["z_x"] and second["s_y_se"] == first["s_y_se"]


def test_an_interrupted_batch_writes_the_summary_of_the_logs_done(fleet, tmp_path):
    def stop(done, total, row):
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        calibrate_many(fleet, tmp_path / "out", progress=stop)
    assert len(pd.read_csv(tmp_path / "out" / "summary.csv")) == 2


def test_batch_apply_corrects_each_log_as_apply_does(fleet, tmp_path, capsys):
    out_dir, corrected = tmp_path / "params", tmp_path / "corrected"
    run(capsys, "batch", "calibrate", fleet, "--out-dir", out_dir, "--method", "joint")
    code, out, err = run(
        capsys, "batch", "apply", out_dir, fleet, "--out-dir", corrected, "--flag-outliers"
    )
    assert code == 2 and "Traceback" not in err
    summary = pd.read_csv(corrected / "summary.csv")
    assert list(summary.columns) == list(APPLY_COLUMNS)
    status = dict(zip(summary["log"].map(os.path.basename), summary["status"]))
    assert status["sensor_0.csv"] == "ok" and status["sensor_flat.csv"] == "bad-input"
    assert status["sensor_cone.csv"] == "bad-input"  # quality-failed: no parameters written
    flat = summary[summary["log"].str.endswith("sensor_flat.csv")].iloc[0]
    assert "does not exist" in flat["message"]
    single = tmp_path / "single.csv"
    params = out_dir / "sensor_0.params.json"
    run(capsys, "apply", params, fleet / "sensor_0.csv", "--flag-outliers", "-o", single)
    pd.testing.assert_frame_equal(
        pd.read_csv(corrected / "sensor_0.corrected.csv"), pd.read_csv(single)
    )
    row = summary[summary["log"].str.endswith("sensor_0.csv")].iloc[0]
    b_total = pd.read_csv(single)["b_total"]
    assert row["std_corrected"] == pytest.approx(np.std(b_total), rel=1e-9)
    assert row["outliers"] == 0 and row["n_samples"] == 1200
    # One parameters file for every log: a Parquet log is written back as Parquet.
    pytest.importorskip("pyarrow")
    pd.read_csv(fleet / "sensor_2.csv").to_parquet(tmp_path / "sensor_2.parquet", index=False)
    code, _, err = run(
        capsys, "batch", "apply", params, tmp_path / "sensor_2.parquet", "--out-dir", corrected
    )
    assert code == 0, err
    written = pd.read_parquet(corrected / "sensor_2.corrected.parquet")
    assert written["b_total"].std() < 5.0  # corrected with another sensor's parameters


def test_output_names_are_the_logs_names_and_unique(tmp_path):
    paths = [
        tmp_path / "a" / "log.csv",
        tmp_path / "b" / "log.csv",
        tmp_path / "b" / "log.parquet",
        tmp_path / "b" / "other.csv.gz",
    ]
    names = output_names(paths)
    assert names[paths[3]] == "b__other"
    assert names[paths[0]] == "a__log"
    assert len(set(names.values())) == 4
    assert output_names([tmp_path / "x.csv", tmp_path / "y.csv"]) == {
        tmp_path / "x.csv": "x",
        tmp_path / "y.csv": "y",
    }


def test_a_reference_and_loss_reach_every_log(fleet, tmp_path):
    report = calibrate_many(
        [fleet / "sensor_0.csv", fleet / "sensor_1.csv"],
        tmp_path / "out",
        read_options={"reference_field": PAPER_FIELD},
        options={"method": "joint", "loss": "huber"},
    )
    assert report.exit_status == 0
    document = json.loads((tmp_path / "out" / "sensor_1.params.json").read_text())
    assert document["reference"] == {"mode": "constant", "field": PAPER_FIELD}
    assert document["robust"]["loss"] == "huber"


def test_batch_calibrate_takes_the_quality_overrides_of_calibrate(fleet, tmp_path, capsys):
    out_dir = tmp_path / "out"
    flat = fleet / "sensor_flat.csv"
    # With a reference field the joint solve converges on the turntable log; the plane fails the
    # quality check.
    options = ("--method", "joint", "--reference-field", str(PAPER_FIELD))
    code, _, _ = run(capsys, "batch", "calibrate", flat, "--out-dir", out_dir, *options)
    assert code == 1 and not (out_dir / "sensor_flat.params.json").exists()
    code, _, err = run(
        capsys,
        "batch",
        "calibrate",
        flat,
        "--out-dir",
        out_dir,
        *options,
        "--allow-unidentifiable",
        "--threads",
        "1",
    )
    assert code == 0 and (out_dir / "sensor_flat.params.json").exists()
    summary = pd.read_csv(out_dir / "summary.csv")
    assert "lie in one plane" in summary.loc[0, "warnings"]


def test_an_interrupted_rerun_leaves_no_output_marked_with_options_it_was_not_made_with(
    fleet, tmp_path
):
    out_dir = tmp_path / "out"
    calibrate_many(fleet, out_dir, options={"method": "joint"})

    def interrupt(done, total, row):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):  # the first log is redone with staged, then Ctrl-C
        calibrate_many(fleet, out_dir, options={"method": "staged"}, progress=interrupt)
    staged = nlpcal.CalibrationResult.load(out_dir / "sensor_0.params.json")
    assert staged.method == "staged"
    # the outputs the interrupted run meant to redo lost their entries before it started; the
    # one it rewrote is marked with its own options
    record = json.loads((out_dir / "batch.json").read_text())["outputs"]
    assert list(record) == ["sensor_0.params.json"]
    again = calibrate_many(fleet, out_dir, options={"method": "joint"})
    assert all(r["action"] == "run" for r in again.rows)
    assert nlpcal.CalibrationResult.load(out_dir / "sensor_0.params.json").method == "joint"


def test_an_output_counts_for_the_log_that_wrote_it_only(tmp_path):
    out_dir = tmp_path / "out"
    for k, folder in enumerate(("one", "two")):
        (tmp_path / folder).mkdir()
        write(tmp_path / folder / "sensor.csv", make_log(n=800, noise=1.0, seed=40 + k)[0])
    os.utime(tmp_path / "two" / "sensor.csv", (1e9, 1e9))  # older than any output (cp -p)
    first = calibrate_many(tmp_path / "one", out_dir, options={"method": "joint"})
    second = calibrate_many(tmp_path / "two", out_dir, options={"method": "joint"})
    assert second.rows[0]["action"] == "run"
    assert second.rows[0]["z_x"] != first.rows[0]["z_x"]
    threads = calibrate_many(tmp_path / "two", out_dir, options={"method": "joint", "threads": 1})
    assert threads.rows[0]["action"] == "skipped"  # threads do not change a result
