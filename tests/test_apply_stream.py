"""`nlpcal apply` and the other tables nlpcal writes: every row in its place, the container by
the output's extension, the digits the data warrant, a log streamed in chunks, progress on a
terminal only, and nothing left behind by a run that fails or is killed."""

import io
import json
import os
import pty
import re
import select
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

import nlpcal.io.output
import nlpcal.io.stream
from nlpcal.cli import main
from nlpcal.errors import InputError
from nlpcal.io.layout import Layout
from nlpcal.io.output import (
    Precision,
    check_table_output,
    rounded,
    significant_digits,
    write_table,
)
from nlpcal.io.progress import Progress
from synthetic import PAPER_FIELD, make_log, sensor_axes

pytest.importorskip("pyarrow")

SAMPLES, _ = make_log(n=1500, noise=1.0, seed=24)
#: Data rows (1-based) of the log written by `messy_log`: zero vectors, a run of repeats, and
#: lines with a missing or a non-numeric value.
ZERO_ROWS = (1, 700)
REPEAT_ROWS = (301, 302, 303)  # repeat row 300
BAD_ROWS = (5, 1202)


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def inverse_eq4(raw, parameters: dict) -> np.ndarray:
    """B1 from B_M: the forward model of tests/synthetic.py (B_M = diag(1 + s) T B + z) solved
    for B, with the parameters of a params file."""
    axes = sensor_axes(parameters["alpha_deg"], parameters["beta_deg"], parameters["gamma_deg"])
    z = np.array([parameters[f"z_{k}"] for k in "xyz"])
    scale = 1.0 + np.array([parameters[f"s_{k}"] for k in "xyz"])
    return np.linalg.solve(axes, ((raw - z) / scale).T).T


def messy_log(path, samples=SAMPLES):
    """A log with a time and a text column, 3 decimals, zero vectors, repeats and bad lines;
    returns the field vectors of its rows of numbers (in order) and their row kinds."""
    rows, vectors, kinds = [], [], []
    data = iter(samples)
    previous = None
    for row in range(1, len(samples) + len(ZERO_ROWS) + len(REPEAT_ROWS) + len(BAD_ROWS) + 1):
        if row in BAD_ROWS:
            rows.append(
                f"{row * 0.01:.2f},1.0,,3.0,lab" if row == 5 else f"{row * 0.01:.2f},x,2,3,lab"
            )
            continue
        if row in ZERO_ROWS:
            vector, kind = np.zeros(3), "zero"
        elif row in REPEAT_ROWS:
            vector, kind = previous, "repeat"
        else:
            vector, kind = np.round(next(data), 3), "reading"
        previous = vector
        vectors.append(vector)
        kinds.append(kind)
        rows.append(f"{row * 0.01:.2f},{vector[0]:.3f},{vector[1]:.3f},{vector[2]:.3f},lab {row}")
    path.write_text("t,bx,by,bz,note\n" + "\n".join(rows) + "\n")
    return np.array(vectors), np.array(kinds)


@pytest.fixture(scope="module")
def params(tmp_path_factory):
    folder = tmp_path_factory.mktemp("params")
    log = folder / "clean.csv"
    pd.DataFrame(np.round(SAMPLES, 3), columns=["bx", "by", "bz"]).to_csv(log, index=False)
    path = folder / "p.json"
    argv = ["calibrate", log, "--method", "joint", "--reference-field", PAPER_FIELD, "-o", path]
    assert main([str(a) for a in [*argv, "-q"]]) == 0
    return path


@pytest.fixture
def small_chunks(monkeypatch):
    """Chunks of 400 rows, so that a log of 1500 is read in several."""
    monkeypatch.setattr(nlpcal.io.stream, "CHUNK_ROWS", 400)


def test_every_row_of_numbers_in_place_readings_corrected(tmp_path, capsys, params, small_chunks):
    log = tmp_path / "log.csv"
    vectors, kinds = messy_log(log)
    out = tmp_path / "out.csv"
    code, _, err = run(capsys, "apply", params, log, "--drop-invalid", "-o", out)
    assert code == 0, err
    written = pd.read_csv(out, keep_default_na=False)
    assert list(written.columns) == ["t", "bx", "by", "bz", "note", "b_total", "valid"]
    assert len(written) == len(vectors)  # one row per row of numbers, the bad lines out
    readings = kinds == "reading"
    np.testing.assert_array_equal(written["valid"].to_numpy(), readings.astype(int))
    field = written[["bx", "by", "bz"]].to_numpy()
    np.testing.assert_array_equal(field[~readings], vectors[~readings])  # raw, never NaN
    expected = inverse_eq4(vectors[readings], json.loads(params.read_text())["parameters"])
    # 8 significant digits in, 9 out: within half a unit of the ninth digit
    np.testing.assert_allclose(field[readings], expected, rtol=1e-8)
    magnitude = np.linalg.norm(field, axis=1)
    np.testing.assert_allclose(written["b_total"], magnitude, rtol=1e-8)
    assert written["note"].tolist()[:3] == ["lab 1", "lab 2", "lab 3"]  # text kept
    assert "nan" not in out.read_text().lower() and "inf" not in out.read_text().lower()
    # the dropped lines are counted and named by their data rows; the others said
    assert re.search(r"dropped 2 row\(s\).*data row 5, 1202", err)
    assert f"{(kinds == 'zero').sum()} row(s) whose field vector is exactly (0, 0, 0)" in err
    assert "marked the repeats valid 0" in err


def test_a_bad_line_without_drop_invalid_fails_and_keeps_the_output(
    tmp_path, capsys, params, small_chunks
):
    log = tmp_path / "log.csv"
    messy_log(log)
    out = tmp_path / "out.csv"
    out.write_text("precious\n")
    code, _, err = run(capsys, "apply", params, log, "-o", out)
    assert code == 2 and "--drop-invalid" in err and "Traceback" not in err
    assert out.read_text() == "precious\n"
    assert sorted(os.listdir(tmp_path)) == ["log.csv", "out.csv"]


@pytest.mark.parametrize(
    "row", [3, 1300]
)  # in the first chunk (which decides the unit), the fourth
def test_a_sample_too_large_anywhere_in_the_log_writes_nothing(
    tmp_path, capsys, params, small_chunks, row
):
    """Every chunk is held to the magnitude limit every reader applies, before anything computes
    with it: one sentence, no numpy warnings, and the old output kept."""
    text = ["bx,by,bz"] + [f"{x:.3f},{y:.3f},{z:.3f}" for x, y, z in SAMPLES]
    text[row] = "1e308,1e308,1e308"  # |B| would overflow to infinity
    log = tmp_path / "log.csv"
    log.write_text("\n".join(text) + "\n")
    out = tmp_path / "out.parquet"
    out.write_bytes(b"old")
    code, _, err = run(capsys, "apply", params, log, "-o", out, "-q")
    assert code == 2 and "1e+308" in err and "Warning" not in err
    assert len(err.strip().splitlines()) == 1
    assert out.read_bytes() == b"old" and sorted(os.listdir(tmp_path)) == ["log.csv", "out.parquet"]


def test_parquet_out_by_the_extension_round_trips(tmp_path, capsys, params, small_chunks):
    log = tmp_path / "log.csv"
    vectors, kinds = messy_log(log)
    text_out, parquet_out = tmp_path / "out.csv", tmp_path / "out.parquet"
    for out in (text_out, parquet_out):
        code, _, err = run(
            capsys, "apply", params, log, "--drop-invalid", "--precision", "17", "-o", out
        )
        assert code == 0, err
    assert parquet_out.read_bytes()[:4] == b"PAR1"
    table = pd.read_parquet(parquet_out)
    assert table["t"].dtype == np.float64 and table["note"].iloc[0] == "lab 1"
    text = pd.read_csv(text_out, keep_default_na=False)
    pd.testing.assert_frame_equal(table, text, check_dtype=False)
    # and Parquet in: every digit of a float64 out (by default), in a text output
    again = tmp_path / "again.csv"
    code, _, err = run(capsys, "apply", params, parquet_out, "-o", again)
    assert code == 0, err
    twice = pd.read_csv(again)
    raw = table[["bx", "by", "bz"]].to_numpy()
    expected = inverse_eq4(raw, json.loads(params.read_text())["parameters"])
    valid = table["valid"].to_numpy() == 1
    # the same equation twice, in double precision: differences of rounding only
    np.testing.assert_allclose(
        twice[["bx", "by", "bz"]].to_numpy()[valid], expected[valid], rtol=1e-12
    )


def test_text_digits_follow_the_input(tmp_path, capsys, params):
    log = tmp_path / "log.csv"
    pd.DataFrame(np.round(SAMPLES[:50], 2), columns=["bx", "by", "bz"]).to_csv(
        log, index=False, float_format="%.2f"
    )
    carried = max(significant_digits(pd.read_csv(log, dtype=str)[c]) for c in ("bx", "by", "bz"))
    for extra, expected in ((), carried + 1), (("--precision", "4"), 4):
        out = tmp_path / "out.csv"
        assert run(capsys, "apply", params, log, "-o", out, *extra)[0] == 0
        cells = pd.read_csv(out, dtype=str)[["bx", "by", "bz", "b_total"]].to_numpy().ravel()
        digits = [len(re.sub(r"[-.]|e.*", "", c).strip("0")) for c in cells]  # fewest shown
        assert max(digits) == expected


def test_significant_digits_and_rounding():
    cells = pd.Series(["-0.00120", "1.50e3", "1200", "+7", " 12.5 "])
    assert significant_digits(cells) == 4
    assert significant_digits(cells[:2]) == 3
    assert significant_digits(cells, at_least=6) == 6
    values = np.array([30617.5776, -0.000123456, 1.5e20 + 3e15, 0.0, 999.96])
    assert [repr(float(v)) for v in rounded(values, 4)] == [
        "30620.0",
        "-0.0001235",
        "1.5e+20",
        "0.0",
        "1000.0",
    ]
    precision = Precision()
    precision.observe([cells])
    assert precision.significant == 5
    precision.observe([pd.Series([1.0])])  # numbers, not text: every digit
    assert precision.significant is None
    with pytest.raises(InputError):
        Precision(0)


def test_other_tables_are_parquet_by_extension_too(tmp_path, capsys):
    out = tmp_path / "sim.parquet"
    code, _, err = run(capsys, "simulate", "-n", "50", "-o", out)
    assert code == 0, err
    assert out.read_bytes()[:4] == b"PAR1" and len(pd.read_parquet(out)) == 50


def test_parquet_to_a_terminal_is_refused(tmp_path):
    master, slave = os.openpty()
    try:
        link = tmp_path / "out.parquet"
        link.symlink_to(f"/proc/self/fd/{slave}")
        with pytest.raises(InputError, match="terminal"):
            check_table_output(link)
    finally:
        os.close(master)
        os.close(slave)


def test_progress_line_only_on_a_terminal():
    class Screen:
        def __init__(self, tty):
            self.tty, self.text = tty, ""

        def isatty(self):
            return self.tty

        def write(self, text):
            self.text += text

        def flush(self):
            pass

    now = [0.0]
    for tty, enabled, shown in ((True, None, True), (False, None, False), (True, False, False)):
        screen = Screen(tty)
        with Progress(
            "applying x.csv", 100e6, stream=screen, enabled=enabled, clock=lambda: now[0]
        ) as bar:
            now[0] = 10.0
            bar.update(40e6)
        assert ("40% (40 of 100 MB), 4.0 MB/s, 15 s left" in screen.text) is shown
        assert bool(screen.text) is shown


BIG_ROWS = 400_000


@pytest.fixture(scope="module")
def big_log(tmp_path_factory, params):
    folder = tmp_path_factory.mktemp("big")
    samples, _ = make_log(n=BIG_ROWS, noise=1.0, seed=7)
    log = folder / "big.csv"
    np.savetxt(
        log, samples, fmt="%.10g", delimiter=",", header="bx,by,bz", comments=""
    )  # as simulate
    return log


def spawn_on_a_terminal(argv, cwd, stdout):
    """`nlpcal argv` with stderr on a pseudo-terminal, the progress line shown from the start;
    returns (process, the terminal's master end)."""
    master, slave = pty.openpty()
    code = (
        "import sys, nlpcal.io.progress as p; p.QUIET_START = 0.0; p.INTERVAL = 0.05; "
        "from nlpcal.cli import main; sys.exit(main(sys.argv[1:]))"
    )
    process = subprocess.Popen(
        [sys.executable, "-c", code, *map(str, argv)], cwd=cwd, stdout=stdout, stderr=slave
    )
    os.close(slave)
    return process, master


def read_terminal(master, until, timeout=120.0) -> str:
    """What the terminal shows until `until(text)` holds or the other end closes."""
    text, deadline = "", time.monotonic() + timeout
    while time.monotonic() < deadline and not until(text):
        ready, _, _ = select.select([master], [], [], 0.5)
        if ready:
            try:
                chunk = os.read(master, 4096)
            except OSError:
                break
            if not chunk:
                break
            text += chunk.decode(errors="replace")
    return text


def test_progress_on_a_terminal_and_a_killed_apply_leaves_nothing(tmp_path, params, big_log):
    out = tmp_path / "out.csv"
    out.write_text("precious\n")
    argv = ["apply", params, big_log, "-o", out]
    process, master = spawn_on_a_terminal(argv, tmp_path, subprocess.DEVNULL)
    try:
        shown = read_terminal(master, lambda text: "left" in text)
        assert re.search(r"applying .*big\.csv: \d+% \(.* MB\), [\d.]+ MB/s, .* left", shown)
        process.send_signal(signal.SIGKILL)  # mid-stream: the progress line is there
        process.wait(timeout=60)
    finally:
        os.close(master)
        if process.poll() is None:
            process.kill()
    assert out.read_text() == "precious\n" and os.listdir(tmp_path) == ["out.csv"]
    # a pipe for stderr, or -q: not a character of progress
    for extra in ((), ("-q",)):
        done = subprocess.run(
            [sys.executable, "-m", "nlpcal", *map(str, argv), *extra],
            capture_output=True,
            text=True,
            check=False,
        )
        assert done.returncode == 0 and "\r" not in done.stderr and "left" not in done.stderr
    assert len(pd.read_csv(out)) == BIG_ROWS
    assert out.stat().st_size <= 1.5 * big_log.stat().st_size


def test_the_pandas_writer_gives_the_same_numbers(tmp_path, monkeypatch):
    """Without pyarrow, pandas' to_csv writes the table: the same cells but whole floats."""
    frame = pd.DataFrame(
        {
            "t": ["0.5", "1,5", 'say "hi"'],
            "x": [30617.5776, -0.000123456, 12.0],
            "flag": [True, False, True],
            "valid": np.array([1, 0, 1], dtype=np.int8),
        }
    )
    texts = {}
    for engine in ("pyarrow", "c"):
        monkeypatch.setattr(nlpcal.io.output, "csv_engine", lambda engine=engine: engine)
        out = tmp_path / f"{engine}.csv"
        write_table(frame, Layout(), out, Precision(6))
        texts[engine] = out.read_text()
        pd.testing.assert_frame_equal(
            pd.read_csv(out, dtype={"t": str}),
            frame.assign(x=[30617.6, -0.000123456, 12.0]),
            check_dtype=False,
        )
    assert texts["pyarrow"].replace("12,", "12.0,") == texts["c"]


def test_parquet_through_a_fifo(tmp_path, capsys, params):
    log = tmp_path / "log.csv"
    pd.DataFrame(np.round(SAMPLES[:300], 3), columns=["bx", "by", "bz"]).to_csv(log, index=False)
    fifo = tmp_path / "pipe.parquet"
    os.mkfifo(fifo)
    reader = subprocess.Popen(["cat", str(fifo)], stdout=subprocess.PIPE)
    code, _, err = run(capsys, "apply", params, log, "-o", fifo)
    data = reader.communicate(timeout=60)[0]
    assert code == 0, err
    assert data[:4] == b"PAR1" and len(pd.read_parquet(io.BytesIO(data))) == 300
