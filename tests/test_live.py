"""`nlpcal live`: the equal-area grid, the moments of a stream, the session's stop rule, the
parsers, and the command fed by stdin, a pseudo-terminal standing in for a serial port and UDP;
the terminal view in tmux and the web view in headless Chromium.

Tolerances: two solves of the same data agree within `resolution.SAME_OPTIMUM_SE` standard
errors (each stops within 0.01 of its optimum); moments summed in the same order agree to
rounding, 1e-9 relative.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from nlpcal.calibration import calibrate
from nlpcal.errors import InputError
from nlpcal.live import LiveSession, StreamMoments, Targets, targets_from
from nlpcal.live.grid import CELLS, cell_centres, cell_index, coverage, zones
from nlpcal.live.parsers import detect_parser
from nlpcal.moments import MomentBlock, accumulate, gram_index, sphere_frame
from resolution import assert_same_optimum
from synthetic import PAPER_FIELD, make_log

SUNSIDED = Path("sunsided_hmc5883l_fullsphere") / "hmc5883l_mag_derived.csv"
#: Targets the sunsided log meets before its end: its 8190 samples give standard errors of
#: 0.2 % of the field, 0.003 and 0.17 deg at the end, and its field visits 84 % of the cells.
SUNSIDED_TARGETS = ["offset=0.5%", "scale=0.005", "angle=0.5"]
SUNSIDED_COVERAGE = "0.75"
#: Targets 6000-8000 samples of the synthetic log (2.5 nT of noise) meet.
SYNTHETIC_TARGETS = ["--target-se", "offset=0.3%", "scale=0.003", "angle=0.3"]


def nlpcal_command(*args) -> list:
    return [sys.executable, "-m", "nlpcal", "live", *args]


def json_lines(text: str) -> list:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def sunsided_lines(real_data) -> tuple:
    """(lines with the header first, the recorded seconds of each data line)."""
    text = (real_data / SUNSIDED).read_text().splitlines()
    rows = [line.split(",") for line in text[1:]]
    header = ",".join(text[0].split(",")[1:])
    return [header, *(",".join(r[1:]) for r in rows)], np.array([float(r[0]) for r in rows])


def csv_lines(samples) -> list:
    return ["bx,by,bz", *(",".join(repr(float(v)) for v in row) for row in samples)]


# --- the grid ------------------------------------------------------------------------------


def test_the_grid_has_80_cells_of_equal_area():
    counts, upper, _ = zones()
    assert counts.sum() == CELLS == 80
    # the zone heights in z are the cells' shares of the sphere (hat-box theorem)
    heights = -np.diff(np.append(upper, -1.0))
    assert np.allclose(heights, 2.0 * counts / CELLS)
    assert np.array_equal(cell_index(cell_centres()), np.arange(CELLS))
    # uniform directions fill every cell alike: 10 000 per cell, Poisson spread 1 %
    rng = np.random.default_rng(3)
    hits = np.bincount(cell_index(rng.standard_normal((800_000, 3))), minlength=CELLS)
    assert np.all(np.abs(hits / 10_000 - 1.0) < 0.05)


def test_the_next_direction_points_into_the_hole():
    rng = np.random.default_rng(4)
    upper = rng.standard_normal((5000, 3))
    upper[:, 2] = np.abs(upper[:, 2]) + 0.3  # the field never pointed down
    cov = coverage(upper)
    assert 0.3 < cov.fraction < 0.7 and not cov.complete
    assert cov.next_direction[2] < -0.5
    assert cov.to_dict()["turn_to"].endswith("-z")
    everywhere = coverage(rng.standard_normal((20_000, 3)))
    assert everywhere.complete and everywhere.next_direction is None


# --- the moments of a stream ---------------------------------------------------------------


def test_stream_moments_summed_in_one_frame_equal_the_pass_over_the_log():
    samples, _ = make_log(n=20_000, seed=5)
    stream = StreamMoments()
    stream.add(samples[:1024])  # the rows `accumulate` takes the shift of its sums from
    stream._restart(sphere_frame(samples))  # the frame of `accumulate`, to compare the sums
    rng = np.random.default_rng(6)
    start = 1024
    while start < len(samples):
        stop = start + int(rng.integers(1, 700))
        stream.add(samples[start:stop])
        start = stop
    live, whole = stream.moments(), accumulate(samples, frame=sphere_frame(samples))
    assert live.n == whole.n == len(samples)
    scale = np.abs(whole.gram).max()
    np.testing.assert_allclose(live.gram, whole.gram, rtol=1e-9, atol=1e-9 * scale)
    assert live.measured == pytest.approx(whole.measured, rel=1e-9)


def test_a_poor_first_frame_is_replaced_and_the_sum_restarted():
    samples, field = make_log(n=6000, noise=200.0, seed=7)  # a noisy MEMS sensor
    order = np.argsort(-field[:, 2])  # the field near +z first: a cap, a poor sphere
    samples = samples[order]
    stream = StreamMoments()
    stream.add(samples[:64])
    assert stream.frame.radius < 0.9 * PAPER_FIELD  # the first frame is poor
    for start in range(64, len(samples), 500):
        stream.add(samples[start : start + 500])
        stream.check_frame()
    assert stream.reframed >= 1
    whole = accumulate(samples, frame=stream.frame)
    scale = np.abs(whole.gram).max()
    np.testing.assert_allclose(stream.moments().gram, whole.gram, atol=1e-9 * scale)


def test_forgetting_weighs_each_sample_by_its_age():
    samples, _ = make_log(n=3000, seed=8)
    lam = 0.999
    stream = StreamMoments(forgetting=lam)
    for start in range(0, len(samples), 257):
        stream.add(samples[start : start + 257])
    weights = lam ** np.arange(len(samples) - 1, -1, -1, dtype=float)
    frame = stream.frame
    block = MomentBlock(
        frame.centre, frame.radius, False, 0.0, len(samples), lambda raw, ref: weights
    )
    sums, _, total = block(samples, None)
    gram = sums[gram_index(False)]
    moments = stream.moments()
    assert moments.weight_sum == pytest.approx(total, rel=1e-12)
    scale = np.abs(gram).max()
    np.testing.assert_allclose(moments.gram * total, gram, atol=1e-9 * scale)


# --- the session ---------------------------------------------------------------------------


def test_a_session_stops_when_determined_and_its_result_is_calibrates():
    samples, _ = make_log(n=6000, noise=2.5, seed=9)
    session = LiveSession("nT", targets=Targets(0.002, 0.002, 0.2), interval=0.0)
    stopped = None
    for start in range(0, len(samples), 250):
        session.add(samples[start : start + 250])
        if session.due() and session.update().determined:
            stopped = session.n
            break
    assert stopped is not None and stopped < len(samples)
    update = session.latest.to_dict()
    assert update["determined"] and update["poorly_determined"] == []
    assert update["coverage"]["fraction"] >= 0.9
    for name, limit in update["target_standard_errors"].items():
        assert update["standard_errors"][name] < limit
    final = session.final()
    expected = calibrate(samples[:stopped], unit="nT")
    assert_same_optimum(final.parameters, expected.parameters, expected.standard_errors)


def test_too_few_samples_are_refused_at_the_end():
    session = LiveSession("nT")
    session.add(make_log(n=10, seed=1)[0])
    with pytest.raises(InputError):
        session.final()


def test_targets_from_the_command_line():
    assert targets_from(["offset=0.5%", "angle=0.2"]) == Targets(0.005, 0.001, 0.2)
    for bad in (["offset=0.5"], ["scale=-1"], ["wobble=1"], ["angle=x"]):
        with pytest.raises(InputError):
            targets_from(bad)


# --- parsers ---------------------------------------------------------------------------------


def test_motioncal_lines_give_the_magnetometer_counts():
    head = ["Raw:1,2,3,4,5,6,-120,35,410", "Uni:0.1,0.2", "Raw:1,2,3"]
    parser = detect_parser(head)
    rows, kept, skipped = parser.parse(head)
    assert parser.kind == "motioncal" and parser.unit == "mG"
    assert rows.tolist() == [[-120.0, 35.0, 410.0]] and kept == head[:1] and skipped == 2


def test_delimited_text_is_detected_as_a_log_is():
    head = ["time;mag_x_uT;mag_y_uT;mag_z_uT", "0,1;12,5;-3,25;40,0", "0,2;12,6;-3,5;40,1"]
    parser = detect_parser(head)
    rows, _, skipped = parser.parse(head)
    assert (parser.kind, parser.unit, parser.unit_source) == ("delimited", "uT", "names")
    assert rows.tolist() == [[12.5, -3.25, 40.0], [12.6, -3.5, 40.1]] and skipped == 1
    headerless = detect_parser(["1 2 3", "4 5 6"], unit="raw")
    assert headerless.parse(["7 8 9"])[0].tolist() == [[7.0, 8.0, 9.0]]


def test_a_regex_takes_named_or_numbered_groups():
    named = detect_parser([], regex=r"z=(?P<z>\S+) y=(?P<y>\S+) x=(?P<x>\S+)", unit="uT")
    rows, kept, _ = named.parse(["t=1 z=3 y=2 x=1", "noise"])
    assert rows.tolist() == [[1.0, 2.0, 3.0]] and kept == ["1,2,3"]
    with pytest.raises(InputError):
        detect_parser([], regex=r"(\d+) (\d+)")
    with pytest.raises(InputError):
        detect_parser([], regex=r"([)")


# --- the command -----------------------------------------------------------------------------


def test_stdin_updates_stop_writes_and_the_recording_reproduces_calibrate(tmp_path):
    samples, _ = make_log(n=8000, seed=12)
    params, record = tmp_path / "params.json", tmp_path / "record.csv"
    run = subprocess.run(
        nlpcal_command(
            "-",
            "--unit",
            "nT",
            *SYNTHETIC_TARGETS,
            "--record",
            str(record),
            "-o",
            str(params),
        ),
        input="\n".join(csv_lines(samples)) + "\n",
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    lines = json_lines(run.stdout)
    for key in ("n_samples", "parameters", "standard_errors", "coverage", "verdict", "table1"):
        assert all(key in line for line in lines)
    assert lines[-1]["determined"] is True
    assert not any(line["determined"] for line in lines[:-1])
    assert f"all parameters determined at sample {lines[-1]['n_samples']}" in run.stderr
    written = json.loads(params.read_text())
    assert written["n_samples"] == lines[-1]["n_samples"]
    again = tmp_path / "again.json"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "nlpcal",
            "calibrate",
            str(record),
            "--unit",
            "nT",
            "-o",
            str(again),
        ],
        check=True,
        capture_output=True,
    )
    expected = json.loads(again.read_text())
    assert_same_optimum(written["parameters"], expected["parameters"], expected["standard_errors"])


@pytest.mark.parametrize(
    "args",
    [
        ["--udp", "nowhere"],
        ["--regex", "(a)(b"],
        ["--target-se", "offset=1"],
        ["--export-format", "px4"],
        ["-", "--udp", "127.0.0.1:0"],
    ],
)
def test_bad_options_exit_2_with_one_sentence(args, tmp_path):
    params = tmp_path / "params.json"
    params.write_text("keep")
    run = subprocess.run(
        nlpcal_command(*args, "-o", str(params)), input="", capture_output=True, text=True
    )
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert params.read_text() == "keep" and sorted(os.listdir(tmp_path)) == ["params.json"]


def test_a_stream_too_short_exits_2_and_leaves_the_output(tmp_path):
    params, record = tmp_path / "params.json", tmp_path / "rec.csv"
    params.write_text("keep")
    run = subprocess.run(
        nlpcal_command("-", "--record", str(record), "-o", str(params)),
        input="bx,by,bz\n1,2,3\n4,5,6\n",
        capture_output=True,
        text=True,
    )
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert params.read_text() == "keep" and sorted(os.listdir(tmp_path)) == ["params.json"]


def replay(fd: int, lines, seconds, rate: float, stop: threading.Event) -> None:
    """Write lines to a non-blocking descriptor at `rate` times their recorded times (the
    header at once) until `stop` is set."""
    os.set_blocking(fd, False)

    def write(line: str) -> None:
        data = (line + "\n").encode()
        while data and not stop.is_set():
            try:
                data = data[os.write(fd, data) :]
            except BlockingIOError:  # the reader is behind: wait for it, or for the stop
                time.sleep(0.01)
            except OSError:
                return

    write(lines[0])
    started = time.monotonic()
    for line, at in zip(lines[1:], seconds - seconds[0]):
        if stop.is_set():
            return
        delay = at / rate - (time.monotonic() - started)
        if delay > 0:
            time.sleep(delay)
        write(line)


def serial_replay(real_data, tmp_path, rate: float):
    """`nlpcal live --serial` on a pseudo-terminal fed the sunsided log at `rate` x its
    recorded rate: (the run, its JSON lines, the parameters written, the recording)."""
    pytest.importorskip("serial")
    lines, seconds = sunsided_lines(real_data)
    master, slave = os.openpty()
    import tty

    tty.setraw(slave)  # a serial device: no echo, no line editing
    params, record = tmp_path / "params.json", tmp_path / "record.csv"
    process = subprocess.Popen(
        nlpcal_command(
            "--serial",
            os.ttyname(slave),
            "--baud",
            "115200",
            "--target-se",
            *SUNSIDED_TARGETS,
            "--coverage",
            SUNSIDED_COVERAGE,
            "--record",
            str(record),
            "-o",
            str(params),
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    stop = threading.Event()
    writer = threading.Thread(target=replay, args=(master, lines, seconds, rate, stop))
    try:
        said = process.stderr.readline()  # "nlpcal: reading /dev/pts/N": the port is open
        assert "reading" in said, said
        writer.start()
        out, err = process.communicate(timeout=60 + 120 / rate)
    finally:
        stop.set()
        if process.poll() is None:
            process.kill()
        if writer.is_alive():
            writer.join()
        os.close(slave)
        os.close(master)
    return process, json_lines(out), err, params, record, len(lines) - 1


def check_determined_before_the_end(real_data, tmp_path, rate):
    process, lines, err, params, record, total = serial_replay(real_data, tmp_path, rate)
    assert process.returncode == 0, err
    last = lines[-1]
    assert last["determined"] and last["n_samples"] < total
    assert f"all parameters determined at sample {last['n_samples']}" in err
    written = json.loads(params.read_text())
    again = tmp_path / "again.json"
    subprocess.run(
        [sys.executable, "-m", "nlpcal", "calibrate", str(record), "-o", str(again)],
        check=True,
        capture_output=True,
    )
    expected = json.loads(again.read_text())
    assert written["n_samples"] == expected["n_samples"] == last["n_samples"]
    assert_same_optimum(written["parameters"], expected["parameters"], expected["standard_errors"])


@pytest.mark.realdata
def test_serial_replay_of_a_real_log_faster_than_recorded(real_data, tmp_path):
    check_determined_before_the_end(real_data, tmp_path, rate=8.0)


@pytest.mark.slow
@pytest.mark.realdata
def test_serial_replay_of_a_real_log_at_its_recorded_rate(real_data, tmp_path):
    """The acceptance run: the sunsided log through a pseudo-terminal at 77 samples/s."""
    check_determined_before_the_end(real_data, tmp_path, rate=1.0)


def test_udp_datagrams_from_127_0_0_1(tmp_path):
    samples, _ = make_log(n=6000, seed=13)
    params = tmp_path / "params.json"
    process = subprocess.Popen(
        nlpcal_command(
            "--udp",
            "127.0.0.1:0",
            "--unit",
            "nT",
            *SYNTHETIC_TARGETS,
            "--max-seconds",
            "60",
            "-o",
            str(params),
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        announced = process.stderr.readline()  # "nlpcal: reading udp://127.0.0.1:PORT"
        port = int(re.search(r"udp://127\.0\.0\.1:(\d+)", announced).group(1))
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        lines = csv_lines(samples)
        for start in range(0, len(lines), 20):  # 20 lines a datagram, 300 datagrams
            sender.sendto("\n".join(lines[start : start + 20]).encode(), ("127.0.0.1", port))
            time.sleep(0.002)
        sender.close()
        out, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, err
    assert json_lines(out)[-1]["determined"]
    assert json.loads(params.read_text())["n_samples"] <= len(samples)


@pytest.mark.parametrize("signal_number", [signal.SIGTERM, signal.SIGINT])
def test_ctrl_c_stops_and_writes_but_sigterm_leaves_the_outputs(tmp_path, signal_number):
    params, record = tmp_path / "params.json", tmp_path / "rec.csv"
    params.write_text("keep")
    process = subprocess.Popen(
        nlpcal_command(  # targets never met: it runs until the signal
            "-",
            "--unit",
            "nT",
            "--target-se",
            "scale=1e-9",
            "--record",
            str(record),
            "-o",
            str(params),
        ),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    samples, _ = make_log(n=2000, seed=14)
    process.stdin.write("\n".join(csv_lines(samples)) + "\n")
    process.stdin.flush()
    process.stdout.readline()  # an update: the loop runs
    process.send_signal(signal_number)
    _, err = process.communicate(timeout=60)
    if signal_number == signal.SIGINT:  # the user's stop: calibrate's result of the samples
        assert process.returncode == 0, err
        assert json.loads(params.read_text())["n_samples"] <= len(samples)
        assert sorted(os.listdir(tmp_path)) == ["params.json", "rec.csv"]
        return
    assert process.returncode == 143
    assert params.read_text() == "keep" and sorted(os.listdir(tmp_path)) == ["params.json"]


# --- the views -----------------------------------------------------------------------------


def _tmux():
    if shutil.which("tmux"):
        return shutil.which("tmux")
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail("CI=true but tmux is not installed (apt-get install tmux)")
    pytest.skip("tmux is not installed (apt-get install tmux)")


def test_the_terminal_view_in_a_tmux_pane(tmp_path):
    tmux = _tmux()
    samples, _ = make_log(n=6000, seed=15)
    log = tmp_path / "log.csv"
    log.write_text("\n".join(csv_lines(samples)) + "\n")
    name = f"nlpcal-live-{os.getpid()}"
    command = (
        f"{sys.executable} -m nlpcal live - --unit nT {' '.join(SYNTHETIC_TARGETS)} "
        f"-o {tmp_path / 'params.json'} < {log} > {tmp_path / 'lines'}; sleep 30"
    )
    subprocess.run(
        [tmux, "-L", name, "new-session", "-d", "-s", name, "-x", "100", "-y", "40", command],
        check=True,
    )
    try:
        pane = ""
        for _ in range(120):
            time.sleep(0.5)
            pane = subprocess.run(
                [tmux, "-L", name, "capture-pane", "-p", "-t", name],
                capture_output=True,
                text=True,
            ).stdout
            if "wrote" in pane:
                break
    finally:
        subprocess.run([tmux, "-L", name, "kill-server"], capture_output=True)
    assert "coverage:" in pane and " of 80 cells" in pane
    assert re.search(r"\+z +[#.@]", pane) and re.search(r"-z +[#.@]", pane)
    assert "std of |B1|" in pane and "z_x" in pane and "alpha_deg" in pane
    assert "all parameters determined at sample" in pane


def test_the_web_view_renders_and_updates_in_headless_chromium(tmp_path):
    from test_report import _browser, _browser_flags

    browser = _browser()
    samples, _ = make_log(n=5000, seed=16)
    lines = csv_lines(samples)
    process = subprocess.Popen(
        nlpcal_command(
            "-",
            "--unit",
            "nT",
            "--web",
            "--web-port",
            "0",
            "--max-seconds",
            "90",
            "--target-se",
            "scale=1e-9",  # never determined: it runs until stdin ends
            "-o",
            str(tmp_path / "params.json"),
        ),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        url = None
        while url is None:
            said = process.stderr.readline()
            assert said, "nlpcal live ended before it served the view"
            found = re.search(r"http://127\.0\.0\.1:\d+/", said)
            url = found and found.group(0)
        views = []
        for part, sent in ((lines[:2000], 1999), (lines[2000:], len(samples))):
            process.stdin.write("\n".join(part) + "\n")
            process.stdin.flush()
            update = json.loads(process.stdout.readline())
            while update["n_samples"] < sent:  # the update of every sample sent
                update = json.loads(process.stdout.readline())
            dom = subprocess.run(
                [
                    browser,
                    *_browser_flags(tmp_path, 1000, 900),
                    "--virtual-time-budget=3000",
                    "--dump-dom",
                    url,
                ],
                capture_output=True,
                text=True,
                timeout=120,
            ).stdout
            views.append(dom)
        process.stdin.close()
        process.stdout.read()
        process.wait(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    counts = []
    for dom in views:
        points = int(re.search(r'id="cloud"[^>]*data-points="(\d+)"', dom).group(1))
        covered = int(re.search(r'id="coverage"[^>]*data-covered="(\d+)"', dom).group(1))
        shown = int(re.search(r'id="n_samples">(\d+)<', dom).group(1))
        assert points > 100 and covered > 20
        assert dom.count("<tr") == 10 and "z_x" in dom and "gamma_deg" in dom
        assert re.search(r'id="verdict"[^>]*>[^<]*verdict: ', dom)
        counts.append(shown)
    assert counts == [1999, len(samples)]
