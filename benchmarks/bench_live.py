"""`nlpcal live` on a 1 kHz stream: the CPU its accumulation costs, and how soon an update
reaches stdout.

    python benchmarks/bench_live.py                 # the figures of docs/live.md
    python benchmarks/bench_live.py --seconds 10    # a quick look

1. Accumulation: the loop's own work on each batch of lines, as `nlpcal.live.run` does it
   (parse the lines, convert the unit, add the samples to the moments of the stream), timed
   with the thread's CPU clock over `--seconds` of a simulated 1 kHz stream arriving in the
   loop's 50 ms batches (50 lines each). The cost is that CPU time over the stream's duration,
   in % of one core; the median and the spread (min-max) over --repeats runs. The solves are
   not accumulation and are left out (their cost is the second figure's).
2. Latency: `nlpcal live -` in a fresh process, fed lines at 1 kHz through a pipe by a thread
   of this one; every update line carries "data_time", the wall-clock time the newest sample
   of its solve arrived, and the line's arrival here is timed: the data-to-stdout latency of
   each update (the solve included), its median and maximum; and the emit latency, from the end
   of the solve ("emitted_time" in the line) to its arrival.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from nlpcal.live import LiveSession
from nlpcal.live.parsers import detect_parser
from nlpcal.live.run import open_stream

RATE = 1000  # samples per second [Hz]
BATCH = 50  # lines per loop turn: 50 ms of a 1 kHz stream


def stream_lines(n: int, seed: int = 1) -> list:
    """A header and n lines of a sensor turned slowly through every direction. [nT]"""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    d = np.column_stack(
        [np.cos(0.7 * t) * np.cos(0.23 * t), np.sin(0.7 * t) * np.cos(0.23 * t), np.sin(0.23 * t)]
    )
    b = 49462.0 * d @ np.diag([1.01, 0.99, 1.0]).T + [300.0, -200.0, 150.0]
    b += rng.normal(0, 20.0, b.shape)
    return ["bx,by,bz", *(f"{x:.3f},{y:.3f},{z:.3f}" for x, y, z in b)]


def accumulation_cost(seconds: float) -> float:
    """% of one core the accumulation of `seconds` of a 1 kHz stream takes."""
    lines = stream_lines(int(seconds * RATE))
    parser = detect_parser(lines[:8], unit="nT")
    stream = open_stream(parser, lines[:8])
    session = LiveSession(stream.unit)
    started = time.thread_time()
    for start in range(1, len(lines), BATCH):
        rows, _ = stream.samples(lines[start : start + BATCH])
        session.add(rows)
    return 100.0 * (time.thread_time() - started) / seconds


def latencies(seconds: float) -> tuple:
    """(data-to-stdout latencies, emit latencies) of the updates of a 1 kHz stream. [s]"""
    lines = stream_lines(int(seconds * RATE), seed=2)
    output = tempfile.NamedTemporaryFile(suffix=".json", delete=False).name
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "nlpcal",
            "live",
            "-",
            "--unit",
            "nT",
            "--max-seconds",
            str(seconds + 5),
            "--target-se",
            "scale=1e-9",  # never determined: every update of the stream is timed
            "-o",
            output,
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        bufsize=1,
    )

    def feed():
        started = time.monotonic()
        process.stdin.write(lines[0] + "\n")
        for k in range(1, len(lines), 10):  # 10 lines every 10 ms
            delay = k / RATE - (time.monotonic() - started)
            if delay > 0:
                time.sleep(delay)
            process.stdin.write("\n".join(lines[k : k + 10]) + "\n")
            process.stdin.flush()
        process.stdin.close()

    writer = threading.Thread(target=feed)
    writer.start()
    data, emit = [], []
    for line in process.stdout:
        now = time.time()
        update = json.loads(line)
        data.append(now - update["data_time"])
        emit.append(now - update["emitted_time"])
    writer.join()
    process.wait()
    os.unlink(output)
    return data, emit


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="stream length [s]")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    costs = [accumulation_cost(args.seconds) for _ in range(args.repeats)]
    print(
        f"accumulation of a 1 kHz stream: {statistics.median(costs):.2f} % of one core "
        f"(median of {args.repeats}; spread {min(costs):.2f}-{max(costs):.2f} %)"
    )
    data, emit = latencies(min(args.seconds, 30.0))
    print(
        f"updates: {len(data)}; data to stdout: median {1e3 * statistics.median(data):.0f} ms, "
        f"max {1e3 * max(data):.0f} ms; end of solve to stdout: median "
        f"{1e3 * statistics.median(emit):.1f} ms, max {1e3 * max(emit):.1f} ms"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
