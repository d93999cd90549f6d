"""A reference with its own time base: `nlpcal.timing.reference_at` against functions it must
reproduce exactly (a line, a cubic), its gaps and span, and `--reference-log` end to end: a log
from the independent forward model in synthetic.py, with a field magnitude that changes in time,
calibrated against a scalar reference recorded at another rate on another clock's grid."""

from __future__ import annotations

import json
import sys

import numpy as np
import pandas as pd
import pytest
from test_observatory import iaga_text

from nlpcal.cli import main
from nlpcal.errors import InputError
from nlpcal.io import read_log
from nlpcal.io.reference import ReferenceLog
from nlpcal.timing import GAP_SAMPLES, interpolate_reference, reference_at, seconds
from synthetic import PAPER_FIELD, PAPER_TRUTH, make_log

#: A recovered parameter lies within this many of its standard errors of the truth. [1]
WITHIN_SE = 5.0
#: Interpolation of exact data is exact up to the rounding of a few operations on numbers of
#: order 1e4..1e5. [relative]
EXACT = 1e-12


def magnitude(t):
    """The field magnitude at time t [s]: slow sinusoids of 120 s and 45 s around 49 462 nT."""
    return PAPER_FIELD + 30.0 * np.sin(2 * np.pi * t / 120.0) + 8.0 * np.cos(2 * np.pi * t / 45.0)


# --- reference_at -------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["linear", "cubic"])
def test_a_polynomial_of_the_interpolation_degree_is_reproduced(kind):
    pytest.importorskip("scipy")
    rng = np.random.default_rng(1)
    times_ref = np.sort(rng.uniform(0.0, 100.0, 400))
    times_ref = times_ref[np.diff(times_ref, prepend=-1.0) > 0.05]  # no gaps at 3 median steps
    degree = 1 if kind == "linear" else 3

    def f(t):
        return 48_000.0 + 3.0 * t + (0.02 * t**2 - 1e-4 * t**3 if degree == 3 else 0.0)

    times = rng.uniform(times_ref[0], times_ref[-1], 1000)
    got = reference_at(times_ref, f(times_ref), times, kind, gap_samples=1e9)
    assert np.allclose(got, f(times), rtol=EXACT, atol=0)


def test_cubic_follows_a_smooth_field_closer_than_linear():
    pytest.importorskip("scipy")
    times_ref = np.arange(0.0, 600.0, 2.0)
    times = np.arange(1.0, 590.0, 0.1)
    error = {
        kind: np.abs(reference_at(times_ref, magnitude(times_ref), times, kind) - magnitude(times))
        for kind in ("linear", "cubic")
    }
    # linear: h^2/8 |f''| ~ 0.4 nT at 2 s steps; the spline's h^4 term is far smaller
    assert error["cubic"].max() < error["linear"].max() / 50


@pytest.mark.parametrize("kind", ["linear", "cubic"])
def test_outside_the_span_and_inside_a_gap_nothing_is_interpolated(kind):
    pytest.importorskip("scipy")
    times_ref = np.concatenate([np.arange(0.0, 50.0, 1.0), np.arange(60.0, 100.0, 1.0)])
    times = np.arange(-5.0, 105.0, 0.25)
    interpolated = interpolate_reference(times_ref, magnitude(times_ref), times, kind)
    values = interpolated.values
    outside = (times < 0.0) | (times > 99.0)
    in_gap = (times > 49.0) & (times < 60.0)
    assert np.isnan(values[outside | in_gap]).all()
    assert np.isfinite(values[~(outside | in_gap)]).all()
    assert interpolated.outside == outside.sum() and interpolated.in_gaps == in_gap.sum()
    assert interpolated.gaps == 1 and interpolated.step_s == 1.0
    at_samples = np.isin(times, times_ref)
    assert np.allclose(values[at_samples], magnitude(times[at_samples]), rtol=EXACT, atol=0)


def test_a_step_of_the_gap_limit_is_still_interpolated():
    times_ref = np.array([0.0, 1.0, 2.0, 2.0 + GAP_SAMPLES, 4.0 + GAP_SAMPLES, 5.0 + GAP_SAMPLES])
    got = reference_at(times_ref, times_ref * 2.0, [2.5, 3.5])
    assert np.allclose(got, [5.0, 7.0])


def test_reference_times_in_any_order_and_refusals():
    times_ref = np.array([3.0, 1.0, 2.0, 0.0])
    assert np.allclose(reference_at(times_ref, 10 * times_ref, [0.5, 2.5]), [5.0, 25.0])
    for bad_times, bad_values in (
        ([0.0, 1.0, 1.0, 2.0], [1.0, 2.0, 3.0, 4.0]),  # a time twice
        ([0.0, np.nan, 2.0], [1.0, 2.0, 3.0]),
        ([0.0, 1.0], [1.0, np.inf]),
        ([0.0], [1.0]),
        ([0.0, 1.0, 2.0], [1.0, 2.0]),
    ):
        with pytest.raises(InputError):
            reference_at(bad_times, bad_values, [0.5])
    with pytest.raises(InputError):
        reference_at([0.0, 1.0], [1.0, 2.0], [0.5], kind="nearest")


def test_cubic_without_scipy_names_its_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "scipy.interpolate", None)
    with pytest.raises(InputError, match=r"nlpcal\[spline\]"):
        reference_at([0.0, 1.0, 2.0, 3.0], [1.0, 2.0, 3.0, 5.0], [0.5], kind="cubic")


def test_seconds_of_iso_text_datetimes_and_numbers():
    iso = ["2024-05-10T00:00:00Z", "2024-05-10T00:00:01.5Z", "not a time"]
    unix = pd.Timestamp("2024-05-10").timestamp()
    assert np.allclose(seconds(iso)[:2], [unix, unix + 1.5]) and np.isnan(seconds(iso)[2])
    stamps = pd.Series(pd.to_datetime(iso[:2], utc=True, format="ISO8601"))
    assert np.allclose(seconds(stamps), [unix, unix + 1.5])
    assert np.allclose(seconds(["0.5", "1.25", "2"]), [0.5, 1.25, 2.0])


# --- --reference-log end to end -----------------------------------------------------------------


def timed_logs(tmp_path, n=3000, rate_hz=10.0, ref_step_s=0.37, ref_span=(-3.0, 280.0), gap=None):
    """A field log with ISO times (10 Hz) and a reference CSV with Unix times on its own grid,
    both from magnitude(t); the sensor sees it through the forward model in random attitudes."""
    t = np.arange(n) / rate_hz
    samples, _ = make_log(n=n, noise=1.0, seed=4, field=magnitude(t)[:, None])
    start = pd.Timestamp("2026-03-01T12:00:00Z")
    log = pd.DataFrame(samples, columns=["bx", "by", "bz"])
    log.insert(0, "utc", (start + pd.to_timedelta(t, unit="s")).strftime("%Y-%m-%dT%H:%M:%S.%fZ"))
    t_ref = np.arange(*ref_span, ref_step_s)
    if gap is not None:
        t_ref = t_ref[(t_ref < gap[0]) | (t_ref > gap[1])]
    reference = pd.DataFrame({"unix_s": start.timestamp() + t_ref, "proton_nT": magnitude(t_ref)})
    log.to_csv(tmp_path / "log.csv", index=False)
    reference.to_csv(tmp_path / "proton.csv", index=False)
    return tmp_path / "log.csv", tmp_path / "proton.csv", t


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_calibrate_against_a_reference_on_its_own_time_base(tmp_path, capsys):
    log, proton, t = timed_logs(tmp_path)
    output = tmp_path / "p.json"
    flags = ("--reference-log", proton, "--reference-column", "proton_nT",
             "--time-column", "utc", "--reference-time-column", "unix_s")  # fmt: skip
    code, _, err = run(capsys, "calibrate", log, *flags, "-o", output)
    assert code == 0, err
    document = json.loads(output.read_text())
    for name, value in PAPER_TRUTH.items():  # the scale too: the reference fixes it
        gap = abs(document["parameters"][name] - value) / document["standard_errors"][name]
        assert gap < WITHIN_SE, (name, document["parameters"][name], value)
    record = document["input"]["reference_log"]
    assert record["column"] == "proton_nT" and record["time_column"] == "unix_s"
    assert record["log_time_column"] == "utc" and record["interpolation"] == "linear"
    outside = int((t > 280.0 - 0.37).sum())  # the reference's last sample is before 280 s
    assert record["rows_outside_span"] == outside and document["n_samples"] == len(t) - outside
    assert document["input"]["rows_dropped"] == outside
    assert f"dropped {outside} row(s) of the log outside the span" in err
    code, out, err = run(capsys, "stats", log, "--params", output, *flags, "--json")
    assert code == 0, err
    rows = json.loads(out)["rows"]
    assert rows[-1]["rmse"] < 2.0  # about the 1 nT noise per axis, not the 30 nT field changes


def test_the_same_reference_read_as_a_column_per_row_is_worse_than_interpolated(tmp_path, capsys):
    """A reference at the log's rate that started 20 s earlier, pasted beside the log row by
    row (what a per-row column assumes), is 20 s off; interpolated onto the log's times it is
    not: the spread of the corrected |B1| left by each fit is compared."""
    log, proton, t = timed_logs(tmp_path, n=2000, ref_step_s=0.1, ref_span=(-20.0, 300.0))
    frame = pd.read_csv(log)
    reference = pd.read_csv(proton)
    frame["proton_nT"] = reference["proton_nT"].to_numpy()[: len(frame)]
    frame.to_csv(tmp_path / "pasted.csv", index=False)
    results = {}
    for name, argv in (
        ("pasted", (tmp_path / "pasted.csv", "--reference-column", "proton_nT")),
        ("interpolated", (log, "--reference-log", proton, "--reference-column", "proton_nT",
                          "--time-column", "utc", "--reference-time-column", "unix_s")),
    ):  # fmt: skip
        params = tmp_path / f"{name}.json"
        code, _, err = run(capsys, "calibrate", *argv, "--method", "joint", "-o", params)
        assert code in (0, 1), err
        code, out, err = run(capsys, "stats", *argv, "--params", params, "--json")
        assert code == 0, err
        results[name] = json.loads(out)["rows"][-1]["rmse"]  # |B1| against the reference [nT]
    assert results["interpolated"] < results["pasted"] / 3


def test_gaps_in_the_reference_and_cubic_interpolation(tmp_path, capsys):
    pytest.importorskip("scipy")
    log, proton, t = timed_logs(tmp_path, gap=(100.0, 110.0))
    output = tmp_path / "p.json"
    code, _, err = run(capsys, "calibrate", log, "--reference-log", proton, "--reference-column",
                       "proton_nT", "--time-column", "utc", "--reference-time-column", "unix_s",
                       "--interpolation", "cubic", "-o", output)  # fmt: skip
    assert code == 0, err
    record = json.loads(output.read_text())["input"]["reference_log"]
    assert record["interpolation"] == "cubic" and record["gaps"] == 1
    first, last = np.arange(-3.0, 280.0, 0.37)[[0, -1]]
    kept = np.arange(-3.0, 280.0, 0.37)
    kept = kept[(kept < 100.0) | (kept > 110.0)]
    before, after = kept[kept < 100.0][-1], kept[kept > 110.0][0]
    assert record["rows_in_gaps"] == int(((t > before) & (t < after)).sum())
    assert "not interpolated across" in err and first < 0 < last


def test_observatory_files_need_no_time_columns(tmp_path):
    """An IAGA-2002 vector log and the scalar from another IAGA-2002 file at a slower rate:
    both put their times in `time`, so no time column is named."""
    n = 600
    t = np.arange(n) * 1.0
    samples, _ = make_log(n=n, noise=1.0, seed=8, field=magnitude(t)[:, None])
    vector = {"X": samples[:, 0], "Y": samples[:, 1], "Z": samples[:, 2]}
    (tmp_path / "vector.sec").write_text(iaga_text(vector))
    scalar_t = np.arange(0, n, 5.0)
    (tmp_path / "scalar.sec").write_text(iaga_text({"F": magnitude(scalar_t)}, step_s=5.0))
    spec = ReferenceLog(path=str(tmp_path / "scalar.sec"), column="F")
    log = read_log(tmp_path / "vector.sec", reference_log=spec)
    assert log.n == n - 4  # after the scalar's last sample at 595 s
    assert np.allclose(log.reference, np.interp(t[: n - 4], scalar_t, magnitude(scalar_t)))
    assert log.reference_log["observatory"]["format"] == "IAGA-2002"


def test_reference_log_mistakes_are_one_sentence(tmp_path, capsys):
    log, proton, _ = timed_logs(tmp_path, n=300)
    far = tmp_path / "far.csv"
    pd.DataFrame({"unix_s": [0.0, 1.0, 2.0], "proton_nT": [5e4, 5e4, 5e4]}).to_csv(far)
    base = ("calibrate", log, "-o", tmp_path / "p.json")
    for argv in (
        (*base, "--reference-log", proton, "--time-column", "utc"),  # no column
        (*base, "--reference-log", proton, "--reference-column", "proton_nT"),  # no log times
        (*base, "--reference-log", proton, "--reference-column", "proton_nT", "--time-column",
         "utc"),  # the reference's times are not called utc
        (*base, "--reference-log", far, "--reference-column", "proton_nT", "--time-column", "utc",
         "--reference-time-column", "unix_s"),  # no overlap
        (*base, "--reference-log", proton, "--reference-column", "proton_nT", "--time-column",
         "utc", "--reference-time-column", "unix_s", "--low-memory"),
        (*base, "--reference-log", proton, "--reference-column", "proton_nT", "--time-column",
         "utc", "--reference-time-column", "unix_s", "--reference-field", "50000"),
        (*base, "--interpolation", "cubic"),
        (*base, "--reference-time-column", "unix_s"),
        (*base, "--reference-log", tmp_path / "absent.csv", "--reference-column", "x",
         "--time-column", "utc"),
    ):  # fmt: skip
        code, _, err = run(capsys, *argv)
        assert code == 2, (argv, err)
        assert "Traceback" not in err and err.startswith("nlpcal calibrate: error"), (argv, err)
        assert not (tmp_path / "p.json").exists()
